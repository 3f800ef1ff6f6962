"""Figures for reports and docs: one place for the headless backend and saving."""

from __future__ import annotations

from pathlib import Path


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


def commutation_error_figure(runs: dict, title: str):
    """Commutation angle error against plant time, one trace per run: ``runs[name] = (t_s, err_deg_e)``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 2.8))
    for name, (t, err) in runs.items():
        ax.plot(t, err, ".", ms=2, label=name)
    ax.set_xlabel("plant time (s)")
    ax.set_ylabel("commutation error (deg e)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, markerscale=4)
    return fig
