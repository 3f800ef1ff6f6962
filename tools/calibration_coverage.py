"""Are the ordinary-run calibration's error bars honest? Two checks, as docs/real-captures.md states them.

    python tools/calibration_coverage.py [--captures 200] [--seed 1] [--halves] [--json out.json]

1. Coverage: ``--captures`` synthetic captures with known truth (this check's own generator:
   AR(1) edge jitter, drifting speed, timer quantisation; ``hil.experiments.calibration_coverage``),
   each calibrated as ``hil calibrate`` does with its pole count stated; per figure, how often
   value +- 1.96 stderr holds the truth, the mean half-width, the RMS error and the RMS of z.
2. ``--halves``: each shipped real capture (tests/data/real-hall) cut in two by edge count, each
   half calibrated alone with the pole count the whole capture gives; per figure the two values
   and z = |a - b| / hypot(se_a, se_b) (honest errors: z <= 3 but for one in 370 figures).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

from hil.calibration.ordinary import hall_steps, ordinary_calibration
from hil.experiments.calibration_coverage import Z, coverage_study, half_split
from hil.recording.hall import read_hall_capture

ROOT = Path(__file__).resolve().parents[1]
CAPTURES = sorted((ROOT / "tests" / "data" / "real-hall").glob("*.vcd"))


WHOLE_KEYS = (
    "rise_fall_delay_difference_s",
    "rise_fall_angle_asymmetry_deg_e",
    "method_cross_check",
    "installation_offset_deg_e",
    "uncertainty",
    "stderr_method",
)


def _pm(d: dict, scale: float, unit: str) -> str:
    if d.get("value") is None:
        return "-"
    return f"{d['value'] * scale:+.4g} +- {d['stderr'] * scale:.2g} {unit}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration-s", type=float, default=6.0, help="length of each synthetic capture")
    ap.add_argument("--jitter-rms-us", type=float, nargs=2, default=(3.0, 20.0), help="range of the edge jitter RMS")
    ap.add_argument("--jitter-lag1", type=float, nargs=2, default=(0.5, 0.85), help="range of its lag-1 correlation")
    ap.add_argument("--pole-pairs", type=int, default=4)
    ap.add_argument("--halves", action="store_true", help="also split each shipped real capture in halves")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    report: dict = {
        "commit": commit.stdout.strip(),
        "command": "python tools/calibration_coverage.py",
        "args": {**vars(args), "json": str(args.json) if args.json else None},
    }
    if args.captures:
        rows, info = coverage_study(
            args.captures,
            args.seed,
            duration_s=args.duration_s,
            jitter_rms_s=tuple(v * 1e-6 for v in args.jitter_rms_us),
            jitter_correlation=tuple(args.jitter_lag1),
            pole_pairs=args.pole_pairs,
        )
        report["coverage"] = {"info": info, "rows": [r.__dict__ for r in rows]}
        print(
            f"coverage of value +- {Z:.2f} stderr over {args.captures} synthetic captures (seed {args.seed}, "
            f"{info['edges_per_capture_mean']:.0f} edges each on average, {info['cpu_s']:.0f} s CPU)"
        )
        print("| figure | intervals | coverage | mean half-width | RMS error | RMS z |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r.figure} | {r.n} | {r.coverage:.1%} | {r.mean_halfwidth:.3g} {r.unit} | "
                f"{r.rms_error:.3g} {r.unit} | {r.rms_z:.2f} |"
            )
    if args.halves:
        report["halves"] = {}
        print("\nhalves of the shipped captures, each calibrated alone (z = |a - b| / hypot(se_a, se_b))")
        print("| capture | figure | first half | second half | z |")
        print("|---|---|---|---|---|")
        for path in CAPTURES:
            t0 = time.process_time()
            cap = read_hall_capture(path)
            whole = ordinary_calibration(hall_steps(cap.t_s, cap.sensor, cap.rising), tick_s=cap.timer_tick_s)
            pole_pairs = whole.ordinary.assumptions.pole_pairs
            whole_json = whole.to_json()  # the report keeps the figures as `hil calibrate --json` writes them
            halves, _ = half_split(cap.t_s, cap.sensor, cap.rising, cap.timer_tick_s, pole_pairs)
            report["halves"][path.stem] = {
                "pole_pairs": pole_pairs,
                "rows": halves,
                "whole": {k: whole_json[k] for k in WHOLE_KEYS},
                "cpu_s": time.process_time() - t0,
            }
            for h in halves:
                scale, unit = (1e6, "us") if h["figure"] == "delay_difference" else (1.0, "deg e")
                a, b = (v * scale for v in h["halves"])
                sa, sb = (v * scale for v in h["stderr"])
                print(
                    f"| {path.stem} | {h['figure']} | {a:+.4g} +- {sa:.2g} {unit} | {b:+.4g} +- {sb:.2g} {unit} | "
                    f"{h['z']:.2f} |"
                )
        print("\nwhole captures")
        print("| capture | delay difference | method cross-check | constant asymmetry | pole pairs |")
        print("|---|---|---|---|---|")
        for stem, h in report["halves"].items():
            w = h["whole"]
            cc = w["method_cross_check"] or {}
            print(
                f"| {stem} | {_pm(w['rise_fall_delay_difference_s'], 1e6, 'us')} | "
                f"{_pm(cc.get('rise_fall_delay_difference_s', {}), 1e6, 'us')} "
                f"({_pm(cc.get('rise_fall_angle_asymmetry_deg_e', {}), 1.0, 'deg e')}) | "
                f"{_pm(w['rise_fall_angle_asymmetry_deg_e'], 1.0, 'deg e')} | {h['pole_pairs']} |"
            )
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
