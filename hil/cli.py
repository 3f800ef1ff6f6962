"""The ``hil`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from plant_models import EFFECTS, PRESETS, ConfigError, PlantConfig
from plant_models.params import describe

from .recording import RecordingError, read_recording


def _plant(args) -> PlantConfig:
    if getattr(args, "plant", None):
        return PlantConfig.from_toml(args.plant)
    return PRESETS[args.preset]()


def cmd_demo(args) -> int:
    from .demo import print_demo, run_demo

    print_demo(run_demo(speed_rpm=args.speed_rpm, duration_s=args.duration_s, out_dir=args.out))
    return 0


def cmd_recording_check(args) -> int:
    rec = read_recording(args.recording)
    print(f"{args.recording}: hil-recording/1, {len(rec)} edges, {len(rec.segments)} segments "
          f"({', '.join(rec.segment_ids)}), pole_pairs {rec.pole_pairs}, "
          f"reference angle {'yes' if rec.ref_angle_mech_deg is not None else 'no'}, "
          f"samples {'yes (' + ', '.join(k for k in rec.samples if k not in ('t_s', 'segment')) + ')' if rec.samples else 'no'}")
    return 0


def cmd_plant_simulate(args) -> int:
    from plant_models.kinematic import OperatingPoint

    from .recording import record_kinematic, write_recording

    config = _plant(args)
    profile = [OperatingPoint(args.duration_s, rpm, args.current_a) for rpm in args.speeds_rpm]
    rec = record_kinematic(config, profile, seed=args.seed)
    write_recording(rec, args.out)
    print(f"wrote {len(rec)} edges in {len(profile)} segments to {args.out}")
    return 0


def cmd_plant_check(args) -> int:
    config = PlantConfig.from_toml(args.plant)
    print(f"{args.plant}: valid; motor {config.motor.pole_pairs} pole pairs; effects: "
          f"{', '.join(e.name for e in config.effects) or 'none'}; hash {config.config_hash()}")
    return 0


def cmd_effects(args) -> int:
    for name, cls in EFFECTS.items():
        print(f"{name}  [{cls.layer}]  {cls.fingerprint.get('signature', '')}")
        for row in describe(cls):
            print(f"    {row['name']:<26} {row['unit']:<10} [{row['low']}, {row['high']}]  default {row['default']!r}  {row['doc']}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hil", description="HIL verification of Hall calibration and Sage-Husa commutation for BLDC pump controllers.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("demo", help="paper-bench run with paper-sized deviations; prints the edge errors")
    p.add_argument("--speed-rpm", type=float, default=5700.0)
    p.add_argument("--duration-s", type=float, default=0.5)
    p.add_argument("--out", default="reports/demo-recording", help="where to write the recording")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("recording", help="bench recordings (hil-recording/1)")
    rs = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = rs.add_parser("check", help="validate a recording directory")
    q.add_argument("recording")
    q.set_defaults(func=cmd_recording_check)

    p = sub.add_parser("plant", help="the plant model")
    ps = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = ps.add_parser("simulate", help="write a kinematic-mode recording of steady operating points")
    g = q.add_mutually_exclusive_group()
    g.add_argument("--plant", help="plant TOML file")
    g.add_argument("--preset", default="paper-bench+deviations", choices=sorted(PRESETS))
    q.add_argument("--speeds-rpm", type=float, nargs="+", default=[1000.0, 5000.0, 10000.0])
    q.add_argument("--current-a", type=float, default=0.0)
    q.add_argument("--duration-s", type=float, default=0.5)
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--out", required=True)
    q.set_defaults(func=cmd_plant_simulate)
    q = ps.add_parser("check", help="validate a plant TOML file")
    q.add_argument("plant")
    q.set_defaults(func=cmd_plant_check)

    p = sub.add_parser("effects", help="list the effect library with units and bounds")
    p.set_defaults(func=cmd_effects)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except (ConfigError, RecordingError) as exc:
        print(f"hil: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
