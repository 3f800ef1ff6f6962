"""The calibration campaign: drive the plant through the operating points the procedure needs.

Low speeds without load for the pole offsets (the paper's 960 / 1107 / 1330 rpm), a no-load
speed sweep for the conditioning delay, and loaded speeds (pump load, plus a throttled load at
the same speeds so that current moves independently of speed) for the armature reaction.
Every point runs a fixed number of mechanical turns in the kinematic mode, with the reference
encoder recorded, and the whole run is one ``hil-recording/1``. The speeds are the paper pump's;
on another motor they are the same fractions of its top speed (``PlantConfig.suite_speed_rpm``).
"""

from __future__ import annotations

from dataclasses import dataclass

from bldc.motor import steady_state
from hil.recording.drivers import record_electrical, record_kinematic
from hil.recording.format import Recording
from plant_models import PlantConfig
from plant_models.kinematic import OperatingPoint

from .corrections import Corrections
from .route import Calibration, Circuit, calibrate


@dataclass(frozen=True)
class CalibrationCampaign:
    low_speeds_rpm: tuple[float, ...] = (960.0, 1107.0, 1330.0)
    no_load_sweep_rpm: tuple[float, ...] = (2000.0, 4000.0, 6000.0, 8000.0, 10000.0)
    loaded_points: tuple[tuple[float, float], ...] = (
        (5000.0, 1.0),
        (7000.0, 1.0),
        (10000.0, 1.0),
        (7000.0, 0.5),
        (10000.0, 0.5),
    )
    turns_per_point: int = 200

    def operating_points(self, config: PlantConfig) -> list[OperatingPoint]:
        ops = []
        for rpm in self.low_speeds_rpm:
            ops.append(self._point(config, rpm, 0.0, f"pole_{rpm:.0f}"))
        for rpm in self.no_load_sweep_rpm:
            ops.append(self._point(config, rpm, 0.0, f"noload_{rpm:.0f}"))
        for rpm, load in self.loaded_points:
            ops.append(self._point(config, rpm, load, f"load{load:g}_{rpm:.0f}"))
        return ops

    def _point(self, config: PlantConfig, paper_rpm: float, load_scale: float, name: str) -> OperatingPoint:
        rpm = config.suite_speed_rpm(paper_rpm)
        current = steady_state(config.motor, rpm, load_scale)["current_a"]
        return OperatingPoint(self.turns_per_point * 60.0 / rpm, rpm, current, load_scale=load_scale, id=name)

    def run(self, config: PlantConfig, seed: int = 0) -> Recording:
        return record_kinematic(config, self.operating_points(config), seed=seed)


def station_calibration(
    config: PlantConfig,
    seed: int = 0,
    *,
    campaign: CalibrationCampaign | None = None,
    circuit: Circuit | None = None,
) -> Calibration:
    """The calibration station end to end: run the campaign on the plant and calibrate its recording
    through the front door (``route.calibrate``), so a station table gets the same bounds and
    refusals as any other calibration (a refused entry is neutral in the table, its reason in
    ``refused``)."""
    rec = (campaign or CalibrationCampaign()).run(config, seed=seed)
    return calibrate(rec, circuit=circuit, source="calibration station campaign")


def station_corrections(
    config: PlantConfig,
    seed: int = 0,
    *,
    campaign: CalibrationCampaign | None = None,
    circuit: Circuit | None = None,
) -> Corrections:
    """The station's table the controller applies (``station_calibration``'s corrections)."""
    return station_calibration(config, seed, campaign=campaign, circuit=circuit).corrections


def record_line_bemf_segments(
    config: PlantConfig,
    speeds_rpm=(960.0, 1107.0, 1330.0),
    turns: int = 20,
    seed: int = 0,
    sample_rate_hz: float = 100e3,
    reference_angle: bool = False,
) -> Recording:
    """Electrical-plant segments at the paper's calibration speeds (the same fractions of this motor's
    top speed on another motor), commutating on raw Hall edges,
    with terminal voltages and phase currents sampled (through the current sensors): what the
    Line-BEMF step (Eq. 3-5) needs from the bench."""
    speeds_rpm = [config.suite_speed_rpm(paper_rpm) for paper_rpm in speeds_rpm]
    ops = [OperatingPoint(turns * 60.0 / rpm, rpm, load_scale=1.0, id=f"linebemf_{rpm:.0f}") for rpm in speeds_rpm]
    return record_electrical(config, ops, seed=seed, sample_rate_hz=sample_rate_hz, reference_angle=reference_angle)
