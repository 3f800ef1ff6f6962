"""The point grid: every combination of the axes' values, its seed, its stimulus, and one run.

A point is a ``hil.bench.stimulus.Stimulus``: the campaign runs it through ``hil.bench.stimulus.run`` on the
lockstep bench against a fresh in-process virtual controller, and a failing point is saved as
that very stimulus, so ``hil replay`` re-runs exactly what the campaign ran.

Seeds: point ``i`` of a campaign with seed ``s`` gets ``SeedSequence(s, spawn_key=(i,))``'s first
32-bit word. It depends on the campaign seed and the point's place in the grid only, never on
which worker runs it or when, so results are identical under any scheduler.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
import traceback
from typing import Any

import numpy as np

from bldc.motor import steady_state

from ..bench import stimulus
from ..bench.stimulus import Stimulus
from ..controller.virtual import VirtualController
from ..dut.in_process import InProcessLink
from ..verdicts.budgets import Budget, Budgets
from .spec import CampaignSpec, point_fault, point_plant


def point_seed(campaign_seed: int, index: int) -> int:
    return int(np.random.SeedSequence(campaign_seed, spawn_key=(index,)).generate_state(1, np.uint32)[0])


def points(spec: "CampaignSpec") -> list[dict[str, Any]]:
    """The grid in order (last axis fastest, repeats innermost): one dict of axis values per point,
    plus ``index``, ``repeat`` and ``seed``."""
    out = []
    grids = itertools.product(*(a.values for a in spec.axes), range(spec.repeats))
    for index, combo in enumerate(grids):
        coords = {a.name: v for a, v in zip(spec.axes, combo[:-1])}
        out.append({"index": index, "repeat": combo[-1], "seed": point_seed(spec.seed, index), **coords})
    return out


def point_stimulus(spec: "CampaignSpec", point: dict) -> Stimulus:
    config = point_plant(spec, point)
    speed = float(point.get("speed_rpm", spec.fixed_speed_rpm))
    steady_state(config.motor, speed)  # raises on a speed the motor cannot hold
    common = dict(
        seed=point["seed"],
        speed_rpm=speed,
        test=f"campaign {spec.name} point {point['index']}",
        plant=dataclasses.replace(config, effects=()).to_dict(),
        budgets=dict(spec.checked),
    )
    effects = [e.to_dict() for e in config.effects]
    if spec.kind == "fault_sequence":
        fault = point_fault(spec, point)
        hold = float(point.get("fault_hold_s", spec.fixed_fault_hold_s))
        return Stimulus(
            "fault_sequence", effects=effects, steps=[["on", fault], ["run", hold], ["off", fault]], **common
        )
    return Stimulus(
        "deviations",
        effects=effects,
        run_s=spec.run_s,
        strategy=str(point.get("strategy", spec.fixed_strategy)),
        **common,
    )


def run_point(job: tuple) -> dict:
    """One point on the lockstep bench (runs on a worker). ``job`` = (stimulus dict, budgets
    dict); returns the measured row fields, or the error and its traceback: a point that raises
    is an error row, never the end of the campaign."""
    stim_dict, budgets_table = job
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        stim = Stimulus(**stim_dict)
        budgets = Budgets({k: Budget(**v) for k, v in budgets_table.items()}, "campaign")
        link = InProcessLink(VirtualController(stim.plant_config().motor))
        outcome = stimulus.run(stim, link, budgets)  # looked up on use, so a patched run takes effect
        row = {
            "ok": outcome.ok,
            "message": outcome.message,
            "values": outcome.values,
            "verdicts": [v.as_dict() for v in outcome.verdicts],
            "error": None,
        }
    except Exception as exc:  # noqa: BLE001 - recorded with its traceback, the campaign goes on
        row = {
            "ok": False,
            "message": f"{type(exc).__name__}: {exc}",
            "values": {},
            "verdicts": [],
            "error": traceback.format_exc(),
        }
    row["duration_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - cpu0  # with duration_s: the share of a core the worker got
    return row
