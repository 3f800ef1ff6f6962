"""The envelope map: a budget's margin over two swept axes, with the pass/fail contour.

Each cell holds the worst (smallest) margin over every point sharing its two coordinates (the
other axes and the repeats), so a green cell passes whatever else was swept. Positive margin
passes, negative fails; the black line is margin = 0. Cells whose points all errored are grey
and crossed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..verdicts.plots import pyplot, save


def _positions(values: list) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """Cell centres and edges of one axis; categorical values sit at 0, 1, 2, ..."""
    if any(isinstance(v, str) for v in values):
        c = np.arange(len(values), dtype=float)
        return c, np.arange(len(values) + 1) - 0.5, [str(v) for v in values]
    c = np.asarray(values, dtype=float)
    if c.size == 1:
        return c, np.array([c[0] - 0.5, c[0] + 0.5]), None
    mid = (c[1:] + c[:-1]) / 2
    return c, np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]]), None


def margin_grid(table, x: str, y: str, budget: str, x_values: list, y_values: list) -> np.ndarray:
    """Worst margin per (y, x) cell; NaN where no point of the cell measured anything."""
    grid = np.full((len(y_values), len(x_values)), np.nan)
    col = f"{budget}.margin"
    for iy, yv in enumerate(y_values):
        for ix, xv in enumerate(x_values):
            sel = table[(table[x] == xv) & (table[y] == yv)]
            m = sel[col].to_numpy(dtype=float) if col in sel else np.array([])
            m = m[~np.isnan(m)]
            if m.size:
                grid[iy, ix] = np.min(m)
    return grid


def envelope_figure(
    table, x: str, y: str, budget: str, x_values: list, y_values: list, unit: str, limit: float, title: str
):
    from matplotlib.colors import TwoSlopeNorm

    plt = pyplot()
    grid = margin_grid(table, x, y, budget, x_values, y_values)
    finite = np.where(np.isinf(grid), np.nan, grid)
    xc, xe, xlab = _positions(x_values)
    yc, ye, ylab = _positions(y_values)
    # colours span +-|limit|: a margin of one limit either way is already far from the boundary,
    # and a lost-synchronisation point (margins of -180 deg) must not wash out the near misses
    scale = abs(limit) if limit else (np.nanmax(np.abs(finite)) if np.isfinite(finite).any() else 1.0)
    norm = TwoSlopeNorm(vmin=-scale, vcenter=0.0, vmax=scale)
    fig, ax = plt.subplots(figsize=(7.2, 4.8))
    # a -inf margin (nothing measured, e.g. no commutation) is the worst failure: shown at the scale's end
    shown = np.where(np.isneginf(grid), -scale, grid)
    mesh = ax.pcolormesh(
        xe, ye, np.ma.masked_invalid(np.clip(shown, -scale, scale)), cmap="RdYlGn", norm=norm, shading="flat"
    )
    cb = fig.colorbar(mesh, ax=ax, extend="both")
    cb.set_label(f"{budget} margin ({unit}); > 0 passes, colours clipped at +-{scale:g}", fontsize=8)
    empty = np.isnan(grid)
    for iy, ix in zip(*np.nonzero(empty)):
        ax.plot(xc[ix], yc[iy], "x", color="0.35", ms=8)
    if len(xc) >= 2 and len(yc) >= 2 and np.isfinite(shown).sum() >= 4 and np.nanmin(shown) < 0 < np.nanmax(shown):
        from matplotlib.lines import Line2D

        ax.contour(xc, yc, np.ma.masked_invalid(shown), levels=[0.0], colors="k", linewidths=2.0)
        ax.legend(
            [Line2D([], [], color="k", lw=2.0)],
            ["pass / fail (margin = 0)"],
            loc="upper right",
            fontsize=8,
            framealpha=0.8,
        )
    for labels, setter, ticks in ((xlab, ax.set_xticks, xc), (ylab, ax.set_yticks, yc)):
        if labels is not None:
            setter(ticks, labels)
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.set_title(title, fontsize=9)
    return fig


def write_envelope(table, spec, path: str | Path) -> Path | None:
    """The PNG for ``spec.map`` (None when the campaign has no second axis to map)."""
    if spec.map is None:
        return None
    axes = {a.name: list(a.values) for a in spec.axes}
    m = spec.map
    others = [a.name for a in spec.axes if a.name not in (m.x, m.y)] + (["repeats"] if spec.repeats > 1 else [])
    title = f"{spec.name}: {m.budget} ({spec.budgets[m.budget].limit:g} {spec.budgets[m.budget].unit})"
    if others:
        title += f", worst over {', '.join(others)}"
    fig = envelope_figure(
        table,
        m.x,
        m.y,
        m.budget,
        axes[m.x],
        axes[m.y],
        spec.budgets[m.budget].unit,
        spec.budgets[m.budget].limit,
        title,
    )
    return save(fig, path)
