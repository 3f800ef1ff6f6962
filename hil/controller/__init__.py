"""The virtual controller: the built-in device under test, as firmware would be written.

It sees only what crosses the link (``bldc.contract``): captured Hall edges in, commutation commands
out. It never imports the simulator (``plant_models``); ``tests/test_architecture.py`` holds that.
"""
