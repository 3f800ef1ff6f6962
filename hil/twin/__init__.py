"""A plant twin of a Hall capture: built from it, checked against it (docs/twin.md)."""
