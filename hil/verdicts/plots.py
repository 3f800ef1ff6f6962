"""Figures for reports and docs: one place for the headless backend and saving."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: fixed colours and markers per run name, so that raw and corrected look different in every figure
_STYLE = {"raw": ("#d1495b", "o"), "corrected": ("#2e6fdb", "s"), "SAGE_HUSA": ("#2e6fdb", "o"), "KF": ("#e07a1f", "s"),
          "CORRECTED": ("#6a994e", "^")}
_CYCLE = [("#2e6fdb", "o"), ("#d1495b", "s"), ("#6a994e", "^"), ("#e07a1f", "D"), ("#7b2cbf", "v")]


def pyplot():
    """matplotlib.pyplot on the headless Agg backend (CI and servers have no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | Path, dpi: int = 110) -> Path:
    """Lay out, write and close ``fig``; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def judged_range(values: list[np.ndarray], budget: float | None = None, coverage: float = 99.0) -> tuple[float, float]:
    """A y-range holding ``coverage`` % of the judged points of every run (and the budget lines),
    so that a few outliers or a transient do not flatten what the figure judges."""
    lo, hi = [], []
    tail = (100.0 - coverage) / 2
    for v in values:
        v = np.asarray(v, dtype=float)
        v = v[np.isfinite(v)]
        if v.size:
            lo.append(np.percentile(v, tail))
            hi.append(np.percentile(v, 100.0 - tail))
    if budget is not None:
        lo.append(-abs(budget))
        hi.append(abs(budget))
    if not lo:
        return -1.0, 1.0
    a, b = min(lo), max(hi)
    pad = 0.12 * max(b - a, 1e-3)
    return a - pad, b + pad


def commutation_error_figure(
    runs: dict,
    title: str,
    judged_from_s: float | None = None,
    budget_deg_e: float | None = None,
    budget_label: str = "p99 budget",
):
    """Commutation angle error against plant time, one trace per run: ``runs[name] = (t_s, err_deg_e)``.


    With ``judged_from_s`` the figure has two panels: the start-up before it (not judged, on its
    own scale) and the judged window, scaled to the judged points so that runs a few tenths of
    a degree apart are visibly apart; each run's median is drawn as a dashed line and labelled.
    ``budget_deg_e`` draws the budget as lines at plus and minus its value."""
    plt = pyplot()
    split = judged_from_s is not None and any(np.any(np.asarray(t) < judged_from_s) for t, _ in runs.values())
    if split:
        fig, (ax0, ax) = plt.subplots(1, 2, figsize=(9.0, 3.2), gridspec_kw={"width_ratios": [1, 3.2]})
    else:
        fig, ax = plt.subplots(figsize=(9.0, 3.2))
    judged = {}
    for i, (name, (t, err)) in enumerate(runs.items()):
        t, err = np.asarray(t, dtype=float), np.asarray(err, dtype=float)
        colour, marker = _STYLE.get(name, _CYCLE[i % len(_CYCLE)])
        keep = t >= judged_from_s if judged_from_s is not None else np.ones(t.size, dtype=bool)
        judged[name] = err[keep]
        median = float(np.median(err[keep])) if keep.any() else float("nan")
        ax.plot(
            t[keep],
            err[keep],
            marker,
            ms=2.2,
            color=colour,
            alpha=0.75,
            linestyle="none",
            label=f"{name} (median {median:+.2f})",
        )
        if keep.any():
            ax.axhline(median, color=colour, linestyle="--", linewidth=1.0)
        if split:
            ax0.plot(t[~keep], err[~keep], marker, ms=1.8, color=colour, alpha=0.6, linestyle="none")
    if budget_deg_e is not None:
        for sign in (1, -1):
            ax.axhline(sign * budget_deg_e, color="#444", linewidth=1.1, linestyle="-")
        ax.annotate(
            f"{budget_label} ±{budget_deg_e:g} deg e",
            xy=(0.0, budget_deg_e),
            xycoords=("axes fraction", "data"),
            xytext=(4, 3),
            textcoords="offset points",
            fontsize=7.5,
            color="#444",
        )
    lo, hi = judged_range(list(judged.values()), budget_deg_e)
    ax.set_ylim(lo, hi + 0.2 * (hi - lo))  # a band at the top for the legend
    outside = sum(int(np.sum((e < lo) | (e > hi))) for e in judged.values())
    if outside:
        ax.text(
            0.99,
            0.02,
            f"{outside} points outside the shown range",
            transform=ax.transAxes,
            ha="right",
            fontsize=7,
            color="#666",
        )
    ax.set_xlabel("plant time (s)")
    ax.set_ylabel("commutation error (deg e)")
    ax.set_title(title + (" (judged window)" if split else ""), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5, markerscale=3, loc="upper right", ncol=len(runs), framealpha=0.9)
    if split:
        ax0.set_title("start-up (not judged)", fontsize=9)
        ax0.set_xlabel("plant time (s)")
        ax0.set_ylabel("commutation error (deg e)")
        ax0.grid(alpha=0.3)
    return fig
