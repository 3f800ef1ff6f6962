"""The ``hil signals`` subcommands (export, score, loopback); hil/cli.py registers them.

The parsers follow the command line's grammar (docs/cli.md, ``hil.cli_grammar``) and import
nothing heavy: each command imports what it runs, so ``hil --help`` stays fast."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from .. import cli_grammar as grammar

#: the score's default hold-off as the help states it (tests/test_cli_grammar.py holds it equal to
#: ``hil.signals.commutations.DEFAULT_HOLD_OFF_S``)
HOLD_OFF_HELP_US = 100


def _plant(args):
    from plant_models import PRESETS, PlantConfig

    return PlantConfig.from_toml(args.plant) if args.plant else PRESETS[args.preset]()


def _command(args) -> str:
    """The export's options as a command line (recorded in meta.json)."""
    parts = ["python", "-m", "hil", "signals", "export"]
    for key, value in vars(args).items():
        if key in ("func", "command", "sub", "progress") or value is None or value is False:
            continue
        parts.append("--" + key.replace("_", "-"))
        if value is not True:
            parts.append(shlex.quote(str(value)))
    return " ".join(parts)


def cmd_export(args) -> int:
    from ..recording.errors import SignalError
    from .export import ExportSettings, export, ideal, load_effects
    from .trajectory import parse_profile

    config = _plant(args)
    if args.effects:
        config = config.with_effects(*load_effects(args.effects))
    if args.no_deviations:
        config = ideal(config)
    if args.speed_profile:
        points = parse_profile(args.speed_profile)
        duration = args.duration_s if args.duration_s is not None else points[-1][0]
    else:
        points = [(0.0, args.speed_rpm)]
        duration = args.duration_s if args.duration_s is not None else 1.0
    if duration <= 0:
        raise SignalError("--duration-s", "a profile that ends at t = 0 needs --duration-s")
    settings = ExportSettings(
        config=config,
        breakpoints=points,
        duration_s=duration,
        sample_rate_hz=args.sample_rate_hz,
        seed=args.seed,
        current_v_per_a=args.current_v_per_a,
        current_zero_v=args.current_zero_v,
        analog_rate_hz=args.analog_rate_hz,
        analog_lsb_v=args.analog_lsb_v,
        currents=not args.no_currents,
        csv_max_bytes=args.csv_max_bytes,
        write_csv=not args.no_csv,
        command=_command(args),
        effects_source=args.effects or "",
        deviations=not args.no_deviations,
    )

    from ..verdicts.progress import Meter

    progress = Meter("chunks written", enabled=args.progress)
    res = export(args.out, settings, progress)
    progress.close()
    print(
        f"{args.out}: {res.n_edges} Hall edges, {res.n_commutations} ideal commutations over {duration:g} s "
        f"at {args.sample_rate_hz:g} Hz (Hall timing within +-{0.5e6 / args.sample_rate_hz:.3g} us of the plant); "
        f"plant {config.name}; {res.wall_s:.1f} s"
    )
    print(
        f"  stimulus.vcd {res.vcd_bytes / 1e6:.1f} MB"
        + (f", stimulus.csv {res.csv_bytes / 1e6:.1f} MB" if res.csv_bytes is not None else "")
    )
    if res.csv_skipped_reason:
        print(f"  {res.csv_skipped_reason}")
    return 0


def _mapping(args):
    from ..recording.capture import GateMapping

    if args.mapping and args.channels:
        raise ValueError("give --mapping or --channels, not both")
    if args.mapping:
        return GateMapping.from_toml(args.mapping)
    return GateMapping.parse(args.channels) if args.channels else GateMapping()


def cmd_score(args) -> int:
    from .commutations import DEFAULT_HOLD_OFF_S
    from .score import score, write_html

    hold_off_s = DEFAULT_HOLD_OFF_S if args.hold_off_s is None else args.hold_off_s
    sc = score(args.stimulus, args.capture, _mapping(args), hold_off_s)
    print(f"{args.capture} against {Path(args.stimulus) / 'truth.csv'}:")
    print(sc.summary())
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(sc.to_json(), indent=1) + "\n")
        print(f"score written to {args.json}")
    if args.html:
        write_html(args.html, sc, f"gate capture {args.capture}")
        print(f"summary written to {args.html}")
    return 0


def cmd_loopback(args) -> int:
    from bldc.contract import strategy_named
    from plant_models import PlantConfig

    from ..controller.virtual import VirtualController
    from ..dut.in_process import InProcessLink
    from .loopback import run_loopback

    meta = json.loads((Path(args.stimulus) / "meta.json").read_text())
    config = PlantConfig.from_dict(meta["plant"])
    controller = VirtualController(
        config.motor, strategy=strategy_named(args.strategy), speed_setpoint_rpm=args.speed_rpm
    )
    tick = args.capture_tick_s if args.capture_tick_s is not None else config.compile().timer_tick_s
    res = run_loopback(
        args.stimulus,
        InProcessLink(controller),
        args.out,
        pwm_frequency_hz=config.inverter.pwm_frequency_hz,
        capture_tick_s=tick,
    )
    print(
        f"{args.out}: the virtual controller ({args.strategy}) took {res.edges} Hall edges, "
        f"answered {res.commands} commands, "
        f"{res.gate_changes} gate changes"
    )
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "signals", help="real-bench signals: stimulus an instrument plays, gate captures scored against truth"
    )
    ss = p.add_subparsers(dest="sub", metavar="ACTION", required=True)

    q = ss.add_parser(
        "export", help="write stimulus.vcd (Hall pins, current-sensor volts), stimulus.csv, truth.csv, meta.json"
    )
    grammar.add_out(q, "the stimulus directory to write", required=True, metavar="DIR")
    grammar.add_plant_source(q, "plant TOML")
    g = q.add_mutually_exclusive_group()
    g.add_argument("--speed-rpm", type=float, default=6000.0, help="constant speed (default 6000)")
    g.add_argument(
        "--speed-profile", help='speed breakpoints "t:rpm,t:rpm,..." from t = 0, linear between (forward rotation)'
    )
    # --profile is a device profile elsewhere (hil dut serve)
    grammar.add_deprecated(g, "--profile", dest="speed_profile", new="--speed-profile")
    q.add_argument("--duration-s", type=float, help="length (default: 1 s, or the profile's last breakpoint)")
    q.add_argument("--sample-rate-hz", type=float, default=1e6, help="instrument sample rate (default 1 MHz)")
    q.add_argument("--effects", help="TOML with [[effects]] tables added to the plant's")
    q.add_argument("--no-deviations", action="store_true", help="ideal stimulus: no effects, ideal current sensors")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--current-v-per-a", type=float, default=0.1, help="current-sensor output scale (default 0.1 V/A)")
    q.add_argument("--current-zero-v", type=float, default=0.0, help="current-sensor output at 0 A (default 0 V)")
    q.add_argument("--analog-rate-hz", type=float, default=50e3, help="update rate of IA..IC (default 50 kHz)")
    q.add_argument("--analog-lsb-v", type=float, default=1e-3, help="resolution of IA..IC (default 1 mV)")
    q.add_argument("--no-currents", action="store_true", help="Hall pins only")
    q.add_argument("--no-csv", action="store_true", help="do not write stimulus.csv")
    q.add_argument("--csv-max-bytes", type=float, default=2e9, help="skip stimulus.csv above this size (default 2 GB)")
    grammar.add_progress(q)
    q.set_defaults(func=cmd_export)

    q = ss.add_parser("score", help="score a gate capture (VCD, sigrok .sr, CSV) against the stimulus' truth")
    q.add_argument("stimulus", help="the directory `hil signals export` wrote")
    q.add_argument("capture", help="gate capture: .vcd, .sr (sigrok/PulseView session) or .csv with a time column")
    grammar.add_json(q, "the score (docs/signals.md)")
    q.add_argument("--html", metavar="PATH", help="write a one-page summary here")
    q.add_argument("--mapping", help="TOML channel mapping (docs/signals.md)")
    q.add_argument("--channels", help="AH=D0,AL=D1,... (capture channel of each gate)")
    q.add_argument(
        "--hold-off-s",
        type=float,
        help=f"hold-off (default {HOLD_OFF_HELP_US:g} us)",
    )
    q.set_defaults(func=cmd_score)

    q = ss.add_parser("loopback", help="play a stimulus into the virtual controller and write its gates as a VCD")
    q.add_argument("stimulus", help="the directory `hil signals export` wrote")
    grammar.add_out(q, "the gate VCD to write", required=True)
    grammar.add_strategy(q, "the virtual controller's commutation strategy (default: raw)", default="raw")
    q.add_argument("--speed-rpm", type=float, default=6000.0, help="the controller's speed set point")
    q.add_argument(
        "--capture-tick-s",
        type=float,
        help="input-capture timer tick (default: the plant's timer quantisation, else exact)",
    )
    q.set_defaults(func=cmd_loopback)


__all__ = ["add_parser"]
