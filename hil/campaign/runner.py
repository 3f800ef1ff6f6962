"""``hil campaign SPEC.toml``: run the grid, write the table, the envelope map, replays and report.

Outputs in the campaign directory (``--out``, default ``reports/campaign-<name>``):

* ``points.parquet``: one row per point (docs/campaigns.md lists the columns). Rewritten
  atomically (temporary file, then rename) every few seconds and at the end, so it is a valid
  table at every moment, also after Ctrl-C or a killed run, holding every point finished so far.
* ``envelope.png``: the envelope map of ``[map]``.
* ``replays/point-NNNNN.json``: every failing (or erroring) point as a ``hil-stimulus/1`` file (``hil replay``).
* ``campaign.json``: the summary (counts, scheduler, workers used, timings, paths).
* ``campaign-report.html``: the summary, the envelope map, the failures and the errors.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from .envelope import write_envelope
from .grid import point_stimulus, points, run_point
from .report import write_report
from .scheduler import DispatchInfo, TaskError, dispatch
from .spec import CampaignSpec

#: how often the partial table is rewritten while the campaign runs
FLUSH_S = 5.0
TABLE = "points.parquet"


@dataclass
class CampaignResult:
    spec: CampaignSpec
    out_dir: Path
    rows: list[dict]
    info: DispatchInfo
    paths: dict[str, str] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        out = {"pass": 0, "marginal": 0, "fail": 0, "error": 0}
        for r in self.rows:
            out[r["verdict"]] += 1
        return out

    def summary(self) -> dict:
        n = len(self.rows)
        return {
            "campaign": self.spec.name,
            "spec": self.spec.path,
            "seed": self.spec.seed,
            "kind": self.spec.kind,
            "points_planned": self.spec.size,
            "points_done": n,
            "complete": n == self.spec.size and not self.info.interrupted,
            **self.counts(),
            **self.info.as_dict(),
            # throughput once the workers are up (the cluster's start is a fixed cost, in startup_s)
            "points_per_s": n / (self.info.elapsed_s - self.info.startup_s)
            if self.info.elapsed_s > self.info.startup_s
            else None,
            "budgets": {
                b: {"metric": m, **dataclasses.asdict(self.spec.budgets[b])} for b, m in self.spec.checked.items()
            },
            "axes": {a.name: list(a.values) for a in self.spec.axes},
            "failures": [{"index": r["index"], "replay": r["replay"]} for r in self.rows if r["verdict"] == "fail"],
            "errors": [r["index"] for r in self.rows if r["verdict"] == "error"],
            "paths": self.paths,
        }


def _row(spec: CampaignSpec, point: dict, stim, result) -> dict:
    """The table row of one point: coordinates, seed, measured values, per-budget verdicts."""
    row = {"index": point["index"], "repeat": point["repeat"], "seed": point["seed"], "kind": spec.kind}
    row.update({a.name: point[a.name] for a in spec.axes})
    row.setdefault("speed_rpm", stim.speed_rpm)
    row.setdefault("load_scale", spec.fixed_load_scale)
    row.setdefault("strategy", stim.strategy if spec.kind == "deviations" else "corrected")
    if isinstance(result, TaskError):  # the task itself never returned (e.g. it killed its workers)
        result = {
            "ok": False,
            "message": result.message,
            "values": {},
            "verdicts": [],
            "error": result.traceback,
            "duration_s": float("nan"),
            "cpu_s": float("nan"),
        }
    v = result["values"]
    nan = float("nan")
    if spec.kind == "deviations":
        row.update(
            angle_p99_deg_e=v.get("commutation_angle_p99_deg_e", nan),
            angle_rms_deg_e=v.get("commutation_angle_rms_deg_e", nan),
            angle_max_deg_e=v.get("commutation_angle_max_deg_e", nan),
            commutations=v.get("commutations", -1),
        )
    else:
        row.update(
            recovered_p99_deg_e=v.get("recovered_p99_deg_e", nan),
            faults_acted=",".join(v.get("acted", [])),
            fault_codes=",".join(v.get("codes", [])),
        )
    verdicts = {d["budget"]: d for d in result["verdicts"]}
    for b in spec.checked:
        d = verdicts.get(b)
        row[f"{b}.measured"] = d["measured"] if d else nan
        row[f"{b}.limit"] = spec.budgets[b].limit
        row[f"{b}.margin"] = d["margin"] if d else nan
        row[f"{b}.verdict"] = d["verdict"] if d else "error"
    if result["error"]:
        row["verdict"] = "error"
    elif not result["ok"]:
        row["verdict"] = "fail"
    else:
        row["verdict"] = "marginal" if any(d["verdict"] == "marginal" for d in result["verdicts"]) else "pass"
    row.update(
        message=result["message"],
        error=result["error"],
        replay=None,
        effects=json.dumps(stim.effects, sort_keys=True),
        duration_s=result["duration_s"],
        cpu_s=result["cpu_s"],
    )
    return row


def write_table(rows: list[dict], path: Path) -> None:
    """All rows so far, ordered by point index, as Parquet: written beside, then renamed over."""
    import pandas as pd

    frame = pd.DataFrame(sorted(rows, key=lambda r: r["index"]))
    tmp = path.with_name(f".{path.name}.tmp")
    frame.to_parquet(tmp, engine="pyarrow", index=False)
    os.replace(tmp, path)


def read_table(path: str | Path):
    import pandas as pd

    return pd.read_parquet(path, engine="pyarrow")


def run_campaign(
    spec: CampaignSpec,
    out_dir: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> CampaignResult:
    out = Path(out_dir)
    (out / "replays").mkdir(parents=True, exist_ok=True)
    for old in (out / "replays").glob("point-*.json"):
        old.unlink()  # a new run: replays of an earlier one would read as this one's failures
    table = out / TABLE
    grid = points(spec)
    stimuli = [point_stimulus(spec, p) for p in grid]
    budgets = {b: dataclasses.asdict(spec.budgets[b]) for b in spec.checked}
    jobs = [(dataclasses.asdict(s), budgets) for s in stimuli]
    rows: list[dict] = []
    last_flush = [time.monotonic()]

    def on_result(i: int, result) -> None:
        row = _row(spec, grid[i], stimuli[i], result)
        if row["verdict"] in ("fail", "error"):  # an error replays too: it re-raises where the campaign saw it
            path = stimuli[i].save(out / "replays" / f"point-{i:05d}.json")
            row["replay"] = str(path)
        rows.append(row)
        if time.monotonic() - last_flush[0] > FLUSH_S:
            write_table(rows, table)
            last_flush[0] = time.monotonic()

    try:
        info = dispatch(
            run_point, jobs, on_result, scheduler=scheduler, workers=workers, label="campaign points", progress=progress
        )
    finally:  # whatever stopped the run, the table holds every point received
        rows.sort(key=lambda r: r["index"])
        write_table(rows, table)
    result = CampaignResult(spec, out, rows, info, {"table": str(table)})
    if rows:
        png = write_envelope(read_table(table), spec, out / "envelope.png")
        if png:
            result.paths["envelope"] = str(png)

    result.paths["report"] = str(out / "campaign-report.html")
    result.paths["json"] = str(out / "campaign.json")
    write_report(result, out / "campaign-report.html")
    (out / "campaign.json").write_text(json.dumps(result.summary(), indent=1, default=str) + "\n")
    return result
