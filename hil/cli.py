"""The ``hil`` command line."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

from . import cli_grammar as grammar
from .dut.kinds import firmware_kinds, kinds_help

# nothing heavy at the top (tests/test_cli_grammar.py): ``hil --help`` builds every parser without
# numpy, numba, scipy or the plant; each command imports what it runs


def _plant(args):
    """The plant of ``--plant TOML`` or ``--preset NAME``."""
    from plant_models import PRESETS, PlantConfig

    return PlantConfig.from_toml(args.plant) if getattr(args, "plant", None) else PRESETS[args.preset]()


def cmd_demo(args) -> int:
    from .demo import print_demo, run_demo

    print_demo(run_demo(speed_rpm=args.speed_rpm, duration_s=args.duration_s, out_dir=args.out))
    return 0


def cmd_recording_check(args) -> int:
    from .recording.load import load_recording

    rec = load_recording(args.recording)
    form = "hil-recording/1" if Path(args.recording).is_dir() else "Hall capture"
    channels = ", ".join(k for k in (rec.samples or ()) if k not in ("t_s", "segment"))
    if rec.ordinary:
        pp = rec.stated_pole_pairs
        print(
            f"{args.recording}: {form}, {len(rec)} edges, one ordinary run (no segments: speed, direction "
            f"and reversals come from the edges), pole_pairs {pp if pp else 'not stated'}, timer_tick_s "
            f"{rec.timer_tick_s or 'unknown'}, samples {f'yes ({channels})' if rec.samples else 'no'}"
        )
        return 0
    print(
        f"{args.recording}: hil-recording/1, {len(rec)} edges, {len(rec.segments)} segments "
        f"({', '.join(rec.segment_ids)}), pole_pairs {rec.pole_pairs}, "
        f"reference angle {'yes' if rec.ref_angle_mech_deg is not None else 'no'}, "
        f"samples {f'yes ({channels})' if rec.samples else 'no'}"
    )
    return 0


def cmd_recording_import(args) -> int:
    from .recording.format import write_recording
    from .recording.hall import capture_recording, parse_channels, read_hall_capture, step_summary

    cap = read_hall_capture(
        args.capture,
        parse_channels(args.channels) if args.channels else None,
        sample_rate_hz=args.sample_rate_hz,
        time_column=args.time_column,
        active_low=tuple(x.strip().upper() for x in args.active_low.split(",") if x.strip()) if args.active_low else (),
    )
    rec = capture_recording(cap, args.pole_pairs, source=Path(args.capture).name)
    write_recording(rec, args.out)
    n_rise = int(cap.rising.sum())
    print(f"{args.capture}: {len(rec)} Hall edges ({n_rise} rising, {len(rec) - n_rise} falling)")
    print(f"  channels: {', '.join(f'{k}={v}' for k, v in cap.channels.items())}")
    tick = f"{cap.timer_tick_s:.6g} s" if cap.timer_tick_s else "unknown"
    print(f"  timer_tick_s: {tick} (from {cap.tick_source})")
    print(f"  rotor steps: {step_summary(rec.t_s, rec.sensor, rec.rising)}")
    for note in cap.notes:
        print(f"  note: {note}")
    if args.pole_pairs:
        print(f"  pole_pairs: {args.pole_pairs} (stated)")
    else:
        print(
            "  pole_pairs: not stated; `hil calibrate` looks for the pole pattern in the edges and says what it "
            "assumes (give --pole-pairs N if you know it; speeds in rpm need it)"
        )
    print(f"  written to {args.out} as one ordinary run (no segments)")
    return 0


def cmd_plant_simulate(args) -> int:
    from plant_models.kinematic import OperatingPoint

    from .recording.drivers import record_kinematic
    from .recording.format import write_recording

    config = _plant(args)
    profile = [OperatingPoint(args.duration_s, rpm, args.current_a) for rpm in args.speeds_rpm]
    rec = record_kinematic(config, profile, seed=args.seed)
    write_recording(rec, args.out)
    print(f"wrote {len(rec)} edges in {len(profile)} segments to {args.out}")
    return 0


def cmd_calibrate(args) -> int:
    from bldc.reasons import words

    from .calibration import calibrate
    from .calibration.campaign import CalibrationCampaign
    from .calibration.refusals import Circuit
    from .recording.format import write_recording
    from .recording.load import load_recording

    if args.campaign:
        config = _plant(args)
        rec = CalibrationCampaign(turns_per_point=args.turns).run(config, seed=args.seed)
        write_recording(rec, args.recording)
        print(f"campaign: {len(rec.segments)} operating points, {len(rec)} edges written to {args.recording}")
    rec = load_recording(args.recording)
    cal = calibrate(
        rec, circuit=Circuit(args.pullup_ohm, args.filter_farad, args.delay_max_s), source=str(args.recording)
    )
    if cal.route == "ordinary":
        _print_ordinary_calibration(args.recording, cal)
    else:
        _print_segment_calibration(args.recording, cal.corrections)
    for r in cal.refused:
        print(f"  REFUSED {r.field}: {words(r.reason)}", file=sys.stderr)
    for quantity, why in cal.corrections.undetermined_words().items():
        print(f"  could not determine {quantity}: {why}", file=sys.stderr)
    if args.json:
        _write_json(args.json, cal.to_json())
    if args.plot and cal.route == "ordinary":
        from .gap.ordinary import save_sector_width_figure

        title = f"{Path(str(args.recording)).name}: sector width against speed"
        save_sector_width_figure(args.plot, cal.steps, cal.fit, title)
        print(f"sector widths before and after calibration plotted to {args.plot}")
    return 0


def _print_segment_calibration(recording, corr) -> None:
    fmt = lambda d: ", ".join(f"{k} {v:+.4f}" for k, v in d.items())  # noqa: E731
    print(f"{recording}: {corr.info.get('method')}")
    print(f"  installation_offset_deg_e: {fmt(corr.installation_offset_deg_e)}")
    print(f"  pole_offset_deg_e:         {', '.join(f'{v:+.4f}' for v in corr.pole_offset_deg_e)}")
    print(
        f"  conditioning_delay_s:      rise {corr.conditioning_delay_s['rise'] * 1e6:.3f} us, fall "
        f"{corr.conditioning_delay_s['fall'] * 1e6:.3f} us"
    )
    print(f"  armature_reaction:         {corr.armature_reaction_deg_e_per_a:+.4f} deg_e/A")


def _print_ordinary_calibration(recording, cal) -> None:
    """An ordinary run's calibration (a typed ``hil.calibration.result.Calibration``) for the reader."""
    from bldc.reasons import words

    from .calibration.result import Estimate

    o, a, corr = cal.ordinary, cal.ordinary.assumptions, cal.corrections

    def pm(e, scale=1.0, unit=""):
        if e.value is None:
            return f"not given: {words(e.reason)}"
        return f"{e.value * scale:+.4g} +- {e.stderr * scale:.2g}{unit}"

    print(f"{recording}: {corr.info['method']}")
    print(f"  direction: {a.direction()}; {a.edges_used} of {a.edges} edges in {a.runs} run(s)")
    print(
        f"  speed range: {a.speed_range_hz_e[0]:.1f}-{a.speed_range_hz_e[1]:.1f} Hz electrical (5-95 %); "
        f"steadiness: {a.steadiness()}"
    )
    print(
        f"  removed: {a.glitches_removed} glitch(es), {a.invalid_states_dropped} invalid-state edge(s), "
        f"{a.stalls_split} stall(s) split, {a.reversals} reversal(s) split, {a.outlier_edges} outlier(s)"
    )
    print(f"  timer_tick_s: {a.timer_tick_s or 'unknown'}; pole pairs: {words(a.pole_pairs_source)}")
    print(f"  rise_fall_delay_difference_s:    {pm(o.rise_fall_delay_difference_s, 1e6, ' us')}")
    print(f"  rise_fall_angle_asymmetry_deg_e: {pm(o.rise_fall_angle_asymmetry_deg_e, 1.0, ' deg e')}")
    print(f"  standard errors: {o.stderr_method()}")
    ind = o.cross_check
    if ind:
        print(
            "  method cross-check (sector widths vs speed; the same edges and model, not independent data): "
            f"delay {pm(Estimate(ind.delay_diff_s, ind.stderr_s), 1e6, ' us')}, "
            f"angle {pm(Estimate(ind.asymmetry_deg_e, ind.asymmetry_stderr_deg_e), 1.0, ' deg e')}"
        )
    inst = corr.installation_offset_deg_e
    print(f"  installation_offset_deg_e (relative): {', '.join(f'{k} {v:+.3f}' for k, v in inst.items())}")
    poles = corr.pole_offset_deg_e
    print(f"  pole_offset_deg_e: {', '.join(f'{v:+.3f}' for v in poles) if poles else 'none'}")
    print(f"  delay bound: {a.delay_bound_s * 1e6:.0f} us ({words(a.delay_bound_why)})")


def cmd_compare_correction(args) -> int:
    from .experiments.headline import PAPER_MEAN_CURRENT_REDUCTION, PAPER_SPEED_MSE_REDUCTION, compare, plot

    raw, cor, _ = compare(speed_rpm=args.speed_rpm, turns=args.turns, seed=args.seed)
    mse = 1 - cor.speed_mse_rpm2 / raw.speed_mse_rpm2
    cur = 1 - cor.mean_phase_current_a / raw.mean_phase_current_a
    print(
        f"paper bench with paper-sized deviations, {args.speed_rpm:.0f} rpm, PI speed loop, {args.turns} mechanical "
        "turns"
    )
    print(
        f"{'strategy':<18} {'speed fluct. MSE':>18} {'set-point MSE':>15} {'mean |i|':>10} {'comm. RMS':>10} "
        f"{'comm. p99':>10}"
    )
    for r in (raw, cor):
        print(
            f"{r.name:<18} {r.speed_mse_rpm2:>14.3g} rpm2 {r.setpoint_mse_rpm2:>11.3g} rpm2 "
            f"{r.mean_phase_current_a:>8.4f} A "
            f"{r.rms_deg_e:>7.3f} de {r.p99_deg_e:>7.3f} de"
        )
    print(
        f"reduction with correction: speed MSE {mse:.1%} (paper {PAPER_SPEED_MSE_REDUCTION:.1%}), "
        f"mean phase current {cur:.1%} (paper {PAPER_MEAN_CURRENT_REDUCTION:.1%})"
    )
    path = plot(raw, cor, args.plot)
    print(f"speed traces written to {path}")
    return 0


def cmd_table5(args) -> int:
    if args.closed_loop:
        from .experiments.closed_loop import closed_loop

        result = closed_loop(seed=args.seeds[0] if args.seeds else 0)
        print(result.format())
        if args.json:
            _write_json(args.json, result.to_json())
        return 0
    from .experiments.compare import EVAL_SEEDS, TRAIN_SEEDS, run_protocol

    result = run_protocol(
        args.protocol, eval_seeds=tuple(args.seeds or EVAL_SEEDS), train_seeds=tuple(args.train_seeds or TRAIN_SEEDS)
    )
    import textwrap

    print(f"protocol {result.protocol}:")
    for line in result.statement:  # the whole output fits 100 columns
        print(textwrap.fill(line, 100, initial_indent="  ", subsequent_indent="    "))
    print(result.format())
    if args.json:
        _write_json(args.json, result.to_json())
    return 0


def cmd_predictors_compare(args) -> int:
    from .experiments import peers
    from .recording.load import load_recording

    if args.recording and args.scenario:
        raise ValueError("give a RECORDING or --scenario, not both")
    if args.recording:
        result = peers.compare_recording(load_recording(args.recording), args.recording)
    elif (args.scenario or "paper") == "paper":
        result = peers.compare_paper()
    else:
        result = peers.compare_pumps()
    print(peers.format_result(result))
    if args.json:
        _write_json(args.json, result)
    return 0


def _write_json(path: str, data: dict) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {path}")


def cmd_gap_diagnose(args) -> int:
    from .gap import diagnose
    from .gap.report import format_text, write_html

    from plant_models import PlantConfig

    from .recording.load import TraceFiles, load_recording

    rec = load_recording(args.recording, traces=TraceFiles(args.meta, args.mapping))
    model = PlantConfig.from_toml(args.model) if args.model else None
    d = diagnose(rec, model)
    print(format_text(d, str(args.recording)))
    if args.json:
        _write_json(args.json, d.to_json())
    if args.html:
        write_html(args.html, str(args.recording), rec, d, model)
        print(f"report written to {args.html}")
    return 0


def cmd_gap_validate(args) -> int:
    from .gap.validate import run_validation

    if args.json is None:  # the old default path, for one release
        args.json = "reports/gap-validate.json"
        grammar.deprecated("hil gap validate (no --json: writes reports/gap-validate.json)",
                           "hil gap validate --json reports/gap-validate.json")
    report = run_validation(
        per_effect=args.per_effect,
        null=args.null,
        two=args.two,
        out_of_library=args.out_of_library,
        seed=args.seed,
        progress=args.progress,
        jobs=(os.cpu_count() or 1) if args.workers == "auto" else max(args.workers, 1),
        generator=args.generator,
        scheduler=args.scheduler,
    )
    if report.dispatch.get("interrupted"):
        print(
            f"interrupted: {len(report.cases)} recordings diagnosed (the summary below covers those)", file=sys.stderr
        )
    print(
        f"ran on {report.dispatch['scheduler']}"
        f"{' (' + report.dispatch['scheduler_address'] + ')' if report.dispatch.get('scheduler_address') else ''}: "
        f"{report.dispatch['workers_used']} worker(s) used, {report.dispatch['elapsed_s']:.1f} s"
    )
    for e in report.errors:
        print(f"ERROR in case {e['index']} {e['case']}: {e['message']}", file=sys.stderr)
    ran = {
        "scheduler": report.dispatch["scheduler"],
        "workers_used": report.dispatch["workers_used"],
        "dispatch": report.dispatch,
        "errors": report.errors,
    }
    if not report.cases:  # every case raised, or Ctrl-C came before the first result: nothing to score
        print("no recording was diagnosed", file=sys.stderr)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps({**ran, "cases": []}, indent=1) + "\n")
        return 130 if report.dispatch.get("interrupted") else 1

    def pct(v) -> str:
        return "-" if v is None else f"{v:.1%}"

    for min_snr in (1.0, 3.0):
        s = report.summary(min_snr)
        print(
            f"SNR >= {min_snr:g}: top-1 {pct(s['top1_rate'])}, top-3 {pct(s['top3_rate'])} ({s['single_cases']} "
            "single-effect cases); "
            f"false alarms {pct(s['false_alarm_rate'])} ({s['null_cases']} null); out-of-library unexplained "
            f"{pct(s['unexplained_rate'])} "
            f"({s['out_of_library_cases']}); both of two found {pct(s['two_effect_both_found_rate'])} "
            f"({s['two_effect_cases']}); "
            f"parameters within 20 % {pct(s['param_within_20pct_rate'])} (median error "
            f"{pct(s['median_param_error'])}); "
            f"median held-out shrink {pct(s['median_heldout_shrink'])}"
        )
        if s["false_alarm_rate_electrical"] is not None:
            print(
                f"  false alarms on null recordings with samples {s['false_alarm_rate_electrical']:.1%}; "
                f"dead time withheld (no trace in the format's signals) flagged {pct(s['no_trace_alarm_rate'])} "
                f"({s['no_trace_cases']})"
            )
    s = report.summary(3.0)
    if args.generator == "field":
        _print_cause_confusion(report, 3.0)
    names = sorted(s["confusion"])
    cols = names + ["none"] + sorted({k for row in s["confusion"].values() for k in row} - set(names) - {"none"})
    print("confusion matrix at SNR >= 3 (rows: withheld effect, columns: top-1 accepted):")
    print(" " * 22 + "".join(f"{c[:10]:>11}" for c in cols))
    for n in names:
        print(f"{n:<22}" + "".join(f"{s['confusion'][n].get(c, 0):>11}" for c in cols))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(
            json.dumps(
                {**ran, "summary_snr_ge_1": report.summary(1.0), "summary_snr_ge_3": s, "cases": report.cases}, indent=1
            )
            + "\n"
        )
        print(f"validation written to {args.json}")
    return 130 if report.dispatch.get("interrupted") else (1 if report.errors else 0)


def cmd_campaign(args) -> int:
    import re

    from .campaign import load_spec, run_campaign

    spec = load_spec(args.spec)
    out = args.out or f"reports/campaign-{re.sub(r'[^A-Za-z0-9_.-]+', '_', spec.name)}"
    scheduler, workers = args.scheduler, None if args.workers == "auto" else args.workers
    if workers == 0:  # no worker processes: in this process
        scheduler, workers = scheduler or "serial", None
    result = run_campaign(spec, out, scheduler=scheduler, workers=workers, progress=args.progress)
    s = result.summary()
    print(
        f"campaign {spec.name}: {s['points_done']}/{s['points_planned']} "
        f"points{' (INTERRUPTED)' if s['interrupted'] else ''}: "
        f"{s['pass']} pass, {s['marginal']} marginal, {s['fail']} fail, {s['error']} error; on {s['scheduler']}, "
        f"{s['workers_used']} worker(s), {s['elapsed_s']:.1f} s ({s['points_per_s'] or 0:.2f} points/s)"
    )
    for key, path in result.paths.items():
        print(f"  {key}: {path}")
    from .history.hook import record_campaign

    for line in record_campaign(result, args.history, args.station):
        print(line, file=sys.stderr if "warning" in line else sys.stdout)
    if s["fail"]:
        print(f"  {s['fail']} failing point(s) saved for hil replay in {Path(out) / 'replays'}")
    return 130 if s["interrupted"] else (1 if s["error"] else 0)


def _print_cause_confusion(report, min_snr: float) -> None:
    """Field generator: rows are the physical causes (with the effect that should explain them)."""
    from plant_models.hall_field import FIELD_CAUSES

    single = [c for c in report.cases if c["kind"] == "single" and c["snr"] >= min_snr]
    cols = sorted({c["top1"] for c in single} | {cause.explained_by.name for cause in FIELD_CAUSES})
    print(f"field causes at SNR >= {min_snr:g} (rows: withheld cause -> expected effect; columns: top-1 accepted):")
    print(" " * 44 + "".join(f"{c[:10]:>11}" for c in cols))
    for cause in FIELD_CAUSES:
        row = [c["top1"] for c in single if c["cause"][0] == cause.name]
        label = f"{cause.name} -> {cause.explained_by.name}"
        print(f"{label:<44}" + "".join(f"{row.count(c):>11}" for c in cols))


def cmd_dut_serve(args) -> int:
    from bldc.contract import strategy_named

    from .dut.serve import serve

    if args.canopen_port is None and args.modbus_port is None:
        raise ValueError("give --canopen-port and/or --modbus-port")
    # the operator sees why the socketcand server closed or refused a client (one line each, on
    # stderr); the Modbus server's refusals are debug lines (docs/controller.md)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    serve(args.canopen_port, args.modbus_port, host=args.host, node_id=args.node_id, unit=args.unit,
          strategy=int(strategy_named(args.strategy)), preset=args.preset, bus_name=args.bus_name,
          idle_timeout_s=args.idle_timeout, profile=args.profile)
    return 0


def cmd_dut_check(args) -> int:
    """Read every readable object of the DUT's profile once (writes nothing) and say which
    requirements the profile makes testable; 1 when the device refuses an object."""
    from .verdicts.requirements import REQUIREMENTS, missing_needs
    from .dut.link import LinkError, edge_hook_kind
    from .dut.profile import ROLES
    from .dut.spec import open_dut

    refused = 0
    with open_dut(args.dut, _plant(args).motor) as dut:
        profile = getattr(dut.link, "profile", None)
        if profile is None:
            raise ValueError(f"{args.dut}: this link has no device profile to check")
        print(f"{dut.link.where}: profile {profile.path} ({profile.name})")
        info = getattr(dut.link, "info", None)
        if info is not None:  # a firmware in the loop: what it said of itself, and how it was built
            print(f"firmware: {info.name!r}, hil-sil/{info.abi}, timer {info.timer_hz} Hz x {info.timer_bits} bit, "
                  f"control {info.control_hz} Hz, ADC {info.amps_per_count:g} A/count, {info.pole_pairs} pole pairs, "
                  f"compare unit {'yes' if info.has_compare else 'no'}, EMCY {'yes' if info.has_emcy else 'no'}; "
                  f"{getattr(dut.link, 'build', '')}")
        print(f"{'role':<46}{'object':<18}{'raw':>24}  engineering")
        for role, obj in profile.objects.items():
            label = obj.label() + (f" x{obj.count}" if obj.count > 1 else "")
            if not obj.readable:
                print(f"{role:<46}{label:<18}{'(action: ' + str(obj.write) + ', not written)':>24}")
                continue
            try:
                raws = dut.link.read_raw(obj)
            except LinkError as exc:
                refused += 1
                print(f"{role:<46}{label:<18}{'REFUSED':>24}  {exc}")
                continue
            values = [obj.from_raw(r, profile.pole_pairs) for r in raws]
            unit = ROLES[role].unit if role in ROLES else obj.unit
            if obj.values is not None:  # an enumeration: the framework's name of the device's value
                names = {v: k for k, v in obj.values.items()}
                values, unit = [names.get(r, f"(no name for {r})") for r in raws], ""
            shown = ", ".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in values)
            print(f"{role:<46}{label:<18}{', '.join(map(str, raws))[:24]:>24}  {shown} {unit}")
        print("requirements:")
        for rid, title in REQUIREMENTS.items():
            missing = missing_needs([rid], profile.has, edge_hook_kind(dut.link), profile.fault_sources)
            print(f"  {rid:<14}{'testable' if not missing else 'not testable: lacks ' + ', '.join(missing)}")
    if refused:
        print(f"hil dut check: the device refused {refused} object(s)", file=sys.stderr)
    return 1 if refused else 0


def cmd_dut_profile(args) -> int:
    from .dut.draft import draft_from_eds

    text = draft_from_eds(args.from_eds)
    if args.out:
        Path(args.out).write_text(text)
        print(f"{args.out}: drafted from {args.from_eds}; finish every line marked GUESS")
    else:
        print(text, end="")
    return 0


def cmd_plant_check(args) -> int:
    from plant_models import PlantConfig

    config = PlantConfig.from_toml(args.plant)
    print(
        f"{args.plant}: valid; motor {config.motor.pole_pairs} pole pairs, top speed "
        f"{config.operating.top_speed_rpm:.0f} rpm; effects: "
        f"{', '.join(e.name for e in config.effects) or 'none'}; hash {config.config_hash()}"
    )
    return 0


def effect_routes(cls) -> list[str]:
    """Where the house meets an effect, read from its declaration (``plant_models.effects.Effect``)."""
    routes = []
    if cls.edge_signature() is not None:
        routes.append("diagnosed from its mean edge-angle signature (a recording with a reference)")
    if cls.validation == "jitter":
        routes.append("diagnosed as edge noise (a variance)")
    if cls.ordinary is not None:
        routes.append(f"diagnosed from capture times alone (an ordinary run: {cls.ordinary.meaning})")
    sig = cls.sample_signature()
    if sig is not None:
        routes.append(f"diagnosed from the sampled signals ({sig.domain} residual; relevant against the "
                      f"{sig.budget} budget: {sig.disturbs})")
    if cls.no_trace:
        routes.append("not diagnosed: " + cls.no_trace)
    if cls.validation is not None:
        routes.append(f"validated by the {cls.validation!r} law (`hil gap validate`)")
    if cls.from_base_in_twin():
        why = f": {cls.capture_blind}" if cls.capture_blind else " (with the motor)"
        routes.append(f"a twin from a Hall capture takes it from its base plant{why}")
    routes.append(f"swept by a campaign axis `{cls.name}.<parameter>`")
    return routes


def effects_markdown() -> str:
    """The effect library as a Markdown reference (docs/effects.md is generated from this)."""
    import inspect

    from bldc.params import describe
    from plant_models import EFFECTS

    lines = [
        "# The effect library",
        "",
        "Generated by `hil effects --markdown`; do not edit by hand. "
        "Sign convention: a positive angle means the captured edge trails the ideal one (forward rotation).",
        "",
    ]
    for name, cls in EFFECTS.items():
        doc = inspect.cleandoc(cls.__doc__ or "")
        lines += [f"## `{name}` ({cls.layer})", "", doc, ""]
        fp = cls.fingerprint
        lines += [
            f"Fingerprint: {fp.get('signature', '-')}; scales with {fp.get('scales_with', '-')}; knob: "
            f"{fp.get('knob', '-')}.",
            "",
        ]
        lines += [f"Routes: {'; '.join(effect_routes(cls))}.", ""]
        lines += ["| parameter | unit | bounds | default | meaning |", "|---|---|---|---|---|"]
        for row in describe(cls):
            lines.append(
                f"| `{row['name']}` | {row['unit']} | [{row['low']}, {row['high']}] | `{row['default']!r}` | "
                f"{row['doc']} |"
            )
        for part, kind in getattr(cls, "parts", {}).items():  # nested tables (hall_field)
            lines += [
                "",
                f"Table `{part}` ({kind.__name__}):",
                "",
                "| parameter | unit | bounds | default | meaning |",
                "|---|---|---|---|---|",
            ]
            for row in describe(kind):
                lines.append(
                    f"| `{row['name']}` | {row['unit']} | [{row['low']}, {row['high']}] | `{row['default']!r}` | "
                    f"{row['doc']} |"
                )
        lines.append("")
    return "\n".join(lines)


def cmd_effects(args) -> int:
    from bldc.params import describe
    from plant_models import EFFECTS

    if args.markdown:
        print(effects_markdown())
        return 0
    for name, cls in EFFECTS.items():
        print(f"{name}  [{cls.layer}]  {cls.fingerprint.get('signature', '')}")
        for row in describe(cls):
            print(
                f"    {row['name']:<26} {row['unit']:<10} [{row['low']}, {row['high']}]  default {row['default']!r}  "
                f"{row['doc']}"
            )
    return 0


def find_suite(path: str | None) -> Path:
    """The acceptance suite: the given directory or test file, ./test_cases, or the one beside this package."""
    if path:
        if not Path(path).exists():
            raise ValueError(f"--suite {path}: no such directory or file")
        return Path(path)
    candidates = [Path("test_cases"), Path(__file__).resolve().parent.parent / "test_cases"]
    for c in candidates:
        if (c / "conftest.py").is_file():
            return c
    raise ValueError(f"no acceptance suite at {', '.join(str(c) for c in candidates)} (give --suite DIR)")


def cmd_qualify(args) -> int:
    """The suite against each seeded defect: exit 0 when the control run PASSes and every defect is
    caught by an assertion, 1 when a defect survives or errors a test or the control run fails, 2
    on bad input."""
    from .qualify.defects import CATALOGUE, load_defects
    from .qualify.run import firmware_defects, qualify

    try:
        if args.defects:
            load_defects(args.defects)
        catalogue = firmware_defects(args.dut) or CATALOGUE  # a firmware folder's own (defects.toml)
        if args.list:
            for d in catalogue.values():
                print(f"{d.name:<34} {d.defect_class or '-':<19} {d.description}")
            return 0
        args.report_dir = args.out  # hil.qualify reads the report directory by its old name
        if args.workers == "auto":
            args.workers = os.cpu_count() or 1
        args.only = [n.strip() for n in args.only.split(",") if n.strip()] if args.only else None
        if args.run_limit_s is not None and not args.run_limit_s > 0:  # NaN too
            raise ValueError(f"--run-limit-s {args.run_limit_s:g}: give the seconds a run may take, above 0")
        suite = find_suite(args.suite)
        args.suite = str(suite if suite.is_dir() else suite.parent)
        print(f"hil qualify: {len(args.only or catalogue)} defects against {args.dut}, {args.workers} at a time; "
              f"reports in {args.out}/")
        # each run is recorded in the results history as a qualify run (its pytest reads the environment)
        scoped = {**_history_env(args), "HIL_RUN_KIND": "qualify"}
        before = {k: os.environ.get(k) for k in scoped}
        os.environ.update(scoped)
        try:
            result = _under_compile_ahead(qualify, args)
        finally:
            for k, v in before.items():
                os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)
    except (OSError, ValueError, TypeError) as exc:
        print(f"hil qualify: {exc}", file=sys.stderr)
        return 2
    out = result.to_json()
    if result.control_passed:
        print(f"control run: {result.control.verdict}; caught {len(result.killed)} of {len(result.mutants)} defects "
              f"({100 * (result.detection_ratio or 0):.0f} %) in {result.duration_s:.0f} s")
    else:
        print(f"control run: {result.control.verdict}; no detection figure: {out['no_detection_because']}")
    if result.errored:
        print("errored (a test raised, nothing was caught; findings to fix, not catches): "
              + ", ".join(result.errored))
    if result.not_judged:
        print("not judged (a setup check failed: the scenario did not provoke what the test judges): "
              + ", ".join(result.not_judged))
    for req, names in result.requirements().items():
        print(f"  {req:<14} catches {', '.join(names)}")
    if result.survivors:
        print("survivors (findings: add the requirement that catches them, or state why harmless): "
              + ", ".join(result.survivors))
    if result.by_design:  # defects.toml's kinds: another kind of DUT must catch them
        print("not this kind's catch by design (shown, not counted): "
              + ", ".join(f"{m.name} ({m.verdict}; {', '.join(k + ':' for k in m.kinds)} catches it)"
                          for m in result.by_design))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
        print(f"written: {args.json}")
    if getattr(args, "table", None):
        from .qualify.run import sensitivity_markdown

        Path(args.table).parent.mkdir(parents=True, exist_ok=True)
        Path(args.table).write_text(sensitivity_markdown(out))
        print(f"written: {args.table}")
    return 0 if (result.control_passed and not result.survivors and not result.errored
                 and not result.not_judged) else 1


def _under_compile_ahead(run, *args):
    """``run(*args)`` with the numba code compiled once, ahead, for the pytest runs it starts (they
    inherit HIL_COMPILE_LOCK and wait for it: hil/compile_ahead.py), not once per run."""
    from .compile_ahead import LOCK_ENV, CompileAhead

    root = str(Path(__file__).resolve().parent.parent)
    ahead = CompileAhead({**os.environ, "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get(
        "PYTHONPATH")])])}).start()
    os.environ.update(ahead.env())
    try:
        return run(*args)
    finally:
        os.environ.pop(LOCK_ENV, None)
        ahead.close()


def cmd_acceptance(args) -> int:
    import subprocess

    from .verdicts.report import ReportWriter

    suite = find_suite(args.suite)
    # progress lines (hil.verdicts.progress) instead of dots: count, elapsed time, outcome and name per test
    # (pytest-benchmark, if installed, has nothing to do here and warns under xdist)
    argv = [
        str(suite),
        "-p",
        "no:cacheprovider",
        "-p",
        "no:benchmark",
        "-p",
        "hil.verdicts.progress",
        "-q",
        "-o",
        "console_output_style=classic",
        f"--hil-report-dir={args.out}",
        f"--hil-seed={args.seed}",
        f"--hypothesis-seed={args.seed}",
        "-o",
        "faulthandler_timeout=600",
    ]
    # one controller by default, as a user's run judges one: the same built-in controller over a
    # second link gives the same figures again (the suite is deterministic per seed) at twice the time
    duts = args.dut or ["virtual:canopen"]
    for dut in duts:
        argv.append(f"--hil-dut={dut}")
    if args.plant:
        argv.append(f"--hil-plant={args.plant}")
    if args.budgets:
        argv.append(f"--hil-budgets={args.budgets}")
    if args.delay_draws:
        argv.append(f"--hil-delay-draws={args.delay_draws}")
    argv += ["-n", str(default_workers(duts) if args.workers == "auto" else args.workers)]
    if argv[-1] != "0":  # a test per worker as each frees up: the suite's tests differ in length by 100x
        argv += ["--dist", "worksteal"]
    extra = list(args.pytest_args)
    if extra[:1] == ["--"]:  # argparse keeps the separator in a REMAINDER; pytest would take it for a path
        extra = extra[1:]
    ReportWriter.clear(Path(args.out))  # pytest may refuse the arguments before the plugin can
    # pytest runs in a fresh interpreter: here hil and plant_models are imported already, and
    # pytest would warn that it cannot rewrite the asserts of its plugin's packages
    # the same hil (and plant_models) as this command, wherever the interpreter would find another
    root = str(Path(__file__).resolve().parent.parent)
    program = "python -m hil" if Path(sys.argv[0]).name == "__main__.py" else Path(sys.argv[0]).name
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])]),
        "HIL_COMMAND": " ".join([program, *sys.argv[1:]]),
        **_history_env(args),
    }  # what the report names as the run's command
    # the numba code compiled once, in this process, while pytest starts; its workers wait for it
    # and load it from the cache instead of each compiling it (hil/compile_ahead.py)
    from .compile_ahead import CompileAhead

    ahead = CompileAhead(env).start()
    try:
        status = subprocess.run([sys.executable, "-m", "pytest", *argv, *extra], env={**env, **ahead.env()}).returncode
    except KeyboardInterrupt:  # pytest has seen the interrupt too and written its reports
        status = 2
    finally:
        ahead.close()
    return acceptance_exit(status, Path(args.out) / "hil-report.json")


def default_workers(duts: list[str]) -> str:
    """``hil acceptance``'s pytest-xdist workers without ``-n``: virtual controllers on every core
    (up to four: each worker opens its own and compiles the filters once), a real one in this
    process (it serves one session); "0" runs without workers. A firmware in the loop counts as
    virtual: each worker loads its own instance, in a process of its own."""
    from .dut.spec import DutSpecError, parse_dut

    try:
        virtual = all(parse_dut(d).local for d in duts)
    except DutSpecError:
        return "0"  # pytest names the bad spec
    cores = min(os.cpu_count() or 1, 4)
    return str(cores) if virtual and cores > 1 else "0"


def acceptance_exit(pytest_status: int, report_json: Path) -> int:
    """The exit status of ``hil acceptance``: 0 only for a PASS verdict. pytest's own status is kept
    when it says more (interrupted 2, internal error 3, usage error 4, no tests collected 5, failed
    tests 1); any other non-PASS verdict (a known failure, a requirement no test answered) exits 1."""
    try:
        content = json.loads(report_json.read_text())
    except (OSError, ValueError):
        print(f"hil acceptance: no report at {report_json} (pytest exit status {pytest_status})", file=sys.stderr)
        return pytest_status or 1
    verdict = content.get("verdict")
    print(f"hil acceptance: {verdict}" + "".join(f"\n  {r}" for r in content.get("verdict_reasons", [])))
    if verdict == "PASS" and pytest_status == 0:
        return 0
    return pytest_status or 1


def cmd_replay(args) -> int:
    from .verdicts.budgets import Budgets
    from .dut.spec import open_dut
    from .bench.stimulus import Stimulus, run

    stim = Stimulus.load(args.file)
    budgets = Budgets.from_toml(args.budgets) if args.budgets else Budgets.defaults()
    with open_dut(args.dut, stim.plant_config().motor) as dut:
        outcome = run(stim, dut.link, budgets)
    print(f"{args.file}: {stim.kind} from {stim.test or 'an unnamed test'} against {args.dut}")
    for k, v in outcome.values.items():
        print(f"  {k}: {v}")
    print(("PASS: " if outcome.ok else "FAIL: ") + outcome.message)
    return 0 if outcome.ok else 1


def _parser_paper(sub) -> None:
    p = sub.add_parser("paper", help="the paper's experiments: the demo bench, Section 4.3, Table 5")
    ps = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    _parser_demo(ps)
    _parser_compare_correction(ps)
    _parser_table5(ps)


def _parser_demo(sub) -> None:
    p = sub.add_parser("demo", help="paper-bench run with paper-sized deviations; prints the edge errors")
    p.add_argument("--speed-rpm", type=float, default=5700.0)
    p.add_argument("--duration-s", type=float, default=0.5)
    grammar.add_out(p, "the recording directory to write (default: reports/demo-recording)",
                    default="reports/demo-recording")
    p.set_defaults(func=cmd_demo)


def _parser_recording(sub) -> None:
    p = sub.add_parser("recording", help="bench recordings (hil-recording/1)")
    rs = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = rs.add_parser("check", help="validate a recording (or read a capture) and summarise it")
    grammar.add_recording(q)
    q.set_defaults(func=cmd_recording_check)
    q = rs.add_parser(
        "import", help="a logic-analyser capture of the three Hall lines (VCD, sigrok .sr, CSV) as a recording"
    )
    q.add_argument("capture", help="VCD, sigrok session (.sr) or CSV (time or sample index, three levels)")
    grammar.add_out(q, "the recording directory to write", required=True)
    q.add_argument(
        "--channels", help="A=NAME,B=NAME,C=NAME (default: hall_a, hall_b, hall_c if present, else the first three)"
    )
    q.add_argument(
        "--sample-rate-hz", type=float, help="the capture's sample rate (default: from the file's time base)"
    )
    q.add_argument("--time-column", help="CSV: the time or sample-index column (default: the first)")
    q.add_argument("--active-low", help="sensors whose line reads 0 when the Hall element is on, e.g. A,B,C")
    q.add_argument("--pole-pairs", type=int, help="the motor's pole pairs, if known (written to meta.json)")
    q.set_defaults(func=cmd_recording_import)


def _parser_plant(sub) -> None:
    p = sub.add_parser("plant", help="the plant model")
    ps = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = ps.add_parser("simulate", help="write a kinematic-mode recording of steady operating points")
    grammar.add_plant_source(q)
    q.add_argument("--speeds-rpm", type=float, nargs="+", default=[1000.0, 5000.0, 10000.0])
    q.add_argument("--current-a", type=float, default=0.0)
    q.add_argument("--duration-s", type=float, default=0.5)
    q.add_argument("--seed", type=int, default=0)
    grammar.add_out(q, "the recording directory to write", required=True)
    q.set_defaults(func=cmd_plant_simulate)
    q = ps.add_parser("check", help="validate a plant TOML file")
    q.add_argument("plant", metavar="PLANT", help="plant TOML file")
    q.set_defaults(func=cmd_plant_check)


def _parser_twin(sub) -> None:
    from .twin.cli import add_parser  # docs/twin.md

    add_parser(sub)


def _parser_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="compute the Hall correction tables from a recording")
    grammar.add_recording(p, "with --campaign: the recording directory the campaign writes first")
    grammar.add_json(p, "the corrections")
    p.add_argument(
        "--campaign",
        action="store_true",
        help="first run the calibration campaign on the plant and record it to RECORDING",
    )
    grammar.add_plant_source(p, "plant TOML for --campaign")
    p.add_argument("--turns", type=int, default=200, help="mechanical turns per operating point (--campaign)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pullup-ohm", type=float, help="Hall pull-up resistor (with --filter-farad: the delay bound)")
    p.add_argument("--filter-farad", type=float, help="Hall filter capacitor (with --pullup-ohm: the delay bound)")
    p.add_argument(
        "--delay-max-s", type=float, help="stated maximum conditioning delay (default: 1 ms, open-collector wiring)"
    )
    p.add_argument("--plot", metavar="PATH",
                   help="ordinary run: save sector width against speed, before and after calibration (PNG)")
    p.set_defaults(func=cmd_calibrate)


def _parser_compare_correction(sub) -> None:
    p = sub.add_parser(
        "compare-correction", help="paper Section 4.3: raw versus corrected commutation on the paper bench"
    )
    p.add_argument("--speed-rpm", type=float, default=5700.0)
    p.add_argument("--turns", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", metavar="PATH", default="reports/headline-5700rpm.png",
                   help="the speed traces (PNG; default: %(default)s)")
    p.set_defaults(func=cmd_compare_correction)


def _parser_table5(sub) -> None:
    p = sub.add_parser(
        "table5", help="paper Section 4.4: pre-calibration, KF and Sage-Husa predictors on the paper scenario"
    )
    p.add_argument(
        "--protocol",
        default="tuned",
        choices=["paper", "tuned", "misspecified", "bursts"],
        help="how the KF and Sage-Husa are set up and what disturbs the edges (docs/sage-husa.md; default: tuned)",
    )
    p.add_argument(
        "--closed-loop",
        action="store_true",
        help="run the paper scenario through the controller on every link, then replay its edges offline",
    )
    p.add_argument("--seeds", type=int, nargs="+", help="evaluation seeds (default: 0 3 4 ... 11; closed loop: 0)")
    p.add_argument("--train-seeds", type=int, nargs="+", help="tuning seeds (default: 1 2 12 13)")
    grammar.add_deprecated(p, "--seed", dest="seeds", new="--seeds", type=int, nargs="+")
    grammar.add_deprecated(p, "--train-seed", dest="train_seeds", new="--train-seeds", type=int, nargs="+")
    grammar.add_json(p, "the result (keys in docs/sage-husa.md)")
    p.set_defaults(func=cmd_table5)


def _parser_predictors(sub) -> None:
    p = sub.add_parser("predictors", help="commutation predictors: the firmware peers, KF, Sage-Husa, VB-AKF")
    ps = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = ps.add_parser("compare", help="every predictor on a scenario or a recording, with its shipped settings")
    grammar.add_recording(q, "calibrated as `hil calibrate` does, scored on the second half", nargs="?")
    q.add_argument("--scenario", choices=["paper", "pumps"], help="the paper's speed steps (default) or held-out pumps")
    grammar.add_json(q, "the figures (keys in docs/sage-husa.md)")
    q.set_defaults(func=cmd_predictors_compare)


def _parser_gap(sub) -> None:
    p = sub.add_parser("gap", help="sim-to-real gap: diagnose a recording, or validate the diagnosis")
    gs = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = gs.add_parser("diagnose", help="where the gap lies, which effect causes it, how far it shrinks")
    grammar.add_recording(q, "or a trace file (.mf4, .parquet, .csv) with --meta and --mapping")
    q.add_argument(
        "--model", help="plant TOML with the effects the model already knows (default: nominal motor of meta.json)"
    )
    q.add_argument("--meta", help="meta.json (motor, segments) for a trace file")
    q.add_argument("--mapping", help="TOML column mapping for a trace file (docs/gap.md)")
    grammar.add_json(q, "the diagnosis")
    q.add_argument("--html", metavar="PATH", help="write the diagnosis as a page with its figures here")
    q.set_defaults(func=cmd_gap_diagnose)
    q = gs.add_parser("validate", help="inject, withhold, diagnose, score")
    q.add_argument(
        "--per-effect", type=int, default=60, help="draws per effect (per physical cause with --generator field)"
    )
    q.add_argument("--null", type=int, default=100)
    q.add_argument("--two", type=int, default=60)
    q.add_argument("--out-of-library", type=int, default=100)
    q.add_argument("--seed", type=int, default=0)
    grammar.add_workers(q, "local worker processes (default auto: one per core; 0: in this process)")
    grammar.add_deprecated(q, "--jobs", dest="workers", new="-j/--workers", type=int,
                           convert=lambda n: 0 if n <= 1 else n)  # --jobs 1 ran in this process
    q.add_argument(
        "--scheduler",
        help="Dask scheduler: tcp://HOST:PORT of a running cluster, 'local' or 'serial' (default: local, --workers "
        "workers)",
    )
    grammar.add_progress(q)
    q.add_argument(
        "--generator",
        choices=("library", "field"),
        default="library",
        help="library: withhold the library's effects; field: withhold physical causes of the field-level Hall model",
    )
    grammar.add_json(q, "the validation (summaries and every case)")
    q.set_defaults(func=cmd_gap_validate)


def _parser_campaign(sub) -> None:
    p = sub.add_parser(
        "campaign", help="sweep deviations, faults, operating points and strategies; envelope map (docs/campaigns.md)"
    )
    p.add_argument("spec", help="campaign SPEC TOML")
    grammar.add_out(p, "output directory (default: reports/campaign-NAME)", metavar="DIR")
    p.add_argument(
        "--scheduler", help="Dask scheduler: tcp://HOST:PORT of a running cluster, 'local' (default) or 'serial'"
    )
    grammar.add_workers(p, "workers of the local cluster (default auto: one per core; 0: in this process)")
    grammar.add_progress(p)
    grammar.add_history(p)
    grammar.add_station(p)
    p.set_defaults(func=cmd_campaign)


def _parser_dut(sub) -> None:
    p = sub.add_parser("dut", help="the virtual controller (device under test)")
    ds = p.add_subparsers(dest="sub", metavar="ACTION", required=True)
    q = ds.add_parser(
        "serve", help="run the virtual controller in its own process (CANopen over the socketcand protocol, Modbus TCP)"
    )
    q.add_argument(
        "--canopen-port",
        type=int,
        help="serve the CAN bus on HOST:PORT with the socketcand protocol (python-can 'socketcand' interface; 0: any "
        "free port)",
    )
    q.add_argument("--bus-name", default="can0", help="the socketcand bus name clients open (default can0)")
    q.add_argument(
        "--idle-timeout",
        type=float,
        default=300.0,
        help="close a client that sends or reads nothing for this many seconds (default 300)",
    )
    q.add_argument("--modbus-port", type=int, help="serve Modbus TCP on HOST:PORT")
    q.add_argument("--host", default="127.0.0.1", help="bind address (default loopback; 0.0.0.0 only if you mean it)")
    q.add_argument("--node-id", type=int, default=5)
    q.add_argument("--unit", type=int, default=1)
    grammar.add_strategy(q, "the controller's commutation strategy (default: sage_husa)", default="sage_husa")
    grammar.add_preset(q, "the motor the controller is set up for")
    q.add_argument(
        "--profile",
        help="serve under this device profile (hil-device-profile/1, docs/device-profiles.md) instead of the "
        "controller's own map",
    )
    q.set_defaults(func=cmd_dut_serve)
    q = ds.add_parser(
        "check", help="read every object of a DUT's profile once (writes nothing); which requirements it makes testable"
    )
    q.add_argument("--dut", required=True, help="controller spec with profile=FILE, or a firmware in the loop: "
                   f"{', '.join(k + ':FIRMWARE' for k in firmware_kinds())} (hil/dut/kinds.py)")
    grammar.add_preset(q, "the motor (its pole pairs)")
    q.set_defaults(func=cmd_dut_check)
    q = ds.add_parser("profile", help="draft a device profile from an EDS, every guess marked")
    q.add_argument("--from-eds", required=True, help="the device's EDS file")
    grammar.add_out(q, "write the draft here (default: standard output)")
    grammar.add_deprecated(q, "--output", dest="out", new="-o/--out")
    q.set_defaults(func=cmd_dut_profile)


def _parser_acceptance(sub) -> None:
    p = sub.add_parser(
        "acceptance",
        help="run the acceptance suite against a controller (default: the virtual one over CANopen); write the reports",
    )
    p.add_argument(
        "--dut", action="append",
        help="controller spec (repeatable; default: virtual:canopen; --dut virtual:modbus for the Modbus TCP "
             f"link); {kinds_help()}"
    )
    p.add_argument("--plant", metavar="TOML", help="plant TOML (default: the paper-bench preset)")
    p.add_argument("--budgets", help="budgets TOML over the defaults")
    p.add_argument("--delay-draws", choices=("library", "real-wiring"),
                   help="REQ-ROB-001's conditioning delays: 0-50 us (library, default) or 0-300 us (real-wiring)")
    grammar.add_out(p, "where the HTML, JSON and JUnit reports go (default: reports)", default="reports",
                    metavar="DIR")
    grammar.add_deprecated(p, "--report-dir", dest="out", new="-o/--out")
    p.add_argument(
        "--seed", type=int, default=0, help="base seed of the plant and of the hypothesis search (default 0)"
    )
    grammar.add_workers(
        p,
        "pytest-xdist workers, each opening its own controller (default auto: a virtual controller on every core, "
        "up to 4; a real one in one process; 0: no workers)",
    )
    grammar.add_deprecated(p, "-n", dest="workers", new="-j/--workers", type=grammar.workers)
    p.add_argument("--suite", help="the acceptance suite: a directory or test file (default: ./test_cases)")
    grammar.add_history(p)
    grammar.add_station(p)
    p.add_argument("pytest_args", nargs=argparse.REMAINDER, help="further pytest arguments after --")
    p.set_defaults(func=cmd_acceptance)


def _parser_qualify(sub) -> None:
    p = sub.add_parser(
        "qualify",
        help="qualify the acceptance suite: run it against each seeded firmware defect of the built-in controller",
    )
    p.add_argument("--dut", default="virtual:modbus",
                   help="the built-in controller's form (default: virtual:modbus), or "
                        f"{' or '.join(k + ':DIR' for k in firmware_kinds())}: a firmware folder and the seeded "
                        "defects of its defects.toml")
    p.add_argument("--defects", help="a Python file of further @defect classes (hil.qualify.defects)")
    p.add_argument("--only", help="comma-separated defect names (default: the whole catalogue)")
    p.add_argument("--budgets", help="budgets TOML over the defaults")
    p.add_argument("--seed", type=int, default=0, help="base seed of the plant and of the hypothesis search")
    grammar.add_out(p, "one acceptance report per run (default: reports/qualify)", default="reports/qualify",
                    metavar="DIR")
    grammar.add_deprecated(p, "--report-dir", dest="out", new="-o/--out")
    grammar.add_workers(p, "runs at a time (default 2; auto: one per core)", default=2)
    grammar.add_deprecated(p, "-n", dest="workers", new="-j/--workers", type=grammar.workers)
    p.add_argument("--suite", help="the acceptance suite: a directory (default: ./test_cases)")
    p.add_argument("--run-limit-s", type=float, metavar="S",
                   help="stop a run still going after S seconds of wall time, reported as undecided (default: "
                        "3600 s times the DUT kind's run time factor: 4 for pil:, whose core runs every instruction)")
    grammar.add_json(p, "the result")
    p.add_argument("--list", action="store_true", help="list the defects and exit")
    p.add_argument("--sensitivity", action="store_true",
                   help="run each defect to the end on the tests of the requirements that name its class: the "
                        "sensitivity table (requirement x defect, caught by its own budget, with the margin)")
    p.add_argument("--table", help="write the sensitivity table (markdown) here")
    grammar.add_history(p)
    grammar.add_station(p)
    p.set_defaults(func=cmd_qualify)


def _parser_replay(sub) -> None:
    p = sub.add_parser("replay", help="re-run a saved stimulus (a failing property-based example)")
    p.add_argument("file", help="stimulus JSON (reports/replays/*.json)")
    p.add_argument(
        "--dut", default="virtual:in-process", help="controller spec (default: the virtual controller in-process)"
    )
    p.add_argument("--budgets", help="budgets TOML over the defaults")
    p.set_defaults(func=cmd_replay)


def _parser_effects(sub) -> None:
    p = sub.add_parser("effects", help="list the effect library with units and bounds")
    p.add_argument("--markdown", action="store_true", help="print the Markdown reference (docs/effects.md)")
    p.set_defaults(func=cmd_effects)


def _parser_history(sub) -> None:
    from .history.cli import add_parser  # the results history (docs/history.md)

    add_parser(sub)


def _history_env(args) -> dict:
    """``--history`` and ``--station`` as the environment the runs a command starts read (hil.history.location)."""
    from .history.location import HISTORY_ENV, STATION_ENV

    env = {}
    if getattr(args, "history", None):
        env[HISTORY_ENV] = args.history
    if getattr(args, "station", None):
        env[STATION_ENV] = args.station
    return env


def _parser_signals(sub) -> None:
    from .signals.cli import add_parser  # real-bench signals (docs/signals.md)

    add_parser(sub)


#: every command's parser, in the order ``hil --help`` lists them: each function adds its one
#: subparser (and its actions) to ``sub``; a new command adds its function here (one line), and
#: a command of its own module registers with that module's ``add_parser``. The grammar every
#: option follows is docs/cli.md (hil/cli_grammar.py; tests/test_cli_grammar.py walks the parsers)
COMMAND_PARSERS = (
    _parser_paper,
    _parser_recording,
    _parser_plant,
    _parser_twin,
    _parser_calibrate,
    _parser_predictors,
    _parser_gap,
    _parser_campaign,
    _parser_dut,
    _parser_acceptance,
    _parser_qualify,
    _parser_replay,
    _parser_signals,
    _parser_history,
    _parser_effects,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hil",
        description="HIL verification of Hall calibration and Sage-Husa commutation for BLDC pump controllers. "
        "The options' grammar: docs/cli.md.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in COMMAND_PARSERS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(grammar.modernize(sys.argv[1:] if argv is None else argv))
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from .dut.link import LinkError

    try:
        return int(args.func(args) or 0)
    except ValueError as exc:  # ConfigError, RecordingError, SignalError: bad input, one line
        print(f"hil: error: {exc}", file=sys.stderr)
        return 2
    except LinkError as exc:  # a controller that refused, misbehaved or stopped answering
        print(f"hil: controller: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
