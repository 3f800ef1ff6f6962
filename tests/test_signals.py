"""Real-bench signals: stimulus export, gate-capture readers, commutation extraction and scoring.

The controller of the first tests is written here from the documented conventions only
(docs/signals.md: VCD variables, Hall code to sector, the six-step pair of each sector): its
own VCD parser and writer, nothing from hil.signals. It is what an independent bench engineer
would write, and the scorer must recover the delay it put in.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hil.cli import main as hil_main

SPEED_RPM = 6000.0
POLE_PAIRS = 2  # paper bench
OMEGA_E_DEG_S = SPEED_RPM * 6.0 * POLE_PAIRS
#: documented convention (docs/signals.md): Hall code A*4+B*2+C -> sector; sector -> (high, low) phase
SECTOR_OF_CODE = {5: 0, 4: 1, 6: 2, 2: 3, 3: 4, 1: 5}
PAIR_OF_SECTOR = {0: ("C", "A"), 1: ("C", "B"), 2: ("A", "B"), 3: ("A", "C"), 4: ("B", "C"), 5: ("B", "A")}


# --- an independent controller ---------------------------------------------------------------------
def read_hall_changes(path: Path):
    """(time_s, code) at t = 0 and after every Hall change, from a VCD, parsed from scratch."""
    text = path.read_text().split()
    scale = None
    ids = {}
    i = 0
    while text[i] != "$enddefinitions":
        if text[i] == "$timescale":
            num = "".join(text[i + 1:text.index("$end", i)])
            value, unit = float(num.rstrip("munpfs")), num.lstrip("0123456789.")
            scale = value * {"s": 1, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12}[unit]
        if text[i] == "$var" and text[i + 4] in ("HA", "HB", "HC"):
            ids[text[i + 3]] = "ABC".index(text[i + 4][1])
        i += 1
    bits = [0, 0, 0]
    t = 0
    out = []
    pending_vector = False
    for tok in text[i + 2:]:
        if pending_vector:
            pending_vector = False
            continue
        if tok[0] == "#":
            t = int(tok[1:])
        elif tok[0] in "rb":
            pending_vector = True
        elif tok[0] in "01" and tok[1:] in ids:
            bits[ids[tok[1:]]] = int(tok[0])
            code = bits[0] * 4 + bits[1] * 2 + bits[2]
            if out and out[-1][0] == t * scale:
                out[-1] = (t * scale, code)
            elif not out or out[-1][1] != code:
                out.append((t * scale, code))
    return out


def independent_controller(
    stimulus: Path,
    out: Path,
    pwm_hz: float = 20e3,
    duty: float = 0.5,
    carrier: str = "restart",
    complementary: bool = False,
    dead_time_s: float = 0.0,
    chopped: str = "high",
    delay_per_sector_s: float = 4e-6,
) -> list[tuple[float, int]]:
    """Commutates 20 us + ``delay_per_sector_s`` (4 us) per sector after each Hall change; chops its
    ``chopped`` ("high" or "low") side at ``pwm_hz``
    with ``carrier`` "restart" (period restarted at each commutation, on-time first), "free"
    (free-running edge-aligned timer from t = 0: on at the period start) or "center" (free-running
    center-aligned: the on-time centred in each period); writes its six gates as a VCD with a
    1 ns timescale. Returns the (instant, sector) of each commutation it made."""
    changes = read_hall_changes(stimulus / "stimulus.vcd")
    end_s = float(json.loads((stimulus / "meta.json").read_text())["duration_s"])
    plan = []
    for t, code in changes[1:]:  # the first entry is the state at t = 0, not a change
        s = SECTOR_OF_CODE[code]
        if t + 20e-6 + delay_per_sector_s * s < end_s:
            plan.append((t + 20e-6 + delay_per_sector_s * s, s))
    period = 1.0 / pwm_hz
    events: list[tuple[int, str, int]] = []
    for k, (t0, s) in enumerate(plan):
        t1 = plan[k + 1][0] if k + 1 < len(plan) else end_s
        hi, lo = PAIR_OF_SECTOR[s]
        # the chopped switch, its complement, and the switch held on
        sw, comp, held = (hi + "H", hi + "L", lo + "L") if chopped == "high" else (lo + "L", lo + "H", hi + "H")
        # the carrier in whole nanoseconds (the VCD's timescale), so that a commutation on a
        # carrier edge sees the same edge as the carrier
        t0_ns, t1_ns, period_ns = round(t0 * 1e9), round(t1 * 1e9), round(period * 1e9)
        origin_ns = t0_ns if carrier == "restart" else 0
        lead_ns = round((1.0 - duty) / 2 * period_ns) if carrier == "center" else 0  # where the on-time starts
        on_ns = round(duty * period_ns)
        n = (t0_ns - origin_ns) // period_ns - 1
        edges = []
        while origin_ns + n * period_ns < t1_ns:
            on = origin_ns + n * period_ns + lead_ns
            edges += [(on * 1e-9, 1), ((on + on_ns) * 1e-9, 0)]
            n += 1
        level = 1 if lead_ns <= (t0_ns - origin_ns) % period_ns < lead_ns + on_ns else 0
        t0, t1 = t0_ns * 1e-9, t1_ns * 1e-9
        state = {g: 0 for g in ("AH", "AL", "BH", "BL", "CH", "CL")}
        state[held] = 1
        state[sw] = level
        if complementary:
            state[comp] = 1 - level
        for g, v in state.items():
            events.append((round(t0 * 1e9), g, v))
        for te, v in edges:
            if t0 < te < t1:
                if complementary:  # the complement turns off first, turns on after the dead time
                    if v:
                        events.append((round(te * 1e9), comp, 0))
                        events.append((round((te + dead_time_s) * 1e9), sw, 1))
                    else:
                        events.append((round(te * 1e9), sw, 0))
                        events.append((round((te + dead_time_s) * 1e9), comp, 1))
                else:
                    events.append((round(te * 1e9), sw, v))
    events.sort(key=lambda e: e[0])
    code = {"AH": "a", "AL": "b", "BH": "c", "BL": "d", "CH": "e", "CL": "f"}
    lines = ["$timescale 1ns $end", "$scope module ctl $end"] + [f"$var wire 1 {c} {g} $end" for g, c in code.items()]
    lines += ["$upscope $end", "$enddefinitions $end", "#0", "$dumpvars"] + [f"0{c}" for c in code.values()] + ["$end"]
    last_t, cur = None, {g: 0 for g in code}
    for t, g, v in events:
        if cur[g] == v:
            continue
        if t != last_t:
            lines.append(f"#{t}")
            last_t = t
        lines.append(f"{v}{code[g]}")
        cur[g] = v
    lines.append(f"#{round(end_s * 1e9)}")
    out.write_text("\n".join(lines) + "\n")
    return plan


def export_ideal_stimulus(tmp_path_factory, name: str, speed_rpm: float) -> Path:
    """A 0.5 s stimulus without deviations at ``speed_rpm``, exported through the CLI."""
    out = tmp_path_factory.mktemp("stimulus") / name
    argv = ["signals", "export", "--out", str(out), "--speed-rpm", str(speed_rpm), "--duration-s", "0.5",
            "--no-deviations"]
    assert hil_main(argv) == 0
    return out


@pytest.fixture(scope="module")
def ideal_stimulus(tmp_path_factory) -> Path:
    return export_ideal_stimulus(tmp_path_factory, "ideal", SPEED_RPM)


def score_json(stimulus: Path, capture: Path, *extra: str) -> dict:
    out = capture.with_suffix(capture.suffix + ".json")
    assert hil_main(["signals", "score", str(stimulus), str(capture), "--json", str(out), *extra]) == 0
    return json.loads(out.read_text())


@pytest.mark.parametrize("complementary", [False, True], ids=["high-side-chopped", "complementary-with-dead-time"])
def test_independent_controller_delay_is_recovered(ideal_stimulus, tmp_path, complementary):
    """The judged case: 20 us + 4 us per sector after each Hall change, high side chopped at
    20 kHz, ideal stimulus at 6000 rpm: mean within 0.05 deg e of the delay, RMS within 3 %,
    nothing missed, no PWM edge taken for a commutation."""
    plan = independent_controller(
        ideal_stimulus, tmp_path / "gates.vcd", complementary=complementary, dead_time_s=0.5e-6
    )
    got = score_json(ideal_stimulus, tmp_path / "gates.vcd")
    assert set(got) == {"commutations", "missed", "extra", "angle_error_deg_e", "time_error_s"}
    assert set(got["angle_error_deg_e"]) == {"mean", "rms", "p99", "max_abs"} and set(got["time_error_s"]) == {
        "mean",
        "rms",
    }
    delays_s = np.array([20e-6 + 4e-6 * s for _, s in plan])
    # the first Hall change only starts the controller (its first pair is not a commutation)
    expected_deg = delays_s[1:] * OMEGA_E_DEG_S
    assert got["missed"] == 0
    assert got["extra"] == 0
    assert got["commutations"] == len(plan) - 1
    assert abs(got["angle_error_deg_e"]["mean"] - expected_deg.mean()) <= 0.05
    assert abs(got["angle_error_deg_e"]["rms"] / np.sqrt(np.mean(expected_deg**2)) - 1.0) <= 0.03
    assert abs(got["time_error_s"]["mean"] - delays_s[1:].mean()) <= 1e-6


#: a speed at which the 20 kHz carrier is not locked to the electrical revolution: at 6000 rpm
#: (2 pole pairs) a revolution is exactly 100 carrier periods, so each sector's commutation falls
#: at the same carrier phase every revolution and the error of locating it inside an off-time
#: cannot average out (docs/signals.md gives that bound, tested below at 6000 rpm)
UNLOCKED_RPM = 6130.0


@pytest.fixture(scope="module")
def unlocked_stimulus(tmp_path_factory) -> Path:
    return export_ideal_stimulus(tmp_path_factory, "unlocked", UNLOCKED_RPM)


@pytest.mark.parametrize("duty", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("carrier", ["free", "center"], ids=["free-edge-aligned", "free-center-aligned"])
def test_free_running_carrier_delay_is_recovered(unlocked_stimulus, tmp_path, carrier, duty):
    """The judged case with a hardware-like timer: the 20 kHz carrier runs freely, so a change of
    the high phase inside an off-time shows only at the carrier's next turn-on. Located at the
    midpoint of that off-time (docs/signals.md), the mean is within 0.05 deg e of the delay, the
    RMS within 3 %, nothing missed, no PWM edge taken for a commutation."""
    pwm_hz = 20e3
    plan = independent_controller(unlocked_stimulus, tmp_path / "gates.vcd", pwm_hz=pwm_hz, duty=duty, carrier=carrier)
    got = score_json(unlocked_stimulus, tmp_path / "gates.vcd")
    delays_s = np.array([20e-6 + 4e-6 * s for _, s in plan])[1:]
    expected_deg = delays_s * UNLOCKED_RPM * 6.0 * POLE_PAIRS
    assert got["missed"] == 0
    assert got["extra"] == 0
    assert got["commutations"] == len(plan) - 1
    assert abs(got["angle_error_deg_e"]["mean"] - expected_deg.mean()) <= 0.05
    assert abs(got["angle_error_deg_e"]["rms"] / np.sqrt(np.mean(expected_deg**2)) - 1.0) <= 0.03


@pytest.mark.parametrize("duty", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("carrier", ["free", "center"], ids=["free-edge-aligned", "free-center-aligned"])
def test_free_running_carrier_at_a_locked_speed_is_within_the_documented_bound(
    ideal_stimulus, tmp_path, carrier, duty, capsys
):
    """At exactly 6000 rpm the carrier phase of each sector repeats every revolution: the mean
    error is then within the documented bound, (located / commutations) x half the off-time x
    the electrical speed (plus the stimulus' sampling bound), of the delay; nothing missed,
    nothing extra; the summary counts them."""
    pwm_hz = 20e3
    plan = independent_controller(ideal_stimulus, tmp_path / "gates.vcd", pwm_hz=pwm_hz, duty=duty, carrier=carrier)
    got = score_json(ideal_stimulus, tmp_path / "gates.vcd")
    hidden, _ = _hidden_in_off_time(plan, pwm_hz, duty, carrier)
    assert f"{hidden.sum()} located in an off-time" in capsys.readouterr().out
    delays_s = np.array([20e-6 + 4e-6 * s for _, s in plan])[1:]
    assert got["missed"] == 0 and got["extra"] == 0 and got["commutations"] == len(plan) - 1
    bound_deg = hidden.sum() / delays_s.size * (1 - duty) / pwm_hz / 2 * OMEGA_E_DEG_S
    sampling_deg = 0.5e-6 * OMEGA_E_DEG_S  # Hall edges quantised to the 1 MHz stimulus rate
    assert abs(got["angle_error_deg_e"]["mean"] - delays_s.mean() * OMEGA_E_DEG_S) <= bound_deg + sampling_deg


def _stimulus(tmp_path_factory, rpm: float, name: str) -> Path:
    out = tmp_path_factory.mktemp("stimulus") / name
    args = ["--out", str(out), "--speed-rpm", repr(rpm), "--duration-s", "0.3", "--no-deviations"]
    assert hil_main(["signals", "export", *args]) == 0
    return out


@pytest.mark.parametrize("chopped", ["high", "low"])
@pytest.mark.parametrize("duty", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("rpm,delay_per_sector_s,carrier", [
    # 500 us sectors = 10 periods of 20 kHz, one delay: every commutation on the old grid
    (10000.0, 0.0, "undetermined"),
    # 546 us sectors: 5 of 6 commutations 550 us = 11 periods apart, the sixth (26 us less) off the grid
    (60.0 / (6 * POLE_PAIRS * 546e-6), 4e-6, "restarted")], ids=["10000rpm-one-delay", "9157rpm-delay-per-sector"])
def test_restarted_carrier_on_whole_periods_is_scored_at_its_turn_on(
        tmp_path_factory, tmp_path, rpm, delay_per_sector_s, carrier, duty, chopped, capsys):
    """A carrier restarted at each commutation, commutations a whole number of carrier periods
    apart: the restart's turn-on of a changed chopped phase lands on the old carrier's grid,
    exactly where a free-running carrier would show a change hidden in its off-time. Either no
    commutation tells the carrier mode (all on the grid) or those that do show its phase reset at
    commutation: none is moved to an off-time midpoint, and the delay is recovered within the
    sample-rate bound (Hall edges quantised to the 1 MHz stimulus; the gates are exact)."""
    stimulus = _stimulus(tmp_path_factory, rpm, "whole")
    pwm_hz = 20e3
    plan = independent_controller(stimulus, tmp_path / "gates.vcd", pwm_hz=pwm_hz, duty=duty, carrier="restart",
                                  chopped=chopped, delay_per_sector_s=delay_per_sector_s)
    got = score_json(stimulus, tmp_path / "gates.vcd")
    omega_e_deg_s = rpm * 6.0 * POLE_PAIRS
    delays_s = np.array([20e-6 + delay_per_sector_s * s for _, s in plan])[1:]
    assert got["missed"] == 0 and got["extra"] == 0 and got["commutations"] == len(plan) - 1
    sampling_deg = 0.5e-6 * omega_e_deg_s
    assert abs(got["angle_error_deg_e"]["mean"] - delays_s.mean() * omega_e_deg_s) <= sampling_deg
    assert abs(got["angle_error_deg_e"]["rms"] - np.sqrt(np.mean(delays_s ** 2)) * omega_e_deg_s) <= sampling_deg
    out = capsys.readouterr().out
    assert "; 0 located in an off-time" in out
    assert f"carrier: {carrier} (" in out


def test_carrier_mode_without_evidence_reports_the_turn_on():
    """Every commutation on the carrier grid (a restarted carrier, every sector 10 periods, the
    chopped phase changing each time): no commutation tells the carrier mode, so none is moved to
    an off-time midpoint; each is reported where the gates show it, and the summary says so."""
    from hil.signals.commutations import Extractor

    sectors = [0, 1, 2, 3, 4, 5, 0, 1]
    starts = np.arange(len(sectors)) * 500e-6
    t, s = _six_step_states(sectors, starts, starts[-1] + 500e-6, 20e3, 0.5, "high")
    ex = Extractor(100e-6)
    ex.feed(t, s)
    got = ex.finish(starts[-1] + 500e-6)
    tc, sc = got.commutations
    assert sc.tolist() == sectors[1:]
    assert np.allclose(tc, starts[1:], atol=1e-12)
    assert got.carrier == "undetermined" and got.carrier_free_evidence == got.carrier_restart_evidence == 0
    assert got.off_time_candidates > 0 and got.located_in_off_time == 0


def _sampled_at_1mhz(vcd: Path, out: Path) -> Path:
    """The 1 ns gate VCD as a logic analyzer sampling at 1 MHz would record it."""
    lines, last = [], None
    for line in vcd.read_text().splitlines():
        if line.startswith("$timescale"):
            line = "$timescale 1 us $end"
        elif line.startswith("#"):
            line = f"#{round(int(line[1:]) / 1000)}"
            if line == last:
                continue
            last = line
        lines.append(line)
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize("carrier", ["free", "center", "restart"])
def test_carrier_mode_of_a_sampled_capture(unlocked_stimulus, tmp_path, carrier, capsys):
    """A 23.3 kHz carrier (a period of 42.92 us, not a whole number of samples) captured at 1 MHz:
    turn-ons jitter by a sample, yet the capture's carrier mode is read without a dissenting
    commutation, and the free-running delay stays within 0.05 deg e (mean) and 3 % (RMS)."""
    pwm_hz = 23.3e3
    plan = independent_controller(unlocked_stimulus, tmp_path / "gates.vcd", pwm_hz=pwm_hz, carrier=carrier)
    got = score_json(unlocked_stimulus, _sampled_at_1mhz(tmp_path / "gates.vcd", tmp_path / "sampled.vcd"))
    mode = "restarted" if carrier == "restart" else "free-running"
    out = capsys.readouterr().out
    m = re.search(r"carrier: ([a-z-]+) \((\d+) commutations show the carrier grid running on across them, "
                  r"(\d+) show its phase reset", out)
    assert m and m.group(1) == mode, out
    free, restart = int(m.group(2)), int(m.group(3))
    assert (restart if mode == "free-running" else free) == 0 and (free if mode == "free-running" else restart) > 50
    delays_s = np.array([20e-6 + 4e-6 * s for _, s in plan])[1:]
    expected_deg = delays_s * UNLOCKED_RPM * 6.0 * POLE_PAIRS
    assert got["missed"] == 0 and got["extra"] == 0
    assert abs(got["angle_error_deg_e"]["mean"] - expected_deg.mean()) <= 0.05
    assert abs(got["angle_error_deg_e"]["rms"] / np.sqrt(np.mean(expected_deg ** 2)) - 1.0) <= 0.03


def _hidden_in_off_time(plan, pwm_hz, duty, carrier, chopped="high"):
    """Which commutations change the chopped phase while the free-running carrier is in its off-time,
    or exactly at its turn-on (the gates cannot tell these apart), in the controller's own
    whole-nanosecond carrier; and the off-interval (start, end) in seconds that holds each."""
    period_ns = round(1e9 / pwm_hz)
    on_ns = round(duty * period_ns)
    lead_ns = round((1.0 - duty) / 2 * period_ns) if carrier == "center" else 0
    hidden, spans = [], []
    for (_, s_prev), (t, s) in zip(plan, plan[1:]):
        t_ns = round(t * 1e9)
        rel = (t_ns - lead_ns) % period_ns  # time since the last turn-on
        role = 0 if chopped == "high" else 1
        hidden.append(PAIR_OF_SECTOR[s][role] != PAIR_OF_SECTOR[s_prev][role] and (rel == 0 or rel >= on_ns))
        end_ns = t_ns + (period_ns - rel) % period_ns
        spans.append(((end_ns - (period_ns - on_ns)) * 1e-9, end_ns * 1e-9))
    return np.array(hidden), np.array(spans)


@pytest.mark.parametrize("duty", [0.1, 0.3, 0.5, 0.8, 0.95])
@pytest.mark.parametrize(
    "carrier,chopped,complementary",
    [
        ("free", "high", False),
        ("center", "high", False),
        ("restart", "high", False),
        ("free", "low", False),
        ("center", "low", False),
        ("free", "high", True),
    ],
    ids=["free-high", "center-high", "restart-high", "free-low", "center-low", "free-complementary"],
)
def test_commutation_hidden_in_off_time_is_located_at_its_midpoint(
    unlocked_stimulus, tmp_path, carrier, chopped, complementary, duty
):
    """Each change of the chopped phase hidden in a free-running off-time (high or low side
    chopped) is reported at the midpoint of that off-interval, so within half the off-time of the
    true instant, and counted; every other commutation (of the unchopped side, during an on-time,
    of a carrier restarted at commutation, of complementary PWM with dead time) stays exact."""
    from hil.recording.formats import open_capture
    from hil.signals.commutations import extract

    pwm_hz = 20e3
    plan = independent_controller(
        unlocked_stimulus,
        tmp_path / "gates.vcd",
        pwm_hz=pwm_hz,
        duty=duty,
        carrier=carrier,
        chopped=chopped,
        complementary=complementary,
        dead_time_s=0.5e-6,
    )
    ex = extract(open_capture(tmp_path / "gates.vcd"))
    t_c, s_c = ex.commutations
    made = np.array([t for t, _ in plan[1:]])
    assert np.array_equal(s_c, [s for _, s in plan[1:]])
    assert ex.glitches == 0
    hidden, spans = _hidden_in_off_time(plan, pwm_hz, duty, carrier, chopped)
    if carrier == "restart" or complementary:
        hidden[:] = False  # the new phase conducts at once
    else:
        assert hidden.sum() > 0
    assert ex.located_in_off_time == hidden.sum()
    ns = 1e-9  # the VCD's timescale
    assert np.all(np.abs(t_c[~hidden] - made[~hidden]) <= ns)
    assert np.allclose(t_c[hidden], spans[hidden].mean(axis=1), atol=ns, rtol=0)
    assert np.all(np.abs(t_c[hidden] - made[hidden]) <= (1 - duty) / pwm_hz / 2 + ns)


def test_rotated_pair_table_is_scored_and_reported(ideal_stimulus, tmp_path, capsys):
    """A controller whose six-step table is rotated by one sector (another Hall alignment) is
    still scored against the right instants, and the summary says its table differs."""
    global PAIR_OF_SECTOR
    saved = dict(PAIR_OF_SECTOR)
    try:
        PAIR_OF_SECTOR = {s: saved[(s + 1) % 6] for s in range(6)}
        plan = independent_controller(ideal_stimulus, tmp_path / "gates.vcd")
    finally:
        PAIR_OF_SECTOR = saved
    got = score_json(ideal_stimulus, tmp_path / "gates.vcd")
    assert "do not follow the documented six-step table" in capsys.readouterr().out
    assert got["missed"] == 0 and got["extra"] == 0 and got["commutations"] == len(plan) - 1
    assert abs(got["angle_error_deg_e"]["mean"] - 30e-6 * OMEGA_E_DEG_S) <= 0.05


# --- exported phase currents --------------------------------------------------------------------------------
@pytest.mark.parametrize("rpm", [3000.0, 6000.0, 12000.0])
def test_exported_currents_hold_their_speed_on_the_plant(rpm):
    """The stimulus' currents are those of a motor turning steadily at the stimulus' speed: on the
    plant (ideal commutation, from that speed) the tabulated duty keeps the speed within 0.5 rpm
    over 0.2 s and its mean electromagnetic torque is the pump load's within 1 % (the analytic
    L -> 0 duty misses both: at 6000 rpm it loses 9.5 rpm and gives 61 % of the torque)."""
    from bldc.motor import steady_state
    from hil.signals.currents import tabulate
    from plant_models import OracleCommutation, Simulation, paper_bench

    config = paper_bench()
    tables = tabulate(config, [rpm])
    k = int(np.nonzero(tables.speeds_rpm == rpm)[0][0])
    sim = Simulation(
        config,
        OracleCommutation(),
        duty=float(tables.duty[k]),
        initial_speed_rpm=rpm,
        sample_rate_hz=100e3,
        max_step_s=2e-6,
    )
    sim.run_until(0.25)
    s = sim.samples()
    late = s.t_s >= 0.05  # past the winding currents' settling
    drift_rpm = float(s.speed_rpm[late][-1] - s.speed_rpm[late][0])
    load_n_m = steady_state(config.motor, rpm)["torque_n_m"]
    assert abs(drift_rpm) <= 0.5, drift_rpm
    assert abs(np.mean(s.torque_n_m[late]) / load_n_m - 1.0) <= 0.01
    # and the table is that motor's current (mean |i| over phases and turns within 1 %)
    assert np.mean(np.abs(s.i_true_a[late])) == pytest.approx(tables.mean_abs_current_a(rpm), rel=0.01)


# --- loopback against the lockstep bench ------------------------------------------------------------------
@pytest.fixture(scope="module")
def deterministic_plant():
    """Paper-sized deterministic deviations (no jitter: both paths see the same edges) and the
    calibration station's tables for them."""
    from hil.calibration.campaign import station_corrections
    from plant_models import effects as fx
    from plant_models import paper_bench
    from plant_models.plant import PAPER_BENCH_CIRCUIT, paper_installation_offsets_deg_e, paper_pole_offsets_deg_e

    config = paper_bench().with_effects(
        fx.InstallationOffset(offset_deg_e=paper_installation_offsets_deg_e()),
        fx.PoleOffset(offset_deg_e=paper_pole_offsets_deg_e()),
        fx.ConditioningDelay.from_circuit(PAPER_BENCH_CIRCUIT),
        fx.TimerQuantization(tick_s=1e-7),
    )
    return config, station_corrections(config)


@pytest.mark.parametrize("rpm", [SPEED_RPM, 10000.0, 12000.0])
@pytest.mark.parametrize("strategy", ["RAW", "CORRECTED", "SAGE_HUSA"])
def test_loopback_matches_the_lockstep_bench(tmp_path, deterministic_plant, strategy, rpm):
    """The same controller with the same deterministic effects (and, corrected, the same
    calibration): once closed-loop on the lockstep bench, once through a stimulus VCD and its
    gate VCD. Mean, RMS and per-sector mean commutation error agree within the sample-rate
    bound. At 10,000 rpm each sector lasts 10 periods of the 20 kHz carrier, which the loopback
    restarts at commutation: each restart then turns on on the old carrier's grid, as a change
    hidden in a free-running off-time would; the capture's carrier mode (docs/signals.md) keeps
    every commutation where the gates made it."""
    from bldc.contract import Strategy
    from bldc.motor import steady_state
    from hil.bench.lockstep import LockstepBench
    from hil.controller.virtual import VirtualController
    from hil.dut.in_process import InProcessLink
    from hil.signals.export import ExportSettings, export
    from hil.signals.loopback import run_loopback
    from hil.signals.score import score

    config, corrections = deterministic_plant
    fs = 1e6

    def link():
        lk = InProcessLink(VirtualController(config.motor, strategy=Strategy[strategy], speed_setpoint_rpm=rpm))
        if strategy != "RAW":
            lk.download_calibration(corrections)
        return lk

    bench = LockstepBench(
        config,
        link(),
        initial_speed_rpm=rpm,
        duty=steady_state(config.motor, rpm)["duty"],
        sim_options={"max_step_s": 2e-6},
    )
    bench.sim.run_until(0.6)
    c = bench.sim.commutations()
    keep = c.t_s >= 0.1  # past the controller's start and pole alignment on both paths
    lock_err, lock_sector = c.error_deg_e[keep], c.sector[keep]
    s = bench.sim.samples()
    speed = float(np.mean(s.speed_rpm[s.t_s >= 0.1]))
    # the plant runs where it was meant to (the stimulus takes the speed measured here): raw Hall
    # commutation at 12,000 rpm draws its current limit, and a speed loop that does not wind up
    # against it holds 1.1 % below the set point
    assert abs(speed - rpm) < 0.02 * rpm

    export(
        tmp_path / "stim",
        ExportSettings(config=config, breakpoints=[(0.0, speed)], duration_s=0.6, sample_rate_hz=fs, write_csv=False),
    )
    run_loopback(
        tmp_path / "stim",
        link(),
        tmp_path / "gates.vcd",
        pwm_frequency_hz=config.inverter.pwm_frequency_hz,
        capture_tick_s=config.compile().timer_tick_s,
    )
    sc = score(tmp_path / "stim", tmp_path / "gates.vcd")
    assert sc.missed == 0 and sc.extra == 0
    assert sc.extracted.located_in_off_time == 0  # every commutation seen where the gates made it
    late = sc.t_ideal_s >= 0.1
    err, sector = sc.angle_error_deg_e[late], sc.sector[late]
    assert abs(err.size - lock_err.size) <= 2
    # pin quantisation (half a sample) plus gate quantisation (half a sample), as an angle
    bound_deg = 1.0 / fs * speed * 6.0 * POLE_PAIRS
    assert abs(np.mean(err) - np.mean(lock_err)) <= bound_deg
    assert abs(np.sqrt(np.mean(err**2)) - np.sqrt(np.mean(lock_err**2))) <= bound_deg
    for q in range(6):
        assert abs(np.mean(err[sector == q]) - np.mean(lock_err[lock_sector == q])) <= bound_deg, q


# --- capture formats -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def loopback_gates(ideal_stimulus, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("gates") / "gates.vcd"
    assert hil_main(["signals", "loopback", str(ideal_stimulus), "--out", str(out)]) == 0
    return out


def _sigrok() -> str:
    exe = shutil.which("sigrok-cli")
    if exe is None:
        pytest.skip(
            "sigrok-cli is not installed (Debian package sigrok-cli; .ci/run installs it): the .sr reader is not "
            "checked "
            "against the real tool's files in this run"
        )
    return exe


def test_sigrok_session_scores_the_same_as_its_vcd(ideal_stimulus, loopback_gates, tmp_path):
    exe = _sigrok()
    sr = tmp_path / "gates.sr"
    subprocess.run(
        [exe, "-I", "vcd", "-i", str(loopback_gates), "-o", str(sr)], check=True, capture_output=True, timeout=300
    )
    a, b = score_json(ideal_stimulus, loopback_gates), score_json(ideal_stimulus, sr)
    assert a["commutations"] == b["commutations"] > 500 and a["missed"] == b["missed"] and a["extra"] == b["extra"]
    for group in ("angle_error_deg_e", "time_error_s"):
        for k, v in a[group].items():
            assert b[group][k] == pytest.approx(v, rel=1e-9, abs=1e-12), (group, k)


def test_sigrok_csv_export_scores_the_same_as_its_vcd(ideal_stimulus, loopback_gates, tmp_path):
    """libsigrok's CSV (time column on, channel labels): its time unit and its one-sample offset
    are read from its header comments."""
    exe = _sigrok()
    sr = tmp_path / "gates.sr"
    subprocess.run(
        [exe, "-I", "vcd", "-i", str(loopback_gates), "-o", str(sr)], check=True, capture_output=True, timeout=300
    )
    csv = tmp_path / "gates.csv"
    with open(csv, "w") as f:
        subprocess.run(
            [exe, "-i", str(sr), "-O", "csv:time=true:label=channel:dedup=true"], check=True, stdout=f, timeout=300
        )
    a, b = score_json(ideal_stimulus, loopback_gates), score_json(ideal_stimulus, csv)
    assert a["commutations"] == b["commutations"] and a["missed"] == b["missed"] and a["extra"] == b["extra"]
    assert b["angle_error_deg_e"]["mean"] == pytest.approx(a["angle_error_deg_e"]["mean"], abs=1e-9)


def test_csv_capture_with_mapping_and_inverted_channels(ideal_stimulus, loopback_gates, tmp_path):
    """A change-list CSV (Saleae-like: "Time [s]", channels by other names, two active-low)."""
    from hil.recording.capture import GATES
    from hil.recording.formats import open_capture

    rows = []
    for t, s in open_capture(loopback_gates).states():
        for ti, si in zip(t.tolist(), s.tolist()):
            bits = [(si >> j) & 1 for j in range(6)]
            bits[1] ^= 1  # AL wired through an inverting driver
            rows.append(f"{ti:.9f}," + ",".join(map(str, bits)))
    csv = tmp_path / "gates.csv"
    csv.write_text("Time [s]," + ",".join(f"Channel {j}" for j in range(6)) + "\n" + "\n".join(rows) + "\n")
    mapping = tmp_path / "map.toml"
    mapping.write_text(
        'active_low = ["AL"]\n[channels]\n' + "".join(f'{g} = "Channel {j}"\n' for j, g in enumerate(GATES))
    )
    a, b = score_json(ideal_stimulus, loopback_gates), score_json(ideal_stimulus, csv, "--mapping", str(mapping))
    assert a["commutations"] == b["commutations"] and b["missed"] == 0 and b["extra"] == 0
    assert b["angle_error_deg_e"]["rms"] == pytest.approx(a["angle_error_deg_e"]["rms"], rel=1e-6)


# --- hold-off and PWM --------------------------------------------------------------------------------------------
def _gates_vcd(path: Path, events: list[tuple[float, str, int]], end_s: float) -> Path:
    from hil.recording.capture import GATES
    from hil.recording.vcd import Timescale, VcdWriter

    w = VcdWriter(path, Timescale(1, "ns"), list(GATES))
    w.initial([0] * 6)
    events = sorted(events)
    w.changes(
        np.array([round(t * 1e9) for t, _, _ in events]),
        np.array([GATES.index(g) for _, g, _ in events]),
        np.array([v for _, _, v in events], dtype=float),
    )
    w.close(round(end_s * 1e9))
    return path


def test_glitch_on_the_floating_phase_is_not_a_commutation(tmp_path):
    from hil.recording.formats import open_capture
    from hil.signals.commutations import extract

    ev = [(0.0, "CL", 1), (0.0, "BH", 1)]  # sector 4: B high, C low
    ev += [(300e-6, "AH", 1), (302e-6, "AH", 0)]  # 2 us spike on the floating phase A
    ev += [(600e-6, "CL", 0), (600e-6, "AL", 1)]  # commutation to sector 5: B high, A low
    for k in range(40):  # B's high side chopped at 20 kHz throughout
        ev += [(k * 50e-6 + 25e-6, "BH", 0), (k * 50e-6 + 50e-6 - 1e-9, "BH", 1)]
    ex = extract(open_capture(_gates_vcd(tmp_path / "g.vcd", ev, 2e-3)))
    t, s = ex.commutations
    assert ex.glitches == 1
    assert t.tolist() == pytest.approx([600e-6]) and s.tolist() == [5]


def test_hold_off_longer_than_a_sector_is_refused(ideal_stimulus, loopback_gates, capsys):
    assert hil_main(["signals", "score", str(ideal_stimulus), str(loopback_gates), "--hold-off-s", "1e-3"]) == 2
    assert "shortest sector" in capsys.readouterr().err


# --- the stimulus itself ---------------------------------------------------------------------------------------------
def test_stimulus_hall_edges_are_the_plant_edges_within_half_a_sample(tmp_path):
    """On a ramp with paper-sized deviations: every Hall change in the VCD is a conditioned
    edge of the kinematic plant (same trajectory and seed) within half a sample period, and the
    truth instants are where the trajectory reaches 60 n deg e."""
    from hil.signals.export import ExportSettings, _chunk_edges, export
    from hil.signals.trajectory import Trajectory
    from hil.recording.vcd import VcdReader
    from plant_models import paper_bench

    fs = 250e3
    config = paper_bench(True)
    points = [(0.0, 2000.0), (0.3, 9000.0)]
    settings = ExportSettings(
        config=config, breakpoints=points, duration_s=0.3, sample_rate_hz=fs, seed=7, currents=False, write_csv=False
    )
    export(tmp_path, settings)
    r = VcdReader(tmp_path / "stimulus.vcd")
    ticks, slot, val = (np.concatenate(a) for a in zip(*r.changes(["HA", "HB", "HC"])))
    t_vcd = ticks[ticks > 0] * r.timescale.seconds
    traj = Trajectory(points, 0.3, config.motor.pole_pairs)
    from hil.signals import export as ex_mod

    plant_t = np.sort(
        np.concatenate(
            [
                _chunk_edges(
                    config, traj, k * ex_mod.CHUNK_S, min((k + 1) * ex_mod.CHUNK_S, 0.3), settings, None, chunk=k
                ).t_conditioned_s
                for k in range(math.ceil(0.3 / ex_mod.CHUNK_S))
            ]
        )
    )
    plant_t = plant_t[(plant_t > 0.5 / fs) & (plant_t < 0.3 - 0.5 / fs)]
    assert t_vcd.size == plant_t.size
    assert np.max(np.abs(np.sort(t_vcd) - plant_t)) <= 0.5 / fs + 1e-12
    truth = np.genfromtxt(tmp_path / "truth.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert np.allclose(traj.angle_deg_e(truth["t_ideal_s"]), 60.0 * truth["n"], atol=1e-6)
    assert np.allclose(truth["speed_rpm"], np.interp(truth["t_ideal_s"], [0, 0.3], [2000, 9000]), rtol=1e-9)


def test_csv_is_the_vcd_sampled(tmp_path):
    """stimulus.csv holds, at every sample, the values the VCD defines there."""
    import pandas as pd

    from hil.recording.vcd import VcdReader

    argv = ["signals", "export", "--out", str(tmp_path), "--duration-s", "0.05", "--sample-rate-hz", "200000",
            "--seed", "3"]
    assert hil_main(argv) == 0
    csv = pd.read_csv(tmp_path / "stimulus.csv")
    r = VcdReader(tmp_path / "stimulus.vcd")
    names = ["HA", "HB", "HC", "IA", "IB", "IC"]
    ticks, slot, val = (np.concatenate(a) for a in zip(*r.changes(names)))
    k = np.rint(csv["t_s"].to_numpy() / r.timescale.seconds).astype(np.int64)
    assert len(csv) == 10000
    for j, name in enumerate(names):
        mine = slot == j
        idx = np.searchsorted(ticks[mine], k, side="right") - 1
        assert np.allclose(csv[name].to_numpy(), val[mine][idx], atol=1e-9), name


def test_chunk_seams_do_not_change_the_stimulus(tmp_path, monkeypatch):
    """Streaming in short chunks gives the same Hall edges and truth as one long chunk."""
    from hil.signals import export as ex_mod
    from plant_models import paper_bench

    def run(chunk_s, out):
        monkeypatch.setattr(ex_mod, "CHUNK_S", chunk_s)
        s = ex_mod.ExportSettings(
            config=ex_mod.ideal(paper_bench()),
            breakpoints=[(0, 3000.0)],
            duration_s=0.2,
            currents=False,
            write_csv=False,
        )
        ex_mod.export(out, s)
        return (out / "truth.csv").read_text(), [
            ln for ln in (out / "stimulus.vcd").read_text().splitlines() if not ln.startswith(" ")
        ]

    a, b = run(0.2, tmp_path / "one"), run(0.03, tmp_path / "many")
    assert a[0] == b[0]
    assert a[1] == b[1]


def test_timescale_is_the_sample_period():
    from hil.recording.vcd import Timescale

    assert Timescale.for_sample_rate(1e6) == (Timescale(1, "us"), 1)
    assert Timescale.for_sample_rate(2e6) == (Timescale(100, "ns"), 5)
    assert Timescale.for_sample_rate(10e6) == (Timescale(100, "ns"), 1)
    assert Timescale.for_sample_rate(20e3) == (Timescale(10, "us"), 5)


def test_bad_inputs_name_the_file_and_place(tmp_path, ideal_stimulus, capsys):
    bad = tmp_path / "bad.vcd"
    bad.write_text("$timescale 3 us $end\n$enddefinitions $end\n")
    assert hil_main(["signals", "score", str(ideal_stimulus), str(bad)]) == 2
    assert f"{bad}, line 1: $timescale '3 us'" in capsys.readouterr().err
    nogates = tmp_path / "g.vcd"
    nogates.write_text("$timescale 1 us $end\n$var wire 1 ! X $end\n$enddefinitions $end\n#0\n0!\n")
    assert hil_main(["signals", "score", str(ideal_stimulus), str(nogates)]) == 2
    assert "no variable 'AH'" in capsys.readouterr().err
    assert hil_main(["signals", "score", str(ideal_stimulus), str(nogates), "--channels", "XH=1"]) == 2
    assert "'XH' is not a gate" in capsys.readouterr().err
    csv = tmp_path / "c.csv"
    csv.write_text("t_s,AH,AL,BH,BL,CH,CL\n0,0,0,0,0,0,0\n1e-6,0,1,0,0,0,0\n0.5e-6,1,1,0,0,0,0\n")
    assert hil_main(["signals", "score", str(ideal_stimulus), str(csv)]) == 2
    assert f"{csv}, line 4: time goes back" in capsys.readouterr().err


@pytest.mark.parametrize("block_bytes", [113, 4093])
def test_vcd_reader_blocks_do_not_change_the_changes(ideal_stimulus, monkeypatch, block_bytes):
    """Reading in small blocks (tokens and value/identifier pairs cut at every place) gives the
    same changes as reading the file whole."""
    from hil.recording.vcd import VcdReader

    names = ["HA", "HB", "HC", "IA", "IB", "IC"]
    whole = [np.concatenate(a) for a in zip(*VcdReader(ideal_stimulus / "stimulus.vcd").changes(names))]
    monkeypatch.setattr(VcdReader, "BLOCK_BYTES", block_bytes)
    small = [np.concatenate(a) for a in zip(*VcdReader(ideal_stimulus / "stimulus.vcd").changes(names))]
    assert whole[0].size > 10000
    for a, b in zip(whole, small):
        assert np.array_equal(a, b)


def _six_step_states(sectors, starts, end, pwm_hz, duty, scheme):
    """(t, state) of a six-step drive: carrier restarted at each commutation (on first)."""
    hi_lo = {0: (2, 0), 1: (2, 1), 2: (0, 1), 3: (0, 2), 4: (1, 2), 5: (1, 0)}
    t_out, s_out = [], []
    period = 1.0 / pwm_hz
    for k, (s, t0) in enumerate(zip(sectors, starts)):
        t1 = starts[k + 1] if k + 1 < len(starts) else end
        hi, lo = hi_lo[s]
        n = 0
        while t0 + n * period < t1:
            for frac, on in ((0.0, True), (duty, False)):
                t = t0 + (n + frac) * period
                if t < t1:
                    chop_h, chop_l = (on, True) if scheme == "high" else (True, on) if scheme == "low" else (on, True)
                    bits = (chop_h << (2 * hi)) | (chop_l << (2 * lo + 1))
                    if scheme == "complementary" and not on:
                        bits |= 1 << (2 * hi + 1)
                    t_out.append(t)
                    s_out.append(bits)
            n += 1
    return np.array(t_out), np.array(s_out, dtype=np.int64)


from hypothesis import assume, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(deadline=None, max_examples=60, derandomize=True, database=None)
@given(first=st.integers(0, 5), steps=st.lists(st.sampled_from([1, 1, 1, 5]), min_size=3, max_size=30),
       gaps_us=st.lists(st.floats(150.0, 2000.0), min_size=30, max_size=30), pwm_hz=st.floats(10e3, 40e3),
       duty=st.floats(0.05, 0.95), scheme=st.sampled_from(["high", "low", "complementary"]),
       whole_periods=st.lists(st.booleans(), min_size=30, max_size=30))
def test_every_commutation_and_no_pwm_edge_is_found(first, steps, gaps_us, pwm_hz, duty, scheme, whole_periods):
    """Random six-step runs (either direction of stepping, sector lengths down to 1.5 hold-offs),
    PWM on the high side, the low side or complementary, any duty: the extractor finds exactly
    the commutations, at their instants, with their sectors (derandomized: reproducible). Some
    sectors are a whole number of PWM periods long: the restart's turn-on then lies on the old
    carrier's grid, as a change hidden in a free-running off-time would, and stays exact because
    the run never shows a free-running carrier (docs/signals.md)."""
    from hil.signals.commutations import Extractor

    gaps_us = [math.ceil(g * 1e-6 * pwm_hz) / pwm_hz * 1e6 if whole else g for g, whole in zip(gaps_us, whole_periods)]

    sectors = [first]
    for d in steps:
        sectors.append((sectors[-1] + d) % 6)
    starts = np.concatenate([[0.0], np.cumsum(np.array(gaps_us[: len(steps)]) * 1e-6)])
    end = starts[-1] + 1e-3
    t, s = _six_step_states(sectors, starts, end, pwm_hz, duty, scheme)
    ex = Extractor(100e-6)
    half = t.size // 2  # two chunks: the state carries over
    ex.feed(t[:half], s[:half])
    ex.feed(t[half:], s[half:])
    got = ex.finish(end)
    tc, sc = got.commutations
    assert sc.tolist() == sectors[1:]
    assert np.allclose(tc, starts[1:], atol=1e-12)
    assert got.glitches == 0
    assert got.located_in_off_time == 0 and got.carrier_free_evidence == 0


def test_gates_as_bits_of_a_vector(ideal_stimulus, loopback_gates, tmp_path):
    """A capture that dumps the six gates as one bus (``gates[5:0]``, bit 0 = AH) scores the
    same as six wires, mapped as gates[0] ... gates[5]."""
    from hil.recording.capture import GATES
    from hil.recording.formats import open_capture

    lines = [
        "$timescale 1 us $end",
        "$scope module dut $end",
        "$var wire 6 ! gates [5:0] $end",
        "$upscope $end",
        "$enddefinitions $end",
    ]
    for t, s in open_capture(loopback_gates).states():
        for ti, si in zip(t.tolist(), s.tolist()):
            lines += [f"#{round(ti * 1e6)}", f"b{si:b} !"]
    bus = tmp_path / "bus.vcd"
    bus.write_text("\n".join(lines) + "\n#500000\n")
    channels = ",".join(f"{g}=gates[{j}]" for j, g in enumerate(GATES))
    a, b = score_json(ideal_stimulus, loopback_gates), score_json(ideal_stimulus, bus, "--channels", channels)
    assert a == b


@settings(deadline=None, max_examples=60, derandomize=True, database=None)
@given(first=st.integers(0, 5), steps=st.lists(st.sampled_from([1, 1, 1, 5]), min_size=3, max_size=30),
       gaps_us=st.lists(st.floats(190.0, 2000.0), min_size=30, max_size=30), pwm_hz=st.floats(10.5e3, 40e3),
       duty=st.floats(0.1, 0.95), side=st.sampled_from(["high", "low"]), center=st.booleans())
def test_free_running_carrier_commutations_are_exact_or_at_the_off_time_midpoint(
    first, steps, gaps_us, pwm_hz, duty, side, center
):
    """Random six-step runs under a free-running carrier (edge- or center-aligned, high or low side
    chopped, any duty): a commutation of the unchopped side or during an on-time is exact; one of
    the chopped side inside an off-time is at that off-interval's midpoint when the old switch's
    last two turn-ons show the carrier period, else at the next turn-on; never a PWM edge taken
    for a commutation (derandomized: reproducible). Sectors are at least the hold-off plus the
    longest off-time (100 + 86 us): a commutation hidden in an off-time opens its window late by
    up to the off-time, and that window must close before the next commutation (docs/signals.md)."""
    from hil.signals.commutations import Extractor

    sectors = [first]
    for d in steps:
        sectors.append((sectors[-1] + d) % 6)
    starts = np.concatenate([[0.0], np.cumsum(np.array(gaps_us[: len(steps)]) * 1e-6)]) + 7e-6
    end = starts[-1] + 1e-3
    period = 1.0 / pwm_hz
    lead = (1.0 - duty) / 2 * period if center else 0.0
    k = np.arange(-1, math.ceil(end / period) + 1)
    on_edges, off_edges = k * period + lead, k * period + lead + duty * period
    # a commutation on a carrier edge is a tie the gates cannot order (and floats may place on
    # either side): kept at least a nanosecond apart
    assume(np.min(np.abs(starts[:, None] - np.concatenate([on_edges, off_edges])[None, :])) > 1e-9)
    t = np.unique(np.concatenate([[0.0], starts, on_edges, off_edges]))
    t = t[(t >= 0.0) & (t < end)]
    hi_lo = {0: (2, 0), 1: (2, 1), 2: (0, 1), 3: (0, 2), 4: (1, 2), 5: (1, 0)}
    role = 0 if side == "high" else 1

    def pwm_on(x):
        return (
            np.nonzero(on_edges <= x)[0][-1] == np.nonzero(off_edges <= x)[0][-1] + 1
            if (off_edges <= x).any()
            else True
        )

    states = []
    for a, b in zip(t, np.append(t[1:], end)):
        mid = 0.5 * (a + b)
        hi, lo = hi_lo[sectors[np.searchsorted(starts, mid, side="right") - 1]] if mid >= starts[0] else (None, None)
        if hi is None:
            states.append(0)
            continue
        chop = pwm_on(mid)
        states.append(((chop if role == 0 else 1) << (2 * hi)) | ((chop if role == 1 else 1) << (2 * lo + 1)))
    ex = Extractor(100e-6)
    ex.feed(t, np.array(states, dtype=np.int64))
    got = ex.finish(end)
    tc, sc = got.commutations
    assert sc.tolist() == sectors[1:]
    assert got.glitches == 0
    # where the gates show each commutation: its instant, or the carrier's next turn-on when the
    # chopped phase changed in an off-time; and whether the run tells the carrier mode: some
    # commutation seen at its instant, off the grid (kept so above), after two grid turn-ons of the
    # old chopped switch in the old pair's time (docs/signals.md)
    hidden = [i > 0 and hi_lo[sectors[i - 1]][role] != hi_lo[sectors[i]][role] and not pwm_on(starts[i])
              for i in range(len(sectors))]
    shown = [on_edges[on_edges > starts[i]].min() if hidden[i] else starts[i] for i in range(len(sectors))]
    free_shown = any(not hidden[i] and ((on_edges > shown[i - 1]) & (on_edges < starts[i])).sum() >= 2
                     for i in range(1, len(sectors)))
    assert got.carrier == ("free-running" if free_shown else "undetermined")
    assert got.carrier_restart_evidence == 0
    located = 0
    for i in range(1, len(sectors)):
        tk = starts[i]
        chopped_old, chopped_new = hi_lo[sectors[i - 1]][role], hi_lo[sectors[i]][role]
        if chopped_old == chopped_new or pwm_on(tk):
            assert tc[i - 1] == pytest.approx(tk, abs=1e-12)
            continue
        t_off, t_on = off_edges[off_edges <= tk].max(), on_edges[on_edges > tk].min()
        # the old switch's stint as the chopped one, and its grid turn-ons in it
        j = i - 1
        while j > 0 and hi_lo[sectors[j - 1]][role] == chopped_old:
            j -= 1
        turn_ons = on_edges[(on_edges > starts[j]) & (on_edges < tk)]
        if turn_ons.size >= 2 and free_shown:
            located += 1
            assert tc[i - 1] == pytest.approx(0.5 * (t_off + t_on), abs=1e-12)
        else:
            assert tc[i - 1] == pytest.approx(t_on, abs=1e-12)
    assert got.located_in_off_time == located


@pytest.mark.parametrize("first_pair_done", [True, False])
def test_a_commutation_the_start_already_made_is_not_missed(first_pair_done):
    """The first pair the gates show is the controller's start, not a commutation. When the start is
    1.5 us before an ideal commutation and already energises the pair it asks for (the twin of the
    spindle's loopback: its Hall edges lead), that commutation is done, not missed; a start on the
    previous pair that never commutates misses it."""
    from hil.signals.commutations import Extracted
    from hil.signals.score import Truth, score_extracted

    n = np.arange(1, 21)
    t_ideal = 1e-3 * n  # one sector per ms: 60,000 deg e per s, 5000 rpm at 2 pole pairs
    truth = Truth(n=n, t_ideal_s=t_ideal, sector=n % 6, speed_rpm=np.full(n.size, 5000.0), pole_pairs=2,
                  sample_rate_hz=1e6, meta={})
    start = t_ideal[0] - 1.5e-6
    first = truth.sector[0] if first_pair_done else (truth.sector[0] - 1) % 6
    t_s = np.concatenate(([start], t_ideal[1:]))
    sector = np.concatenate(([first], truth.sector[1:]))
    ex = Extracted(t_s=t_s, sector=sector, initial=np.arange(t_s.size) == 0, start_s=0.0, end_s=25e-3)
    got = score_extracted(truth, ex)
    assert got.missed == (0 if first_pair_done else 1), got.missed_t_s
    assert got.extra == 0 and got.commutations == n.size - 1
