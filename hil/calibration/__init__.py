"""Pre-calibration of the Hall position deviations (paper Section 2 and 4.2).

``corrections`` is the table the controller applies (light: numpy only, imported by the controller);
``fit`` estimates it from a recording; ``campaign`` and ``steps`` drive and read the calibration runs.
This package imports nothing itself, so the controller's import of ``corrections`` stays light.
"""
