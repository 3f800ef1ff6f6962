"""pytest side of the signal-injection path (loaded by the ``hil`` plugin).

``hil_signals`` runs a stimulus through a controller's pins and scores its gates: by default
the stimulus is exported from the plant and played into the built-in virtual controller
(:mod:`hil.signals.loopback`); on a bench with an instrument, ``--hil-signals-stimulus DIR``
and ``--hil-signals-capture FILE`` name the exported stimulus you played and the logic
analyser's capture of your controller's gates, and the same test scores that instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("hil", "BLDC pump controller HIL")
    group.addoption("--hil-signals-stimulus", default=None, metavar="DIR",
                    help="stimulus directory (hil signals export) your instrument played; with --hil-signals-capture")
    group.addoption(
        "--hil-signals-capture",
        default=None,
        metavar="FILE",
        help="gate capture (.vcd, .sr, .csv) of your controller playing it; replaces the virtual-controller loopback",
    )
    group.addoption(
        "--hil-signals-mapping", default=None, metavar="TOML", help="channel mapping of the capture (docs/signals.md)"
    )


@dataclass
class SignalRun:
    stimulus_dir: Path
    capture: Path
    source: str          #: "virtual controller loopback" or "capture FILE"
    score: object        #: hil.signals.score.Score


class SignalBench:
    def __init__(
        self, config, seed: int, workdir: Path, stimulus: str | None, capture: str | None, mapping: str | None
    ):
        if bool(stimulus) != bool(capture):
            raise pytest.UsageError("--hil-signals-stimulus and --hil-signals-capture go together")
        self.config, self.seed, self.workdir = config, seed, workdir
        self.stimulus, self.capture, self.mapping = stimulus, capture, mapping

    def run(self, effects=(), speed_rpm: float = 6000.0, duration_s: float = 0.5, strategy=None, corrections=None,
            sample_rate_hz: float = 1e6) -> SignalRun:
        """Export (plant with ``effects``), play into the virtual controller with ``strategy`` and
        ``corrections``, capture its gates, score. With a bench capture: score that."""
        from ..recording.capture import GateMapping
        from .score import score

        mapping = GateMapping.from_toml(self.mapping) if self.mapping else None
        if self.capture:
            return SignalRun(
                Path(self.stimulus),
                Path(self.capture),
                f"capture {self.capture}",
                score(self.stimulus, self.capture, mapping),
            )
        from bldc.contract import Strategy

        from ..controller.virtual import VirtualController
        from ..dut.in_process import InProcessLink
        from .export import ExportSettings, export
        from .loopback import run_loopback

        config = self.config.with_effects(*effects)
        out = self.workdir / "stimulus"
        export(
            out,
            ExportSettings(
                config=config,
                breakpoints=[(0.0, speed_rpm)],
                duration_s=duration_s,
                sample_rate_hz=sample_rate_hz,
                seed=self.seed,
                write_csv=False,
            ),
        )
        link = InProcessLink(VirtualController(config.motor, strategy=Strategy.RAW if strategy is None else strategy,
                                               speed_setpoint_rpm=speed_rpm))
        if corrections is not None:
            link.download_calibration(corrections)
        gates = self.workdir / "gates.vcd"
        run_loopback(
            out,
            link,
            gates,
            pwm_frequency_hz=config.inverter.pwm_frequency_hz,
            capture_tick_s=config.compile().timer_tick_s,
        )
        return SignalRun(out, gates, "virtual controller loopback", score(out, gates, mapping))


@pytest.fixture
def hil_signals(pytestconfig, hil_plant_config, hil_seed, tmp_path) -> SignalBench:
    """``hil_signals.run(effects=(), speed_rpm=6000, duration_s=0.5, strategy=None, corrections=None)``
    -> SignalRun (stimulus, gate capture, score against truth.csv). The virtual controller plays
    the stimulus unless --hil-signals-stimulus/--hil-signals-capture name a bench capture."""
    opt = pytestconfig.getoption
    if opt("--hil-signals-capture") is None:
        # the loopback plays the built-in controller: it judges that controller, so it says nothing
        # of a firmware in the loop or a device on a bus (their gates are judged on their own bench)
        from ..dut.spec import parse_dut

        texts = pytestconfig.getoption("--hil-dut") or pytestconfig.getini("hil_dut") or ["virtual"]
        others = [t for t in texts if not parse_dut(t).is_virtual]
        if others:
            pytest.skip(f"the signal loopback plays the built-in controller, not {others[0]}: give "
                        "--hil-signals-stimulus and --hil-signals-capture of that controller's gates")
    return SignalBench(
        hil_plant_config,
        hil_seed,
        tmp_path,
        opt("--hil-signals-stimulus"),
        opt("--hil-signals-capture"),
        opt("--hil-signals-mapping"),
    )
