"""Field-level Hall sensor model: the switching angles come out of magnet geometry, sensor
thresholds and the stator's field, not out of an effect formula.

The parts, each a typed dataclass with physical bounds:

- :class:`MagnetRing`: a ring of ``2 p`` surface poles (radius, thickness, remanence with its
  temperature coefficient), each pole with its own remanence factor and boundary placement, the
  ring's centre off the rotation axis (dynamic eccentricity: rotor-fixed) and the rotation axis
  off the stator centre (static eccentricity: stator-fixed).
- :class:`HallSwitches`: the three sensors' air gap, placement error, and switching points in mT
  (operate on a rising field, release on a falling one) with a temperature coefficient.
- :class:`StatorCoupling`: the field the phase currents make at each sensor (mT per A along the
  sensor's phase axis; sensor X sits on phase X's axis, where the rotor field crosses zero).
- the output stage: an open-collector output with pull-up, RC filter and the MCU's input
  thresholds (:class:`~plant_models.effects.ConditioningCircuit`); its delays are the RC
  crossing times of that circuit.

Field at a sensor (2-D, per mechanical harmonic n of the magnetisation, wave number n / R):
``B = sum_n c_n H_n(g) exp(i n alpha)``, ``H_n(g) = 1/2 (1 - exp(-n h / R)) exp(-n g / R)``
(the field of a magnetised layer of thickness h at distance g, planar approximation of the
cylindrical solution), with ``c_n`` the exact Fourier coefficients of the piecewise-constant
magnetisation and ``alpha`` the ring angle facing the sensor, seen from the ring's centre:
``alpha = phi - theta_m + (e_d / R_s) sin(phi - theta_m - beta_d)`` for a ring centre offset
e_d at ring angle beta_d, the sensor angle ``phi`` itself moved to
``phi + (e_s / R_s) sin(phi - gamma_s)`` by a static offset e_s towards stator angle gamma_s,
and the gap ``g - e_d cos(.) - e_s cos(.)``.

:class:`HallField` is an effect of the library: it compiles into a switching-angle table per
sensor, magnet pole and direction (what the kinematic generator and the electrical kernel read)
and a table of the current-dependent lag from the stator field (mean |i| -> deg_e), so both
generators, and the recordings made from them, see the same edges.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
from scipy.optimize import brentq

from bldc.hall import SENSOR_POSITION_DEG_E
from bldc.params import ConfigError, bounded, from_mapping, validate

from .effects import (
    EFFECTS,
    ArmatureReaction,
    ConditioningCircuit,
    ConditioningDelay,
    Eccentricity,
    Effect,
    Hysteresis,
    InstallationOffset,
    PoleOffset,
)

#: mechanical harmonics of the magnetisation kept in the field sum (per pole pair)
HARMONICS_PER_POLE_PAIR = 80
#: mean |i| grid (A) of the stator-field lag table; the kernel interpolates, clamped at the ends
CURRENT_GRID_A = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)


@dataclass(frozen=True)
class MagnetRing:
    """The rotor's sensing magnets: 2p surface poles on a ring."""

    radius_mm: float = bounded(15.0, low=1.0, high=200.0, unit="mm", doc="outer radius of the magnet ring")
    thickness_mm: float = bounded(3.0, low=0.1, high=50.0, unit="mm", doc="radial magnet thickness")
    remanence_t: float = bounded(1.2, low=0.1, high=1.5, unit="T", doc="remanence at the reference temperature")
    alpha_br_per_k: float = bounded(-0.0012, low=-0.005, high=0.0, unit="1/K", doc="remanence temperature coefficient")
    pole_remanence: tuple[float, ...] = bounded((), low=0.8, high=1.2, unit="1",
                                                doc="remanence factor of each pole (empty = all 1; else length 2 p)")
    boundary_error_deg_m: tuple[float, ...] = bounded(
        (),
        low=-2.0,
        high=2.0,
        unit="deg_m",
        doc="placement error of the boundary starting each pole (empty = none; else 2 p)",
    )
    eccentricity_mm: float = bounded(
        0.0, low=0.0, high=0.5, unit="mm", doc="ring centre off the rotation axis (dynamic, rotor-fixed)"
    )
    eccentricity_angle_deg: float = bounded(
        0.0, low=0.0, high=360.0, unit="deg_m", doc="ring angle towards which the centre is off"
    )
    static_offset_mm: float = bounded(
        0.0, low=0.0, high=0.5, unit="mm", doc="rotation axis off the stator centre (static, stator-fixed)"
    )
    static_offset_angle_deg: float = bounded(
        0.0, low=0.0, high=360.0, unit="deg_m", doc="stator angle towards which the axis is off"
    )


@dataclass(frozen=True)
class HallSwitches:
    """The three Hall switches: gap, placement, switching points (latch: operate > 0 > release)."""

    air_gap_mm: float = bounded(1.0, low=0.1, high=20.0, unit="mm", doc="sensor to magnet surface")
    position_error_deg_m: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0),
        low=-3.0,
        high=3.0,
        unit="deg_m",
        length=3,
        doc="placement error of A, B, C along the bore; + = later",
    )
    operate_mt: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=0.0, high=50.0, unit="mT", length=3, doc="switching point on a rising field (B_op)"
    )
    release_mt: tuple[float, float, float] = bounded(
        (0.0, 0.0, 0.0), low=-50.0, high=0.0, unit="mT", length=3, doc="switching point on a falling field (B_rp)"
    )
    threshold_tc_per_k: float = bounded(
        0.0, low=-0.005, high=0.005, unit="1/K", doc="temperature coefficient of B_op and B_rp"
    )


@dataclass(frozen=True)
class StatorCoupling:
    """Field of the phase currents at the sensors: sensor X on phase X's axis sees
    ``coupling * (i_x - (i_y + i_z) / 2) = 1.5 coupling i_x``."""

    coupling_mt_per_a: float = bounded(
        0.0,
        low=-20.0,
        high=20.0,
        unit="mT/A",
        doc="field at a sensor per ampere along its phase axis; + opposes the rotor field at the edge",
    )


def _is_neutral(obj) -> bool:
    return obj == type(obj)()


@dataclass(frozen=True)
class HallField(Effect):
    """Field-level Hall sensing: magnet ring, Hall switches in mT, stator field, open-collector output.

    Physics: each sensor switches where the rotor's field plus the stator's field at it crosses
    its operate (rising) or release (falling) point; the ring's geometry (per-pole remanence,
    boundary placement, dynamic and static eccentricity) and the sensors' placement set where
    the rotor field crosses; the output's pull-up, RC filter and MCU thresholds delay the
    captured edge. Defaults are an ideal ring, ideal sensors, no stator field and no output
    filter: the ideal edges.
    Parameters: ``temperature_rise_k`` and four sub-tables, ``ring``, ``sensors``, ``stator`` and
    ``output`` (the open-collector circuit; absent = no filter), e.g. in TOML
    ``ring = { eccentricity_mm = 0.05 }``.
    Fingerprint: whatever the mechanism makes; docs/gap.md maps each cause to the library effect
    that explains it.
    """

    name: ClassVar[str] = "hall_field"
    layer: ClassVar[str] = "sensor"
    fingerprint: ClassVar[Mapping[str, str]] = {
        "signature": "the mechanism's own (docs/gap.md maps each cause to a library effect)",
        "scales_with": "geometry, temperature and phase current",
        "knob": "-",
    }
    #: nested parameter tables (TOML sub-tables of the effect)
    parts: ClassVar[Mapping[str, type]] = {
        "ring": MagnetRing,
        "sensors": HallSwitches,
        "stator": StatorCoupling,
        "output": ConditioningCircuit,
    }
    ring: MagnetRing = field(default_factory=MagnetRing)
    sensors: HallSwitches = field(default_factory=HallSwitches)
    stator: StatorCoupling = field(default_factory=StatorCoupling)
    output: ConditioningCircuit | None = None
    temperature_rise_k: float = bounded(
        0.0, low=-40.0, high=150.0, unit="K", doc="sensor and magnet temperature above the reference"
    )

    def check(self, pole_pairs, prefix):
        validate(self, prefix)
        validate(self.ring, f"{prefix}ring.")
        validate(self.sensors, f"{prefix}sensors.")
        validate(self.stator, f"{prefix}stator.")
        for name in ("pole_remanence", "boundary_error_deg_m"):
            v = getattr(self.ring, name)
            if v and len(v) != 2 * pole_pairs:
                raise ConfigError(
                    f"{prefix}ring.{name}",
                    f"expected {2 * pole_pairs} values (one per magnet pole) or none, got {len(v)}",
                )
        if self.output is not None:
            validate(self.output, f"{prefix}output.")
            self.output.delays_s()  # thresholds inside the swing
        g_min = self.sensors.air_gap_mm - self.ring.eccentricity_mm - self.ring.static_offset_mm
        if g_min <= 0.05:
            raise ConfigError(
                f"{prefix}sensors.air_gap_mm",
                f"the eccentricities close the gap to {g_min:.3g} mm; the ring would touch a sensor",
            )

    def to_dict(self) -> dict[str, Any]:
        def plain(obj):
            return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(obj).items()}

        out = {
            "name": self.name,
            "ring": plain(self.ring),
            "sensors": plain(self.sensors),
            "stator": plain(self.stator),
            "temperature_rise_k": self.temperature_rise_k,
        }
        if self.output is not None:
            out["output"] = plain(self.output)
        return out

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], prefix: str) -> "HallField":
        data = dict(data)
        parts = {}
        for key, kind in (
            ("ring", MagnetRing),
            ("sensors", HallSwitches),
            ("stator", StatorCoupling),
            ("output", ConditioningCircuit),
        ):
            if key in data:
                table = data.pop(key)
                if not isinstance(table, Mapping):
                    raise ConfigError(f"{prefix}{key}", "expected a table")
                parts[key] = from_mapping(kind, table, f"{prefix}{key}.")
        return dataclasses.replace(from_mapping(cls, data, prefix), **parts)

    @classmethod
    def strategy(cls, pole_pairs: int = 2):
        from hypothesis import strategies as st

        def f(lo, hi):
            return st.floats(lo, hi, allow_nan=False)

        ring = st.builds(
            MagnetRing,
            eccentricity_mm=f(0.0, 0.2),
            eccentricity_angle_deg=f(0.0, 360.0),
            static_offset_mm=f(0.0, 0.2),
            pole_remanence=st.tuples(*([f(0.9, 1.1)] * (2 * pole_pairs))),
        )
        sensors = st.builds(
            HallSwitches,
            operate_mt=st.tuples(f(0.0, 10.0), f(0.0, 10.0), f(0.0, 10.0)),
            release_mt=st.tuples(f(-10.0, 0.0), f(-10.0, 0.0), f(-10.0, 0.0)),
        )
        return st.builds(
            cls,
            ring=ring,
            sensors=sensors,
            stator=st.builds(StatorCoupling, coupling_mt_per_a=f(0.0, 2.0)),
            temperature_rise_k=f(-20.0, 80.0),
        )

    # --- the physics -------------------------------------------------------------------------
    def model(self, pole_pairs: int) -> "FieldModel":
        return FieldModel(self, pole_pairs)

    def contribute(self, plant):
        if not (_is_neutral(self.ring) and _is_neutral(self.sensors) and _is_neutral(self.stator)):
            table, lag = _tables(self, plant.pole_pairs)
            plant.switch_offset_deg_e = plant.switch_offset_deg_e + table
            plant.field_current_a = np.asarray(CURRENT_GRID_A, dtype=float)
            plant.field_lag_deg_e = plant.field_lag_deg_e + lag if plant.field_lag_deg_e.size else lag.copy()
        if self.output is not None:
            rise, fall = self.output.delays_s()
            plant.rise_delay_s += rise
            plant.fall_delay_s += fall


class FieldModel:
    """The field of one :class:`HallField` on a motor with ``pole_pairs``, and where it switches."""

    def __init__(self, hf: HallField, pole_pairs: int):
        self.hf, self.p = hf, pole_pairs
        ring, sen = hf.ring, hf.sensors
        n_poles = 2 * pole_pairs
        self.radius_sensor_mm = ring.radius_mm + sen.air_gap_mm
        rem = np.asarray(ring.pole_remanence or (1.0,) * n_poles, dtype=float)
        err = np.radians(np.asarray(ring.boundary_error_deg_m or (0.0,) * n_poles, dtype=float))
        t_scale = 1.0 + ring.alpha_br_per_k * hf.temperature_rise_k
        # boundary k at ring angle -k pi / p (it passes sensor A at theta_e = 180 k), pole k from
        # boundary k to k + 1, positive for even k (an even region: the output is high)
        edges = -np.arange(n_poles + 1) * math.pi / pole_pairs + np.append(err, err[0])
        m = ring.remanence_t * 1e3 * t_scale * rem * np.where(np.arange(n_poles) % 2 == 0, 1.0, -1.0)  # mT
        n = np.arange(1, HARMONICS_PER_POLE_PAIR * pole_pairs + 1)
        # c_n = 1/(2 pi) sum_k m_k int_{a_{k+1}}^{a_k} exp(-i n a) da
        c = np.zeros(n.size, dtype=complex)
        for k in range(n_poles):
            c += m[k] * (np.exp(-1j * n * edges[k]) - np.exp(-1j * n * edges[k + 1])) / (-1j * n)
        self.c = c / (2 * math.pi)
        self.n = n
        self.thr_scale = 1.0 + sen.threshold_tc_per_k * hf.temperature_rise_k
        self._grids: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def sensor_angle_rad(self, x: int) -> float:
        """Stator angle of sensor x as seen from the rotation axis (placement and static offset)."""
        ring, sen = self.hf.ring, self.hf.sensors
        phi = math.radians((SENSOR_POSITION_DEG_E[x]) / self.p + sen.position_error_deg_m[x])
        gamma = math.radians(ring.static_offset_angle_deg)
        return phi + ring.static_offset_mm / self.radius_sensor_mm * math.sin(phi - gamma)

    def field_mt(self, x: int, theta_e_deg: np.ndarray) -> np.ndarray:
        """Rotor field at sensor x (mT, + = the even poles' polarity) at electrical angles."""
        ring, sen = self.hf.ring, self.hf.sensors
        th_m = np.radians(np.asarray(theta_e_deg, dtype=float)) / self.p
        phi = self.sensor_angle_rad(x)
        phi0 = math.radians(SENSOR_POSITION_DEG_E[x] / self.p + sen.position_error_deg_m[x])
        beta, gamma = math.radians(ring.eccentricity_angle_deg), math.radians(ring.static_offset_angle_deg)
        a0 = phi - th_m
        alpha = a0 + ring.eccentricity_mm / self.radius_sensor_mm * np.sin(a0 - beta)
        gap = sen.air_gap_mm - ring.eccentricity_mm * np.cos(a0 - beta) - ring.static_offset_mm * math.cos(phi0 - gamma)
        k = self.n / ring.radius_mm  # wave number per mm
        h = 0.5 * (1.0 - np.exp(-k * ring.thickness_mm))
        terms = self.c[None, :] * h[None, :] * np.exp(-np.outer(gap, k)) * np.exp(1j * np.outer(alpha, self.n))
        return 2.0 * np.real(terms.sum(axis=1))

    def _grid(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """The field of sensor x over one mechanical turn (and 90 deg_e either side) on a
        0.25 deg_e grid, computed once: it brackets every crossing."""
        if x not in self._grids:
            th = np.arange(-90.0, 360.0 * self.p + 90.0, 0.25)
            self._grids[x] = (th, self.field_mt(x, th))
        return self._grids[x]

    def threshold_mt(self, x: int, rising_field: bool) -> float:
        sen = self.hf.sensors
        return (sen.operate_mt[x] if rising_field else sen.release_mt[x]) * self.thr_scale

    def stator_mt(self, mean_abs_current_a: float) -> float:
        """Stator field at a sensor at its edge, against the rotor field's change: the two phases
        conduct +-I with mean |i| = 2 I / 3, and the sensor's own phase carries -I on a rising
        field (the sector before the edge), so it sees 1.5 * coupling * I opposing."""
        return 1.5 * self.hf.stator.coupling_mt_per_a * 1.5 * mean_abs_current_a

    def switch_angle_deg_e(self, x: int, boundary: int, direction: int, mean_abs_current_a: float = 0.0) -> float:
        """Electrical angle at which sensor x switches on ``boundary`` turning ``direction``."""
        nominal = 180.0 * boundary + SENSOR_POSITION_DEG_E[x]
        rising_field = (boundary % 2 == 0) == (direction > 0)  # even boundaries enter a positive pole forward
        sign = 1.0 if rising_field else -1.0
        target = self.threshold_mt(x, rising_field) + sign * self.stator_mt(mean_abs_current_a)

        def f(th):
            return float(self.field_mt(x, np.array([th]))[0]) - target

        # the crossing nearest the boundary; in angle the field rises through even boundaries
        grid, b = self._grid(x)
        near = np.abs(grid - nominal % (360.0 * self.p)) <= 75.0
        grid = grid[near] + (nominal - nominal % (360.0 * self.p))
        s = (b[near] - target) * (1.0 if boundary % 2 == 0 else -1.0)
        cross = np.nonzero((s[:-1] < 0) & (s[1:] >= 0))[0]
        if cross.size == 0:
            raise ConfigError(
                "hall_field",
                f"sensor {'ABC'[x]} never reaches {target:.3g} mT near boundary {boundary}: "
                "thresholds beyond the field at this gap",
            )
        i = cross[np.argmin(np.abs(grid[cross] - nominal))]
        fa, fb = f(grid[i]), f(grid[i + 1])
        if fa * fb > 0.0:  # a crossing at a grid point, within rounding
            return float(grid[i] if abs(fa) < abs(fb) else grid[i + 1])
        return brentq(f, grid[i], grid[i + 1], xtol=1e-10)

    def switch_table_deg_e(self) -> np.ndarray:
        """(3, 2p, 2) switching-angle offsets at zero current: [sensor, pole, forward / reverse]
        (the boundary starting pole j, crossed forward or backward), deg_e, absolute (not lag)."""
        n_poles = 2 * self.p
        out = np.zeros((3, n_poles, 2))
        for x in range(3):
            for j in range(n_poles):
                nominal = 180.0 * j + SENSOR_POSITION_DEG_E[x]
                for col, d in ((0, 1), (1, -1)):
                    out[x, j, col] = self.switch_angle_deg_e(x, j, d) - nominal
        return out

    def stator_lag_table_deg_e(self) -> np.ndarray:
        """Lag (deg_e, in the direction of motion) the stator field adds at each current of
        CURRENT_GRID_A, averaged over sensors, poles and directions (the spread between edges is
        second order in the field's curvature)."""
        if self.hf.stator.coupling_mt_per_a == 0.0:
            return np.zeros(len(CURRENT_GRID_A))
        n_poles = 2 * self.p
        # beyond the current at which the stator field cancels 90 % of the rotor's peak the
        # sensor would stop switching altogether; the table ends there (clamped beyond)
        peak = min(float(np.max(np.abs(self._grid(x)[1]))) for x in range(3))
        thr = max(max(self.hf.sensors.operate_mt), -min(self.hf.sensors.release_mt)) * abs(self.thr_scale)
        i_max = max(0.9 * peak - thr, 0.0) / abs(2.25 * self.hf.stator.coupling_mt_per_a)
        zero = {(x, j, d): self.switch_angle_deg_e(x, j, d) for x in range(3) for j in range(n_poles) for d in (1, -1)}
        lags = []
        for i in CURRENT_GRID_A:
            if i == 0.0 or i > i_max:
                lags.append(lags[-1] if lags else 0.0)
                continue
            acc = []
            for x in range(3):
                for j in range(n_poles):
                    for d in (1, -1):
                        acc.append(d * (self.switch_angle_deg_e(x, j, d, i) - zero[(x, j, d)]))
            lags.append(float(np.mean(acc)))
        return np.asarray(lags)

    def slope_mt_per_deg_e(self) -> float:
        """Mean |dB/dtheta_e| of the rotor field at its zero crossings (the gain from mT to angle)."""
        out = []
        for x in range(3):
            for j in range(2 * self.p):
                th = 180.0 * j + SENSOR_POSITION_DEG_E[x]
                b = self.field_mt(x, np.array([th - 0.01, th + 0.01]))
                out.append(abs(b[1] - b[0]) / 0.02)
        return float(np.mean(out))


@functools.lru_cache(maxsize=256)
def _tables(hf: HallField, pole_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """(switching-angle table, stator lag table) of a field model, computed once per model:
    a plant compiles often, and every root is a field sum over hundreds of harmonics."""
    m = hf.model(pole_pairs)
    table, lag = m.switch_table_deg_e(), m.stator_lag_table_deg_e()
    table.setflags(write=False)
    lag.setflags(write=False)
    return table, lag


EFFECTS[HallField.name] = HallField


# --- causes: the field model's physical parameters, each with the library effect that explains it ---
#
# ``hil gap validate --generator field`` withholds these (docs/gap.md, "Causes and the library
# effects that explain them"). A cause declares its physical parameter, the library effect that
# should explain it, how a case draws it (its fixed parts from the case's random generator, then a
# size factor the validation scales to the drawn signal-to-noise), and the magnitude of that effect
# its parameter implies by first-order physics. R_s is the sensor radius (ring radius plus air gap);
# dB/dtheta the ring field's slope at its zero crossings (mT per deg_e).

#: temperature coefficient of the Hall switching points drawn with a hysteresis band (an
#: uncompensated CMOS Hall latch drifts by about -0.1 %/K)
THRESHOLD_TC_PER_K = -0.001


class FieldCause:
    """One physical cause of the field model, declared once: every route that withholds or
    scores it reads this."""

    name: ClassVar[str] = ""
    #: the physical parameter drawn (words, for the tables)
    parameter: ClassVar[str] = ""
    #: the library effect that should explain it
    explained_by: ClassVar[type[Effect]] = Effect

    def draw(self, rng: np.random.Generator, pole_pairs: int) -> Callable[[float], HallField]:
        """Draw the case's fixed parts; returns size factor -> field model (factor 1: the unit size)."""
        raise NotImplementedError

    def implied(self, hf: HallField, pole_pairs: int) -> Effect:
        """The library effect with the magnitude ``hf``'s physical parameter implies."""
        raise NotImplementedError


def _sensor_radius_mm(hf: HallField) -> float:
    return hf.ring.radius_mm + hf.sensors.air_gap_mm


def _nominal_slope_mt_per_deg_e(pole_pairs: int) -> float:
    return HallField().model(pole_pairs).slope_mt_per_deg_e()


class _RingOffsetCause(FieldCause):
    """A ring or axis off centre: a size in mm (0.05 mm per unit, within the ring's bounds)
    towards an angle drawn uniformly."""

    offset_field: ClassVar[str] = ""
    angle_field: ClassVar[str] = ""

    def draw(self, rng, pole_pairs):
        angle = float(rng.uniform(0.0, 360.0))
        return lambda s: HallField(
            ring=MagnetRing(**{self.offset_field: float(np.clip(0.05 * s, 0.0, 0.5)), self.angle_field: angle})
        )


class DynamicEccentricityCause(_RingOffsetCause):
    """Ring centre off the rotation axis by e (mm): eccentricity of amplitude ``p e / R_s`` (rad, as deg_e)."""

    name = "dynamic_eccentricity"
    parameter = "ring centre off the axis, e (mm)"
    explained_by = Eccentricity

    offset_field = "eccentricity_mm"
    angle_field = "eccentricity_angle_deg"

    def implied(self, hf, pole_pairs):
        return Eccentricity(math.degrees(pole_pairs * hf.ring.eccentricity_mm / _sensor_radius_mm(hf)), 0.0)


class StaticEccentricityCause(_RingOffsetCause):
    """Rotation axis off the stator centre by e (mm) towards gamma: an installation offset of
    ``p (e / R_s) sin(phi_x - gamma)`` per sensor (phi_x: the sensor's stator angle)."""

    name = "static_eccentricity"
    parameter = "rotation axis off the stator centre, e (mm), towards gamma"
    explained_by = InstallationOffset

    offset_field = "static_offset_mm"
    angle_field = "static_offset_angle_deg"

    def implied(self, hf, pole_pairs):
        phi = np.radians(SENSOR_POSITION_DEG_E / pole_pairs)
        gamma = math.radians(hf.ring.static_offset_angle_deg)
        shift_rad = pole_pairs * hf.ring.static_offset_mm / _sensor_radius_mm(hf) * np.sin(phi - gamma)
        return InstallationOffset(tuple(float(v) for v in np.degrees(shift_rad)))


class PoleMagnetisationCause(FieldCause):
    """Per-pole remanence and boundary placement: a pole offset where the ring's own field
    crosses zero, per pole boundary (field geometry, all sensors alike)."""

    name = "pole_magnetisation"
    parameter = "per-pole remanence and boundary placement"
    explained_by = PoleOffset

    def draw(self, rng, pole_pairs):
        rem = rng.uniform(-1.0, 1.0, 2 * pole_pairs)
        err = rng.uniform(-1.0, 1.0, 2 * pole_pairs)
        return lambda s: HallField(
            ring=MagnetRing(
                pole_remanence=tuple(float(np.clip(1.0 + 0.02 * s * r, 0.8, 1.2)) for r in rem),
                boundary_error_deg_m=tuple(float(np.clip(0.05 * s * e, -2.0, 2.0)) for e in err),
            )
        )

    def implied(self, hf, pole_pairs):
        zero = HallField(ring=hf.ring).model(pole_pairs).switch_table_deg_e()[:, :, 0].mean(axis=0)
        return PoleOffset(tuple(float(v) for v in zero))


class HysteresisBandCause(FieldCause):
    """B_op = -B_rp = b / 2 (mT) at a temperature rise dT: hysteresis of
    ``(b / 2) (1 + tc dT) / (dB/dtheta (1 + alpha_Br dT))``."""

    name = "hysteresis_band"
    parameter = "B_op = -B_rp = b / 2 (mT) at a temperature"
    explained_by = Hysteresis

    def draw(self, rng, pole_pairs):
        dt = float(rng.uniform(-20.0, 80.0))

        def make(s):
            b = float(np.clip(2.0 * s, 0.0, 100.0))
            return HallField(
                sensors=HallSwitches(
                    operate_mt=(b / 2,) * 3, release_mt=(-b / 2,) * 3, threshold_tc_per_k=THRESHOLD_TC_PER_K
                ),
                temperature_rise_k=dt,
            )

        return make

    def implied(self, hf, pole_pairs):
        sen, dt = hf.sensors, hf.temperature_rise_k
        nominal = _nominal_slope_mt_per_deg_e(pole_pairs)
        b_half = 0.5 * (sen.operate_mt[0] - sen.release_mt[0]) * (1 + sen.threshold_tc_per_k * dt)
        return Hysteresis(b_half / (nominal * (1 + hf.ring.alpha_br_per_k * dt)))


class StatorFieldCause(FieldCause):
    """Stator coupling k (mT/A) along the sensor's phase axis: armature reaction of
    ``2.25 k / (dB/dtheta)`` per A of mean abs(i)."""

    name = "stator_field"
    parameter = "coupling (mT/A)"
    explained_by = ArmatureReaction

    def draw(self, rng, pole_pairs):
        sign = float(rng.choice([-1.0, 1.0]))  # a sensor on the phase axis's far side sees the field reversed: it leads
        return lambda s: HallField(stator=StatorCoupling(float(np.clip(sign * s, -20.0, 20.0))))

    def implied(self, hf, pole_pairs):
        return ArmatureReaction(2.25 * hf.stator.coupling_mt_per_a / _nominal_slope_mt_per_deg_e(pole_pairs))


class OutputFilterCause(FieldCause):
    """Pull-up and filter capacitor of an open-collector output: a conditioning delay of the
    circuit's RC crossing times."""

    name = "output_filter"
    parameter = "pull-up and filter capacitor"
    explained_by = ConditioningDelay

    def draw(self, rng, pole_pairs):
        r2 = float(rng.uniform(2.2e3, 10e3))
        ratio = float(rng.uniform(0.3, 1.0))
        return lambda s: HallField(
            output=ConditioningCircuit(r2_ohm=r2, r1_ohm=ratio * 50.0, c1_f=float(np.clip(1e-9 * s, 1e-12, 1e-6)))
        )

    def implied(self, hf, pole_pairs):
        return ConditioningDelay(*hf.output.delays_s())


#: every field cause, in the order the validation plans its cases (its seeds depend on it)
FIELD_CAUSES: tuple[FieldCause, ...] = (
    DynamicEccentricityCause(),
    StaticEccentricityCause(),
    PoleMagnetisationCause(),
    HysteresisBandCause(),
    StatorFieldCause(),
    OutputFilterCause(),
)
