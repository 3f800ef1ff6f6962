"""The published figures' tool, run as ``python tools/figures.py``: the engine (``engine.py``), what
a group is (``model.py``) and one module per producer (``producers/``). See ``engine.py``."""
