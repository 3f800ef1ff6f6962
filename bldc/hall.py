"""Hall-sensor geometry and the six-step commutation table: the one place for these conventions.

The plant's kernel, the controller, calibration, gap diagnosis and the bench-signal tools all take
them from here (``docs/architecture.md``).

Conventions (``docs/recording-format.md``): in electrical degrees, for forward rotation,
A rises at 0 and falls at 180, B rises at 120 and falls at 300, C rises at 240 and falls at 60.
Magnet boundary ``k`` (rotor-fixed, every 180 deg electrical) passes sensor X at
``theta_e = 180*k + SENSOR_POSITION_DEG_E[X]``; it is caused by the leading edge of magnet pole
``k mod 2p`` (pole 0 = N1 = the pole whose arrival makes A rise at theta_m = 0).
Region ``m`` of a sensor lies between its boundaries ``m`` and ``m+1``; the sensor output is
high in even regions, so entering an even region is a rising edge.

Back-EMF: phase X has a trapezoidal shape ``f(theta_e - BEMF_ZERO_DEG_E[X])`` (rising zero
crossing at that angle), so that every Hall edge sits exactly on a Line-BEMF zero crossing
(paper Section 2.2: the A rising edge coincides with the falling zero crossing of e_BC).
"""

from __future__ import annotations

import numpy as np

SENSORS = ("A", "B", "C")
SENSOR_POSITION_DEG_E = np.array([0.0, 120.0, 240.0])
BEMF_ZERO_DEG_E = np.array([90.0, 210.0, 330.0])

# Six-step table for forward torque: sector s covers theta_e in [60 s, 60 s + 60);
# (high phase, low phase); the third phase floats.
SECTOR_PHASES = np.array([[2, 0], [2, 1], [0, 1], [0, 2], [1, 2], [1, 0]], dtype=np.int64)
SECTOR_HIGH_PHASE = np.ascontiguousarray(SECTOR_PHASES[:, 0])
SECTOR_LOW_PHASE = np.ascontiguousarray(SECTOR_PHASES[:, 1])


def hall_state(theta_e_deg: np.ndarray | float) -> np.ndarray:
    """Ideal (A, B, C) outputs at electrical angle(s) theta_e_deg."""
    th = np.asarray(theta_e_deg, dtype=float)[..., None]
    return (np.mod(th - SENSOR_POSITION_DEG_E, 360.0) < 180.0).astype(np.int64)


def hall_code(bits: np.ndarray) -> np.ndarray:
    """Hall code A*4 + B*2 + C."""
    bits = np.asarray(bits)
    return bits[..., 0] * 4 + bits[..., 1] * 2 + bits[..., 2]


# Hall code -> sector for forward rotation; codes 0 (000) and 7 (111) are illegal (-1).
SECTOR_OF_CODE = np.full(8, -1, dtype=np.int64)
for _s in range(6):
    SECTOR_OF_CODE[int(hall_code(hall_state(60.0 * _s + 30.0)))] = _s
del _s


def pin_mask(a: int, b: int, c: int) -> int:
    """The three Hall lines as a microcontroller's GPIO reads them into one value: bit 0 A, bit 1 B,
    bit 2 C (``hil-sil/1``'s ``levels``; note the order is the reverse of ``hall_code``'s)."""
    return int(a) | int(b) << 1 | int(c) << 2


def sector_of_levels(levels) -> int:
    """The forward sector of one set of Hall line levels (A, B, C; 0 or 1 each), -1 for the
    illegal codes: the scalar form of ``SECTOR_OF_CODE[hall_code(levels)]`` for code that sees
    one edge at a time (the controller)."""
    return int(SECTOR_OF_CODE[(int(levels[0]) << 2) | (int(levels[1]) << 1) | int(levels[2])])


def ideal_edge_angle_deg_e(sensor: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """Unwrapped electrical angle at which magnet boundary ``boundary`` passes ``sensor``."""
    return 180.0 * np.asarray(boundary, dtype=float) + SENSOR_POSITION_DEG_E[np.asarray(sensor)]


def trapezoid(phi_deg, flat_top_deg_e=120.0):
    """Unit trapezoidal back-EMF shape: 0 at phi=0 rising, flat +1 around 90, flat -1 around 270.

    Written with ufuncs only, so the same function serves numpy arrays here and scalars inside the
    plant's compiled kernel (which wraps it with numba instead of keeping a copy)."""
    half_ramp = (180.0 - flat_top_deg_e) * 0.5
    x = phi_deg + 90.0
    x = x - 360.0 * np.floor(x / 360.0) - 90.0  # in [-90, 270)
    # rising flank below 90 deg, falling flank above: the nearer of x and 180 - x
    return np.minimum(np.maximum(np.minimum(x, 180.0 - x) / half_ramp, -1.0), 1.0)
