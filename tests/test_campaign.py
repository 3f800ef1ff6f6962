"""Campaigns: SPEC errors, the grid and its seeds, measured values against the plant's truth,
replays, and the same table on any scheduler (serial, a loopback Dask cluster of two workers),
with a worker killed mid-run, a point that raises, and an interrupted run."""

from __future__ import annotations

import json
import math
import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bldc.params import ConfigError
from hil.campaign import dispatch, load_spec, read_table, run_campaign
from hil.campaign.envelope import margin_grid
from hil.campaign.grid import point_seed, point_stimulus, points, run_point
from hil.campaign.scheduler import TaskError
from hil.bench.stimulus import Stimulus

#: raw Hall commutation with installation offsets: the commutation lands where the sensor's edge
#: is, so its error against the plant's true rotor angle is the offset itself (deg e), plus the
#: edge jitter (0.1 us: 0.011 deg e RMS at 9000 rpm), which makes every figure depend on the seed
SPEC = """
[campaign]
name = "unit"
seed = 5
run_s = 0.1
[campaign.budgets]
commutation_angle_p99 = "angle_p99"
[fixed]
strategy = "raw"
effects = [{ name = "edge_jitter", time_rms_s = 1e-7 }]
[[axis]]
name = "installation_offset.offset_deg_e"
values = [0.0, 0.3, 0.8]
pattern = [1.0, -0.5, 0.25]
[[axis]]
name = "speed_rpm"
values = [4000.0, 9000.0]
"""
#: columns that are timings or paths, not results
NOT_RESULTS = ["duration_s", "cpu_s", "replay"]


def write_spec(tmp_path: Path, text: str = SPEC, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def results(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=NOT_RESULTS).reset_index(drop=True)


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    """The reference: every point in this process (also compiles the plant kernel before workers start)."""
    tmp = tmp_path_factory.mktemp("serial")
    spec = load_spec(write_spec(tmp))
    return run_campaign(spec, tmp / "out", scheduler="serial", progress=False)


@pytest.fixture(scope="module")
def loopback_cluster():
    """A Dask scheduler and two single-threaded worker processes on 127.0.0.1, started here."""
    from distributed import LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=":0")
    yield cluster
    cluster.close()


BAD_SPECS = [
    (SPEC.replace("pattern = [1.0, -0.5, 0.25]\n", ""), "axis[0].pattern"),
    (SPEC.replace("values = [0.0, 0.3, 0.8]", "values = [0.0, 30.0]"), "axis[0].values[1]"),
    (SPEC.replace('name = "speed_rpm"', 'name = "sped_rpm"'), "axis[1].name"),
    (SPEC.replace('strategy = "raw"', 'strategy = "fast"'), "fixed.strategy"),
    (
        SPEC.replace('commutation_angle_p99 = "angle_p99"', 'commutation_angle_p99 = "p95"'),
        "campaign.budgets.commutation_angle_p99",
    ),
    (
        SPEC.replace('commutation_angle_p99 = "angle_p99"', 'no_such_budget = "angle_p99"'),
        "campaign.budgets.no_such_budget",
    ),
    (SPEC.replace("seed = 5", "seed = -5"), "campaign.seed"),
    (SPEC.replace("run_s = 0.1", "run_s = 0.1\nworkers = 3"), "[campaign].workers"),
    (SPEC.replace('values = [4000.0, 9000.0]', 'values = [4000.0, 9000.0]\nstep = 1'), "[[axis]][1].step"),
    ("[campaign]\nname = 'x'\n[axes]\n", "axes"),
    (SPEC + '[map]\nx = "speed_rpm"\ny = "load_scale"\n', "map.y"),
    (SPEC.replace("values = [4000.0, 9000.0]", "linspace = [4000.0, 9000.0]"), "axis[1].linspace"),
    (SPEC + '[[axis]]\nname = "fault.sensor"\nvalues = [0.0]\n', "axis[2].name"),
    (
        SPEC.replace(
            'effects = [{ name = "edge_jitter"',
            'effects = [{ name = "pole_offset", offset_deg_e = [1.0, 2.0] }, { name = "edge_jitter"',
        ),
        "fixed.effects[0].offset_deg_e",
    ),
    ("[campaign\n", "not valid TOML"),
]


@pytest.mark.parametrize("text, where", BAD_SPECS, ids=[where for _, where in BAD_SPECS])
def test_a_bad_spec_names_file_and_key(tmp_path, text, where):
    with pytest.raises(ConfigError) as info:
        load_spec(write_spec(tmp_path, text))
    assert str(info.value).startswith(f"{tmp_path / 'spec.toml'}: {where}"), str(info.value)


def test_grid_order_and_seeds(tmp_path):
    spec = load_spec(write_spec(tmp_path, SPEC.replace("seed = 5", "seed = 5\nrepeats = 2")))
    grid = points(spec)
    assert spec.size == len(grid) == 3 * 2 * 2
    # last axis fastest, repeats innermost
    assert [(p["installation_offset.offset_deg_e"], p["speed_rpm"], p["repeat"]) for p in grid[:4]] == [
        (0.0, 4000.0, 0),
        (0.0, 4000.0, 1),
        (0.0, 9000.0, 0),
        (0.0, 9000.0, 1),
    ]
    seeds = [p["seed"] for p in grid]
    assert len(set(seeds)) == len(seeds)
    assert seeds == [point_seed(5, i) for i in range(len(grid))]
    assert point_seed(6, 0) != point_seed(5, 0)
    stim = point_stimulus(spec, grid[5])
    assert (
        stim.effects[1:] == [{"name": "installation_offset", "offset_deg_e": [0.3, -0.15, 0.075]}]
        and stim.strategy == "raw"
    )


def test_measured_angle_error_is_the_offset_and_failures_replay(serial_run):
    table = read_table(serial_run.paths["table"])
    assert len(table) == 6 and set(table["verdict"]) <= {"pass", "marginal", "fail"}
    from hil.verdicts.budgets import Budgets

    limit = Budgets.defaults()["commutation_angle_p99"].limit  # the default (hil/verdicts/budget_sources.py): 0.6 deg e
    for _, row in table.iterrows():
        offset = row["installation_offset.offset_deg_e"]  # sensor A's, the largest of the pattern
        assert abs(row["angle_p99_deg_e"] - offset) < 0.05, row
        assert row["commutation_angle_p99.margin"] == pytest.approx(limit - row["angle_p99_deg_e"])
        assert row["verdict"] == ("fail" if offset > limit else "pass")
    failing = table[table["verdict"] == "fail"]
    assert len(failing) == 2
    from hil.verdicts.budgets import Budgets
    from hil.controller.virtual import VirtualController
    from hil.dut.in_process import InProcessLink
    from hil.bench.stimulus import run

    for _, row in failing.iterrows():
        stim = Stimulus.load(row["replay"])
        outcome = run(stim, InProcessLink(VirtualController(stim.plant_config().motor)), Budgets.defaults())
        assert not outcome.ok and outcome.values["commutation_angle_p99_deg_e"] == row["angle_p99_deg_e"]
    summary = json.loads(Path(serial_run.paths["json"]).read_text())
    assert summary["complete"] and summary["scheduler"] == "serial" and summary["fail"] == 2
    assert Path(serial_run.paths["envelope"]).stat().st_size > 10_000
    assert "data:image/png;base64" in Path(serial_run.paths["report"]).read_text()


def test_same_table_on_a_loopback_cluster_of_two_workers(serial_run, loopback_cluster, tmp_path):
    spec = load_spec(write_spec(tmp_path))
    remote = run_campaign(spec, tmp_path / "out", scheduler=loopback_cluster.scheduler_address, progress=False)
    assert remote.info.scheduler == loopback_cluster.scheduler_address and remote.info.workers_used == 2
    pd.testing.assert_frame_equal(
        results(read_table(remote.paths["table"])), results(read_table(serial_run.paths["table"]))
    )
    assert sorted(p.name for p in (tmp_path / "out" / "replays").iterdir()) == sorted(
        Path(r).name for r in read_table(serial_run.paths["table"])["replay"].dropna()
    )


def test_a_killed_worker_loses_no_finished_point(serial_run, loopback_cluster, tmp_path):
    from distributed import Client

    spec = load_spec(write_spec(tmp_path))
    grid = points(spec)
    jobs = [
        (vars(point_stimulus(spec, p)), {"commutation_angle_p99": vars(spec.budgets["commutation_angle_p99"])})
        for p in grid
    ]
    with Client(loopback_cluster.scheduler_address) as client:
        pids = client.run(os.getpid)
    got: dict[int, object] = {}

    def on_result(i, value):
        assert i not in got, f"point {i} arrived twice"
        got[i] = value
        if len(got) == 1:  # one point in: kill a worker while the others are queued or running
            os.kill(next(iter(pids.values())), signal.SIGKILL)

    info = dispatch(run_point, jobs, on_result, scheduler=loopback_cluster.scheduler_address, progress=False)
    assert sorted(got) == list(range(len(grid))) and not info.interrupted
    reference = read_table(serial_run.paths["table"])
    for i, value in got.items():
        assert not isinstance(value, TaskError) and value["error"] is None, value
        assert value["values"]["commutation_angle_p99_deg_e"] == reference.loc[i, "angle_p99_deg_e"]


def test_a_raising_job_comes_back_with_its_traceback_on_the_cluster(loopback_cluster):
    got = {}
    info = dispatch(
        math.sqrt, [4.0, -1.0, 9.0], got.__setitem__, scheduler=loopback_cluster.scheduler_address, progress=False
    )
    assert got[0] == 2.0 and got[2] == 3.0 and not info.interrupted
    assert isinstance(got[1], TaskError) and "math domain error" in got[1].message and "Traceback" in got[1].traceback


def test_a_point_that_raises_is_an_error_row_and_the_campaign_goes_on(tmp_path, monkeypatch):
    import hil.bench.stimulus

    spec = load_spec(write_spec(tmp_path))
    bad_seed = points(spec)[3]["seed"]
    real = hil.bench.stimulus.run

    def flaky(stim, link, budgets):
        if stim.seed == bad_seed:
            raise RuntimeError("controller firmware assertion")
        return real(stim, link, budgets)

    monkeypatch.setattr(hil.bench.stimulus, "run", flaky)
    result = run_campaign(spec, tmp_path / "out", scheduler="serial", progress=False)
    table = read_table(result.paths["table"])
    assert len(table) == 6 and list(table["verdict"]).count("error") == 1
    row = table.loc[3]
    assert (
        row["verdict"] == "error" and "controller firmware assertion" in row["message"] and "Traceback" in row["error"]
    )
    assert np.isnan(row["angle_p99_deg_e"]) and row["commutation_angle_p99.verdict"] == "error"
    assert Stimulus.load(row["replay"]).seed == bad_seed  # an erroring point replays too
    assert (table.drop(index=3)["error"].isna()).all()


def test_ctrl_c_leaves_a_valid_partial_table(tmp_path, monkeypatch):
    import hil.bench.stimulus

    spec = load_spec(write_spec(tmp_path))
    real, calls = hil.bench.stimulus.run, []

    def interrupted_at_the_third(stim, link, budgets):
        calls.append(stim.seed)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(stim, link, budgets)

    monkeypatch.setattr(hil.bench.stimulus, "run", interrupted_at_the_third)
    result = run_campaign(spec, tmp_path / "out", scheduler="serial", progress=False)
    assert result.info.interrupted
    table = read_table(tmp_path / "out" / "points.parquet")
    assert list(table["index"]) == [0, 1]
    summary = json.loads((tmp_path / "out" / "campaign.json").read_text())
    assert summary["interrupted"] and not summary["complete"] and summary["points_done"] == 2


def test_envelope_cell_is_the_worst_margin_over_the_other_axes():
    table = pd.DataFrame(
        {
            "x": [0, 0, 1, 1, 0, 1],
            "y": [5, 5, 5, 5, 6, 6],
            "z": [0, 1, 0, 1, 0, 0],
            "b.margin": [0.3, -0.1, 0.2, 0.4, np.nan, 0.1],
        }
    )
    grid = margin_grid(table, "x", "y", "b", [0, 1], [5, 6])
    assert grid[0, 0] == -0.1 and grid[0, 1] == 0.2 and np.isnan(grid[1, 0]) and grid[1, 1] == 0.1


def test_a_worker_running_other_code_gives_an_error_not_a_result(loopback_cluster, monkeypatch):
    import hil.campaign.scheduler as sched

    here = sched.code_fingerprint()
    assert len(here) == 16
    monkeypatch.setattr(sched, "code_fingerprint", lambda: "0123456789abcdef")  # this process now "runs other code"
    got = {}
    dispatch(math.sqrt, [4.0], got.__setitem__, scheduler=loopback_cluster.scheduler_address, progress=False)
    assert isinstance(got[0], TaskError) and f"fingerprint {here}" in got[0].message, got


FAULT_SPEC = """
[campaign]
name = "spikes"
seed = 2
kind = "fault_sequence"
[fixed]
fault = { name = "hall_spike" }
fault_hold_s = 0.02
[[axis]]
name = "fault.width_s"
values = [2e-6, 8e-6]
[[axis]]
name = "speed_rpm"
values = [3000.0, 9000.0]
"""


def test_fault_sweep_records_what_acted_and_what_was_reported(tmp_path):
    spec = load_spec(write_spec(tmp_path, FAULT_SPEC))
    assert [point_stimulus(spec, p).steps[0] for p in points(spec)][1] == [
        "on",
        {"name": "hall_spike", "width_s": 2e-6},
    ]
    table = read_table(run_campaign(spec, tmp_path / "out", scheduler="serial", progress=False).paths["table"])
    assert len(table) == 4 and list(table["faults_acted"]) == ["hall_spike"] * 4
    # a spike to 000 or 111 must be reported as the illegal-Hall-code fault (0xFF01), recovery within budget
    assert all("0xff01" in codes.split(",") for codes in table["fault_codes"]), table["fault_codes"].tolist()
    assert (table["recovered_commutation_angle_p99.measured"] == table["recovered_p99_deg_e"]).all()
    assert set(table["verdict"]) <= {"pass", "marginal"}, table[["verdict", "message"]].to_string()


def test_strategy_names_are_the_contracts_and_the_old_spelling_still_reads(tmp_path):
    """bldc.contract spells the strategies once (sage_husa); a spec or a replay written with
    "sage-husa" reads as sage_husa, and an unknown name is refused naming the known ones."""
    from bldc.contract import STRATEGY_NAMES, Strategy
    from hil.bench.stimulus import Stimulus

    assert list(STRATEGY_NAMES) == ["raw", "corrected", "kf", "sage_husa"]
    spec = load_spec(write_spec(tmp_path, SPEC.replace('strategy = "raw"', 'strategy = "sage-husa"')))
    assert spec.fixed_strategy == "sage_husa" and STRATEGY_NAMES[spec.fixed_strategy] == Strategy.SAGE_HUSA
    with pytest.raises(ConfigError, match=r"fixed.strategy: unknown strategy 'fast' \(known: raw, corrected, kf, "):
        load_spec(write_spec(tmp_path, SPEC.replace('strategy = "raw"', 'strategy = "fast"')))
    replay = tmp_path / "replay.json"
    stim = point_stimulus(spec, points(spec)[0])
    stim.save(replay)
    data = json.loads(replay.read_text())
    replay.write_text(json.dumps({**data, "strategy": "sage-husa"}))
    assert Stimulus.load(replay).strategy == "sage_husa"
