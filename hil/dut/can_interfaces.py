"""Which python-can interfaces exist here: checked when a ``--dut`` is parsed and again when a bus opens."""

from __future__ import annotations


def unknown_can_interface(interface: str) -> str | None:
    """Why python-can cannot open ``interface`` (one line listing the ones it has), or None."""
    import can

    if interface in can.interfaces.VALID_INTERFACES:
        return None
    return (
        f"python-can has no interface {interface!r} (installed: {', '.join(sorted(can.interfaces.VALID_INTERFACES))})"
    )
