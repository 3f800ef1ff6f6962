"""Candidate explanations: each effect of the library that leaves a mean edge-angle signature,
as a linear design block over the residual cells, and the map from fitted coefficients back to
the effect's parameters (in the library's own units and sign convention).

The blocks are the effects' own declarations (``plant_models.effects``, ``Effect.edge_signature``):
this module only views the registry ``EFFECTS`` as candidates, at the time it is asked, so an
effect registered there is a candidate without a line here."""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Callable

import numpy as np

from plant_models.effects import EFFECTS, Effect, OrdinarySignature


@dataclass(frozen=True)
class Candidate:
    name: str
    columns: Callable[[dict], np.ndarray]            #: cells -> (n_cells, k)
    params: Callable[[np.ndarray], dict]             #: coefficients -> effect parameters
    physical: Callable[[np.ndarray, np.ndarray], bool]  #: (coef, stderr) -> plausible?
    #: (coef, stderr) -> standard errors of the parameters; None: the parameters are linear in the
    #: coefficients, so they are ``params(stderr)``
    param_stderr: Callable[[np.ndarray, np.ndarray], dict] | None = None
    #: invisible without an encoder (a recording referenced to the turn)
    needs_encoder: bool = False

    def stderr(self, coef: np.ndarray, se: np.ndarray) -> dict:
        """Standard errors of ``params(coef)`` (model-based: from the weighted fit of the cells)."""
        if self.param_stderr is not None:
            return self.param_stderr(coef, se)
        return {k: (np.abs(v).tolist() if isinstance(v, list) else abs(v)) for k, v in self.params(se).items()}

    @property
    def fingerprint(self) -> dict:
        return dict(EFFECTS[self.name].fingerprint)


@functools.lru_cache(maxsize=None)
def _candidate(cls: type[Effect]) -> Candidate | None:
    sig = cls.edge_signature()
    if sig is None:
        return None
    return Candidate(cls.name, sig.columns, sig.params, sig.physical, sig.param_stderr, sig.needs_encoder)


class _Candidates(Mapping):
    """The registered effects that declare an edge signature, in the registry's order (read on each
    use: a registration after import counts)."""

    def __getitem__(self, name: str) -> Candidate:
        cls = EFFECTS.get(name)
        cand = _candidate(cls) if cls is not None else None
        if cand is None:
            raise KeyError(name)
        return cand

    def __iter__(self) -> Iterator[str]:
        return (name for name, cls in EFFECTS.items() if _candidate(cls) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


CANDIDATES: Mapping[str, Candidate] = _Candidates()

#: Library effects with no mean edge-angle signature are diagnosed elsewhere: edge_jitter as a
#: variance effect (diagnose._noise_gap), the electrical and mechanical ones from the sampled
#: signals (samples.py); dead_time leaves no trace in the format's signals (its declared ``no_trace``).


#: beyond the effect library: the rotor's speed ripple locked to the six-step commutation (the
#: commutation torque ripple over J w^2), largest at low speed. It moves the rotor, not a sensor,
#: and no plant effect makes it (the electrical plant's commutation ripple is its physics, not a
#: deviation to switch on), so it is a candidate of the ordinary run alone, where capture times
#: must tell it from the sensors' effects (it is accepted on real captures: docs/real-captures.md)
ROTOR_MOTION = {
    "torque_ripple": OrdinarySignature(
        "ripple", "ripple_", "angle_at_10_hz_e_contrasts_deg_e",
        "per sensor boundary, sum zero, falls with 1/speed^2: the rotor's sector-locked speed ripple",
    ),
}


class _OrdinaryCandidates(Mapping):
    """The ordinary run's candidates (capture times alone): the registered effects that declare an
    ``ordinary`` signature, in the registry's order, then the rotor's motion (ROTOR_MOTION); read
    on each use."""

    def __getitem__(self, name: str) -> OrdinarySignature:
        cls = EFFECTS.get(name)
        sig = cls.ordinary if cls is not None else ROTOR_MOTION.get(name)
        if sig is None:
            raise KeyError(name)
        return sig

    def __iter__(self) -> Iterator[str]:
        yield from (name for name, cls in EFFECTS.items() if cls.ordinary is not None)
        yield from ROTOR_MOTION

    def __len__(self) -> int:
        return sum(1 for _ in self)


ORDINARY_CANDIDATES: Mapping[str, OrdinarySignature] = _OrdinaryCandidates()
