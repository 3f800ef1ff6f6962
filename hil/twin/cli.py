"""The twin's commands, under one noun: ``hil twin from-capture`` makes it, ``hil twin check`` checks it
(docs/twin.md). ``hil plant from-capture`` is the old spelling of the first (one release)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from .. import cli_grammar as grammar


def cmd_plant_from_capture(args) -> int:
    from plant_models import PlantConfig

    from bldc.reasons import words

    from .capture import UNCALIBRATABLE, from_capture

    with_ = tuple(name for name, option in UNCALIBRATABLE.items()
                  if getattr(args, "with_" + option.removeprefix("--with-").replace("-", "_")))
    twin, text = from_capture(args.recording, args.base, args.pole_pairs, args.capture_tick_in_plant, with_,
                              args.top_speed_rpm)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    PlantConfig.from_toml(args.out)  # what `hil plant check` reads: the file must load as written
    print(f"{args.recording}: twin plant written to {args.out}")
    print("  measured from the capture:")
    for what, how in twin.measured:
        print(f"    {what}: {words(how)}")
    print(f"  assumed (from the base {args.base or 'paper-bench'}):")
    for what, how in twin.assumed:
        print(f"    {what}: {words(how)}")
    print("  measured but left out (no calibration table holds them):"
          + "".join(f"\n    {e.name} ({UNCALIBRATABLE[e.name]} adds it)" for e in twin.left_out) if twin.left_out
          else "  left out: nothing")
    for note in twin.notes:
        print(f"  note: {words(note)}", file=sys.stderr)
    return 0


def cmd_twin_check(args) -> int:
    from .check import format_check, twin_check
    from .report import write_html

    take_on = None if args.take_on is None else tuple(c for c in args.take_on if c != "none")
    result = twin_check(args.recording, args.plant, seed=args.seed, take_on=take_on,
                        log=lambda m: print(m, file=sys.stderr)).to_json()
    print(format_check(result))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")
    if args.html:
        write_html(result, args.html)
        print(f"wrote {args.html}")
    return 0


def _add_from_capture(twin_sub) -> None:
    q = twin_sub.add_parser("from-capture", help="make a twin: a plant TOML whose Hall system reproduces a capture")
    grammar.add_recording(q)
    grammar.add_out(q, "the twin's plant TOML to write", required=True)
    q.add_argument("--base", help="preset or plant TOML for what a capture cannot tell (default: paper-bench)")
    q.add_argument("--pole-pairs", type=int, help="the motor's pole pairs, if known (else the capture's pole pattern)")
    q.add_argument("--top-speed-rpm", type=float,
                   help="the fastest the motor runs in service, where the acceptance suite's speeds end (default: "
                   "the capture's top speed, so the suite judges the twin where it was measured)")
    q.add_argument("--capture-tick-in-plant", action="store_true",
                   help="keep the capture's sampling tick as the plant's timer quantisation (for a controller "
                   "that samples its Hall lines that coarsely); by default only `hil twin check` applies it")
    # by default the plant holds what a calibration table can hold (installation, pole, switching
    # asymmetry, delays); these add what the capture shows and no table holds (docs/twin.md)
    q.add_argument("--with-sensor-pole-pattern", action="store_true",
                   help="add the residual pattern per sensor and pole (sensor_pole_offset) the capture shows")
    q.add_argument("--with-sensor-asymmetry", action="store_true",
                   help="add each sensor's own rise-minus-fall angle (switching_asymmetry); by default the plant "
                   "holds the part common to the three sensors")
    q.add_argument("--with-edge-noise", action="store_true",
                   help="add the capture's edge noise (edge_jitter: white time jitter, AR(1) angle jitter)")
    q.set_defaults(func=cmd_plant_from_capture)


def add_parser(sub) -> None:
    p = sub.add_parser("twin", help="a plant twin of a capture: made from it, checked against it (docs/twin.md)")
    ts = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    _add_from_capture(ts)
    q = ts.add_parser("check", help="run the twin along the capture's trajectory and compare the analyses")
    grammar.add_recording(q)
    q.add_argument("plant", metavar="PLANT", help="the twin's plant TOML (hil twin from-capture)")
    grammar.add_json(q, "the comparison")
    q.add_argument("--html", metavar="PATH", help="write the comparison as a page with the figures here")
    q.add_argument("--seed", type=int, default=0, help="the twin's noise seed (default 0)")
    q.add_argument("--take-on", action="append",
                   choices=["sector_locked_speed_ripple", "sensor_pole_offset", "switching_asymmetry", "edge_jitter",
                            "none"],
                   help="run the twin with this addition (repeatable; 'none' for the twin as written); default: "
                   "what the capture's own calibration modelled (its sector-locked ripple) and what the plant "
                   "leaves out because no calibration table holds it (the motor as measured)")
    q.set_defaults(func=cmd_twin_check)
