"""The paper-bench demo: a run with paper-sized deviations, and the edge errors it shows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bldc.hall import SENSORS
from bldc.motor import steady_state
from plant_models import RawHallCommutation, Simulation, paper_bench

from .recording.drivers import motor_meta, recording_from_edges
from .recording.format import Segment, write_recording
from .verdicts.plots import pyplot, save


def edge_error_table(edges, pole_pairs: int) -> list[dict]:
    """Mean and RMS of the captured-edge angle error per sensor, polarity and pole."""
    err = edges.capture_error_deg_e
    rows = []
    for x, name in enumerate(SENSORS):
        for rising in (True, False):
            for pole in range(2 * pole_pairs):
                sel = (edges.sensor == x) & (edges.rising == rising) & (edges.pole == pole)
                if sel.any():
                    rows.append(
                        {
                            "sensor": name,
                            "edge": "rise" if rising else "fall",
                            "pole": pole,
                            "n": int(sel.sum()),
                            "mean_deg_e": float(err[sel].mean()),
                            "std_deg_e": float(err[sel].std()),
                        }
                    )
    return rows


def run_demo(
    speed_rpm: float = 5700.0, duration_s: float = 0.5, out_dir: str | Path = "reports/demo-recording", seed: int = 1
) -> dict:
    config = paper_bench(with_deviations=True)
    duty = steady_state(config.motor, speed_rpm)["duty"]
    sim = Simulation(config, RawHallCommutation(), duty=duty, initial_speed_rpm=speed_rpm, seed=seed)
    sim.run_until(0.2)  # let the currents settle
    sim.mark_segment(0)
    t0 = sim.t_s
    sim.run_until(t0 + duration_s)
    edges = sim.edges()
    samples = sim.samples()
    sel = edges.segment == 0
    seg = Segment(
        "op01", t0, sim.t_s, "forward", speed_rpm, float(np.abs(samples.i_true_a[samples.t_s >= t0]).mean()), 1.0
    )
    tick = config.compile().timer_tick_s
    ks = samples.t_s >= t0
    sample_cols = {
        "t_s": samples.t_s[ks],
        "segment": np.zeros(int(ks.sum()), dtype=np.int64),
        "i_a": samples.i_meas_a[ks, 0],
        "i_b": samples.i_meas_a[ks, 1],
        "i_c": samples.i_meas_a[ks, 2],
        "u_a": samples.u_v[ks, 0],
        "u_b": samples.u_v[ks, 1],
        "u_c": samples.u_v[ks, 2],
        "speed_rpm": samples.speed_rpm[ks],
    }
    rec = recording_from_edges(motor_meta(config), edges, [seg], timer_tick_s=tick, samples=sample_cols)
    path = write_recording(rec, out_dir)
    e = edges.take(sel)
    result = {
        "config": config,
        "edges": e,
        "table": edge_error_table(e, config.motor.pole_pairs),
        "recording": path,
        "speed_rpm": float(e.speed_rpm.mean()),
        "duty": duty,
    }
    result["plot"] = plot_demo(result, Path(out_dir).parent / "demo-edge-errors.png")
    return result


def plot_demo(result: dict, path: str | Path) -> Path:
    """Edge-error pattern of the demo run: per edge, coloured by sensor, rising vs falling."""
    e = result["edges"]
    err = e.capture_error_deg_e
    fig, (ax1, ax2) = pyplot().subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [2, 1]})
    n = np.arange(len(e))
    for x, name in enumerate(SENSORS):
        for rising, marker in ((True, "^"), (False, "v")):
            sel = (e.sensor == x) & (e.rising == rising)
            ax1.plot(n[sel][:72], err[sel][:72], marker, ms=4, ls="", label=f"{name} {'rise' if rising else 'fall'}")
    ax1.set_xlabel("captured edge index (first mechanical turns)")
    ax1.set_ylabel("edge error [deg electrical]\n(+ = trails ideal)")
    ax1.set_xlim(-1, 6 * 12 + 1)
    ax1.legend(ncol=3, fontsize=7, loc="lower right")
    ax1.grid(alpha=0.3)
    rows = result["table"]
    labels = [f"{r['sensor']}{'r' if r['edge'] == 'rise' else 'f'}{r['pole']}" for r in rows]
    ax2.barh(labels, [r["mean_deg_e"] for r in rows], xerr=[r["std_deg_e"] for r in rows], color="tab:blue")
    ax2.set_xlabel("mean error [deg e] per sensor/edge/pole")
    ax2.tick_params(axis="y", labelsize=7)
    ax2.invert_yaxis()
    fig.suptitle(f"{result['config'].name}: raw Hall commutation at {result['speed_rpm']:.0f} rpm", fontsize=10)
    return save(fig, path)


def print_demo(result: dict) -> None:
    e = result["edges"]
    err = e.capture_error_deg_e
    print(
        f"paper-bench demo: {result['config'].name}, raw Hall commutation, duty {result['duty']:.3f}, "
        f"mean speed {result['speed_rpm']:.0f} rpm, {len(e)} captured edges"
    )
    print("effects:", ", ".join(f.name for f in result["config"].effects))
    print(
        f"{'sensor':>6} {'edge':>5} {'pole':>4} {'n':>5} {'mean err':>10} {'std':>8}   (deg electrical, + = trails "
        "ideal)"
    )
    for r in result["table"]:
        print(
            f"{r['sensor']:>6} {r['edge']:>5} {r['pole']:>4} {r['n']:>5} {r['mean_deg_e']:>10.3f} "
            f"{r['std_deg_e']:>8.3f}"
        )
    print(
        f"all edges: mean {err.mean():.3f}, RMS {np.sqrt(np.mean(err**2)):.3f}, max |err| {np.abs(err).max():.3f} deg_e"
    )
    print(f"recording written to {result['recording']}")
    if result.get("plot"):
        print(f"edge-error plot written to {result['plot']}")
