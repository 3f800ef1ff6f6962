"""Project-level pytest configuration. The HIL fixtures come from the ``hil`` plugin (pytest11)."""

pytest_plugins = ["pytester"]
