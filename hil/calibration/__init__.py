"""Pre-calibration of the Hall position deviations (paper Section 2 and 4.2).

``calibrate(recording)`` is the entry point: it chooses the route (``route``: campaign segments,
``fit``; or an ordinary run, ``ordinary``), applies the same bounds and refusals on both, and
returns one typed ``Calibration`` (``result``); the calibration station (``campaign``) goes
through it too. ``corrections`` is the table the controller applies (light: numpy
only, imported by the controller); ``campaign`` and ``steps`` drive and read the calibration runs.
This package imports nothing at import time, so the controller's import of ``corrections`` stays light.
"""


def calibrate(recording, **kwargs):
    """The project's calibration of a recording (``route.calibrate``; imported on first use)."""
    from .route import calibrate as _calibrate

    return _calibrate(recording, **kwargs)
