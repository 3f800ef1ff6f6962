"""The plant as the kernels read it: a flat numeric view of a ``PlantConfig`` with every effect folded in.

``PlantConfig.compile`` builds it; each effect adds its share in ``Effect.contribute``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .sensor import ARMATURE_SHIFT_LIMIT_DEG_E


@dataclass
class CompiledPlant:
    """Flat numeric view of a PlantConfig with every effect folded in (what the kernels read)."""

    pole_pairs: int
    phase_resistance_ohm: float
    phase_inductance_h: float
    ke_v_s_per_rad: float
    flat_top_deg_e: float
    inertia_kg_m2: float
    friction_n_m_s_per_rad: float
    fan_coefficient_n_m_s2: float
    supply_v: float
    pwm_frequency_hz: float
    sensor_offset_deg_e: np.ndarray
    pole_offset_deg_e: np.ndarray
    hysteresis_deg_e: float = 0.0
    armature_slope_deg_e_per_a: float = 0.0
    armature_table_current_a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    armature_table_offset_deg_e: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rise_delay_s: float = 0.0
    fall_delay_s: float = 0.0
    jitter_time_rms_s: float = 0.0
    jitter_angle_rms_deg_e: float = 0.0
    jitter_correlation: float = 0.0
    timer_tick_s: float = 0.0
    cogging_amplitude_n_m: float = 0.0
    cogging_periods_per_rev: int = 12
    cogging_phase_rad: float = 0.0
    dead_time_s: float = 0.0
    saturation_current_a: float = 20.0
    min_inductance_fraction: float = 1.0
    #: switching-angle offsets [sensor, pole, forward / reverse] beyond sensor and pole offsets
    #: (deg_e, absolute; the field-level Hall model writes it, plant_models.hall_field)
    switch_offset_deg_e: np.ndarray = field(default_factory=lambda: np.zeros((3, 0, 2)))
    #: the field model's current-dependent lag: mean |i| (A) -> deg_e, interpolated, clamped
    field_current_a: np.ndarray = field(default_factory=lambda: np.zeros(0))
    field_lag_deg_e: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def armature_offset_deg_e(self, current_a):
        """Current-dependent lag (deg_e): armature reaction plus the field model's stator field."""
        current_a = np.asarray(current_a, dtype=float)
        if self.armature_table_current_a.size:
            out = np.interp(current_a, self.armature_table_current_a, self.armature_table_offset_deg_e)
        else:
            limit = ARMATURE_SHIFT_LIMIT_DEG_E
            out = np.clip(self.armature_slope_deg_e_per_a * current_a, -limit, limit)
        if self.field_lag_deg_e.size:
            out = out + np.interp(current_a, self.field_current_a, self.field_lag_deg_e)
        return out

    def armature_table(self) -> tuple[np.ndarray, np.ndarray]:
        """The current-dependent lag as one (current, lag) table for the kernel (empty: the
        linear slope alone, which the kernel applies itself)."""
        if not self.armature_table_current_a.size and not self.field_lag_deg_e.size:
            return self.armature_table_current_a, self.armature_table_offset_deg_e
        grid = np.union1d(self.armature_table_current_a, self.field_current_a)
        if not self.armature_table_current_a.size:  # a slope becomes exact on a grid reaching far enough
            slope = abs(self.armature_slope_deg_e_per_a)
            grid = np.union1d(grid, [1e4, *([ARMATURE_SHIFT_LIMIT_DEG_E / slope] if slope else [])])  # and its knee
        return grid, self.armature_offset_deg_e(grid)

    def switch_table_deg_e(self) -> np.ndarray:
        """Every zero-current switching-angle offset as one table [sensor, pole, forward / reverse]
        (deg_e): installation and pole offsets plus the field model's. What the kernel reads."""
        t = self.sensor_offset_deg_e[:, None, None] + self.pole_offset_deg_e[None, :, None]
        return np.broadcast_to(t, (3, self.pole_offset_deg_e.size, 2)) + self.switch_offset_deg_e
