"""The typed result of ``hil twin check`` (issue 40): each figure compared, each predictor's ratio,
the sector widths and every way the twin differs, as values with their units in their names. The
JSON (docs/twin.md) is built by each part's ``to_json`` alone; a difference's sentence (the JSON's
``what`` and ``effect``) is worded here from its values, so the JSON and the readers of it
(``format_check``, hil.twin.report) say the same."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from .capture import PARTLY_HELD, UNCALIBRATABLE, NoiseModel

#: the judged band of the twin/real commutation-error ratio
RATIO_BAND = (0.67, 1.5)
#: a calibration figure differs when real and twin are further apart than this many combined
#: standard errors
SIGMA_BAND = 3.0


@dataclass(frozen=True)
class FigureComparison:
    """A calibration figure of the capture and of the twin's capture, with their combined error."""

    real: float
    twin: float
    combined_stderr: float

    @property
    def difference(self) -> float:
        return self.twin - self.real

    @property
    def beyond(self) -> bool:
        """Further apart than ``SIGMA_BAND`` combined standard errors."""
        return abs(self.difference) > SIGMA_BAND * self.combined_stderr

    def to_json(self) -> dict:
        return {"real": self.real, "twin": self.twin, "difference": self.difference,
                "combined_stderr": self.combined_stderr, "beyond": self.beyond}


@dataclass(frozen=True)
class PredictorRatio:
    """A predictor's commutation-error RMS on the capture and on the twin's capture (second half)."""

    name: str  #: "all" when the comparison refused a capture
    real_rms_deg_e: float | None
    twin_rms_deg_e: float | None
    error: str | None = None  #: which side the comparison refused, and why

    @property
    def ratio(self) -> float | None:
        r, t = self.real_rms_deg_e, self.twin_rms_deg_e
        return t / r if r and t is not None and r > 0 else None

    @property
    def within_band(self) -> bool:
        return self.ratio is not None and RATIO_BAND[0] <= self.ratio <= RATIO_BAND[1]

    def to_json(self) -> dict:
        out = {"name": self.name, "real_rms_deg_e": self.real_rms_deg_e, "twin_rms_deg_e": self.twin_rms_deg_e,
               "ratio": self.ratio, "within_band": self.within_band}
        if self.error is not None:
            out["error"] = self.error
        return out


def _nan_list(a: np.ndarray) -> list:
    return [[None if not np.isfinite(v) else float(v) for v in row] for row in a]


@dataclass
class SectorWidths:
    """Mean sector width (deg e) per edge slot (rows: the label of the edge opening the sector)
    and speed bin (columns), real and twin, with standard errors; NaN: too few sectors."""

    speed_bins_hz_e: list[float]
    real_deg_e: np.ndarray
    twin_deg_e: np.ndarray
    real_stderr_deg_e: np.ndarray
    twin_stderr_deg_e: np.ndarray

    @property
    def difference_deg_e(self) -> np.ndarray:
        return self.twin_deg_e - self.real_deg_e

    @property
    def combined_stderr_deg_e(self) -> np.ndarray:
        return np.hypot(self.twin_stderr_deg_e, self.real_stderr_deg_e)

    def to_json(self) -> dict:
        return {"speed_bins_hz_e": self.speed_bins_hz_e,
                "slots": "label of the edge opening the sector (boundary 60 m deg e, m mod 6)",
                "real_deg_e": _nan_list(self.real_deg_e),
                "twin_deg_e": _nan_list(self.twin_deg_e),
                "real_stderr_deg_e": _nan_list(self.real_stderr_deg_e),
                "twin_stderr_deg_e": _nan_list(self.twin_stderr_deg_e),
                "max_abs_difference_deg_e": float(np.nanmax(np.abs(self.difference_deg_e)))}


@dataclass
class Difference(ABC):
    """A way the twin's capture differs from the real one beyond their uncertainty; each kind
    below holds its figures and words them (``what``: the figure, ``effect``: how far apart)."""

    #: whether running the twin with an addition closed it; None where no addition was tried on it
    explained_by_adding: bool | None = field(default=None, kw_only=True)
    added: str | None = field(default=None, kw_only=True)  #: the addition that closed it

    @property
    @abstractmethod
    def what(self) -> str: ...

    @property
    @abstractmethod
    def effect(self) -> str: ...

    def to_json(self) -> dict:
        out: dict = {"what": self.what, "effect": self.effect}
        if self.explained_by_adding is not None:
            out["explained_by_adding"] = self.explained_by_adding
        if self.added is not None:
            out["added"] = self.added
        return out


@dataclass
class FigureDifference(Difference):
    name: str  #: the calibration figure
    figure: FigureComparison

    @property
    def what(self) -> str:
        return f"calibration: {self.name}"

    @property
    def effect(self) -> str:
        f = self.figure
        return (f"real {f.real:.4g}, twin {f.twin:.4g}: {abs(f.difference) / f.combined_stderr:.1f} combined "
                "standard errors apart")


@dataclass
class PredictorDifference(Difference):
    ratio: PredictorRatio  #: refused (``error``) or outside ``RATIO_BAND``

    @property
    def what(self) -> str:
        return "predictors" if self.ratio.error else f"predictor: {self.ratio.name}"

    @property
    def effect(self) -> str:
        p = self.ratio
        if p.error:
            return f"the comparison refused the capture: {p.error}"
        return (f"commutation-error RMS real {p.real_rms_deg_e}, twin {p.twin_rms_deg_e}: ratio {p.ratio} outside "
                f"{RATIO_BAND[0]}-{RATIO_BAND[1]}")


@dataclass
class WidthDifference(Difference):
    """The sector width of one slot and speed bin furthest apart in standard errors."""

    slot: int
    speed_bin: int
    difference_deg_e: float  #: twin - real
    z: float  #: in combined standard errors

    @property
    def what(self) -> str:
        return "sector widths against speed"

    @property
    def effect(self) -> str:
        return (f"slot {self.slot}, speed bin {self.speed_bin}: twin - real {self.difference_deg_e:+.2f} deg e "
                f"({self.z:.1f} standard errors)")


@dataclass
class AutocorrelationDifference(Difference):
    """The lag at which the angle residuals' autocorrelation of real and twin differ most."""

    lag: int  #: in edges, from 1
    real: float
    twin: float
    stderr: float
    pole_pairs: int | None

    @property
    def what(self) -> str:
        return "residual autocorrelation"

    def pattern(self) -> str:
        """What a pattern at this lag is (empty: none the check names)."""
        n, p = self.lag, self.pole_pairs
        if n <= 2:
            return "neighbouring edges, a colour of the edge noise the twin's jitter does not reproduce"
        if p and n % (6 * p) == 0:
            return "a whole mechanical turn, a pattern of the mechanical turn the twin lacks"
        if p and n % (3 * p) == 0:
            return "half a mechanical turn, a pattern of the mechanical turn the twin lacks"
        if n % 6 == 0:
            return "a whole electrical cycle, a sector-locked pattern the twin lacks"
        if n % 3 == 0:
            return "half an electrical cycle, a sector-locked pattern the twin lacks"
        return ""

    @property
    def effect(self) -> str:
        where = self.pattern()
        return (f"lag {self.lag}: real {self.real:+.3f}, twin {self.twin:+.3f} (standard error {self.stderr:.3f})"
                + (f": {where}" if where else ""))


@dataclass
class LeftOutDifference(Difference):
    """A measured effect no calibration table holds, so the twin's plant leaves it out: how much of
    it the capture, the twin, and the twin with it added show (RMS, deg e)."""

    name: str  #: the effect (a key of ``UNCALIBRATABLE``)
    real_rms_deg_e: float
    twin_rms_deg_e: float
    added_rms_deg_e: float

    @property
    def closed(self) -> bool:
        """The twin with it added shows it as the capture does (RMS ratio in ``RATIO_BAND``)."""
        r = self.real_rms_deg_e
        return r > 0 and RATIO_BAND[0] <= self.added_rms_deg_e / r <= RATIO_BAND[1]

    @property
    def what(self) -> str:
        beyond = f" beyond {PARTLY_HELD[self.name]}" if self.name in PARTLY_HELD else ""
        return f"left out of the twin: {self.name}{beyond}"

    @property
    def effect(self) -> str:
        return (f"the capture shows {self.real_rms_deg_e:.3f} deg e RMS, the twin {self.twin_rms_deg_e:.3f} "
                f"({self.added_rms_deg_e:.3f} with it added): measured, but no calibration table holds it, so the "
                f"twin's plant leaves it out (`hil twin from-capture {UNCALIBRATABLE[self.name]}` keeps it)")


@dataclass
class Comparison:
    """One twin run against the capture: every figure side by side, and what differs."""

    edges_real: int
    edges_twin: int
    figures_real: dict  #: ``check.calibration_figures`` of the capture
    figures_twin: dict  #: and of the twin's capture
    figures: dict[str, FigureComparison]  #: the figures both give with a standard error
    noise_real: NoiseModel
    noise_twin: NoiseModel
    acf_stderr: float  #: of an autocorrelation estimate of white noise over the capture's edges
    sector_widths: SectorWidths
    predictors: list[PredictorRatio]
    differences: list[Difference]

    def to_json(self) -> dict:
        return {
            "edges": {"real": self.edges_real, "twin": self.edges_twin},
            "calibration": {"real": self.figures_real, "twin": self.figures_twin,
                            "comparison": {k: f.to_json() for k, f in self.figures.items()}},
            "noise": {"real": self.noise_real.to_json(), "twin": self.noise_twin.to_json(),
                      "acf_stderr": self.acf_stderr},
            "sector_widths": self.sector_widths.to_json(),
            "predictors": [p.to_json() for p in self.predictors],
            "differences": [d.to_json() for d in self.differences],
        }


@dataclass
class Variant:
    """The twin run another way (with or without an addition), beside the headline."""

    comparison: Comparison
    what: str | None = None  #: what this twin is (None: the twin without additions)
    take_on: str | None = None  #: the command that makes it the headline

    def to_json(self) -> dict:
        c = self.comparison.to_json()
        out = {} if self.what is None else {"what": self.what}
        out.update(predictors=c["predictors"], calibration=c["calibration"], differences=c["differences"])
        if self.take_on is not None:
            out["take_on"] = self.take_on
        return out


@dataclass
class TwinCheck:
    """``hil twin check``'s result: the capture and its twin compared (JSON contract in docs/twin.md)."""

    recording: str
    twin_plant: str  #: the twin's plant TOML
    seed: int
    taken_on: list[str]  #: the additions the headline twin runs with
    left_out: list[str]  #: what the capture shows and the twin's plant leaves out
    capture_tick_s: float | None  #: the capture's timer tick, the twin's replay samples at it
    headline: Comparison
    without_additions: list[Difference]  #: the twin as written, against the capture
    variants: dict[str, Variant] = field(default_factory=dict)

    def replay(self) -> str:
        return ("kinematic (plant_models.kinematic.simulate_edges): the twin's rotor passes each sector boundary "
                "when the capture's fitted trajectory did, at constant speed in between, at the capture's timer "
                f"tick {(self.capture_tick_s or 0) * 1e6:.4g} us; no phase current (armature reaction does not act)")

    def to_json(self) -> dict:
        return {
            "recording": self.recording,
            "twin": self.twin_plant,
            "seed": self.seed,
            "taken_on": self.taken_on,
            "left_out": self.left_out,
            "replay": self.replay(),
            **self.headline.to_json(),
            "ratio_band": list(RATIO_BAND),
            # what the twin as written lacks, and whether an addition the capture names closes it
            "differences_without_additions": [d.to_json() for d in self.without_additions],
            "variants": {name: v.to_json() for name, v in self.variants.items()},
        }

