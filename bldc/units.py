"""Unit conversions between the speeds and angles the plant, the controller and the tools use.

One place for them, so that a speed in rpm becomes the same electrical rate everywhere. The
arithmetic order is fixed: changing it would change results in their last bit.
"""

from __future__ import annotations

import math

SECONDS_PER_MINUTE = 60.0
DEG_PER_REV = 360.0
#: one mechanical rpm is 6 mechanical degrees per second
DEG_PER_S_PER_RPM = DEG_PER_REV / SECONDS_PER_MINUTE


def rpm_to_deg_e_per_s(speed_rpm, pole_pairs):
    """Electrical angular speed in deg e/s of a mechanical speed in rpm."""
    return speed_rpm * 6.0 * pole_pairs


def deg_e_per_s_to_rpm(speed_deg_e_per_s, pole_pairs):
    """Mechanical speed in rpm of an electrical angular speed in deg e/s."""
    return speed_deg_e_per_s / (6.0 * pole_pairs)


def rpm_to_rad_per_s(speed_rpm):
    """Mechanical angular speed in rad/s of a speed in rpm."""
    return speed_rpm * 2 * math.pi / 60


def rad_per_s_to_rpm(speed_rad_per_s):
    """Speed in rpm of a mechanical angular speed in rad/s."""
    return speed_rad_per_s * 60 / (2 * math.pi)


def rad_e_per_s_to_rpm(speed_rad_e_per_s, pole_pairs):
    """Mechanical speed in rpm of an electrical angular speed in rad/s."""
    return speed_rad_e_per_s / pole_pairs * 60 / (2 * math.pi)


def edges_per_s(speed_rpm, pole_pairs):
    """Hall edges per second at a mechanical speed: six per electrical period."""
    return speed_rpm / 60.0 * 6 * pole_pairs
