"""``hil history trend``'s figure (matplotlib PNG) and page (the PNG inlined, the figures below)."""

from __future__ import annotations

import base64
from pathlib import Path


def trend_figure(trend: dict, path: str | Path) -> Path:
    """One budget's figure over the runs of one controller: a line per test that measured it, the
    limit dashed, each point coloured by its verdict, a build's first run marked on the axis."""
    from ..verdicts.plots import pyplot, save

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.5, 3.8))
    points = trend["points"]
    runs = sorted({p["run"] for p in points}, key=lambda r: next(p["started"] for p in points if p["run"] == r) or 0)
    x_of = {r: i for i, r in enumerate(runs)}
    colours = {"pass": "#2da44e", "marginal": "#bf8700", "fail": "#cf222e"}
    for test in dict.fromkeys(p["test"] for p in points):
        mine = [p for p in points if p["test"] == test]
        label = test.rpartition("::")[2] or test
        ax.plot([x_of[p["run"]] for p in mine], [p["measured"] for p in mine], "-", color="#8c959f", lw=1, zorder=1)
        ax.scatter([x_of[p["run"]] for p in mine], [p["measured"] for p in mine], s=18, zorder=2, label=label[:60],
                   c=[colours.get(p["verdict"], "#57606a") for p in mine])
    limits = sorted({p["limit_value"] for p in points if p["limit_value"] is not None})
    for lim in limits[-1:]:
        ax.axhline(lim, ls="--", color="#cf222e", lw=1, label=f"limit {lim:.4g}")
    builds, ticks, labels = None, [], []
    for r in runs:  # a tick where the build changes
        b = next(p["build"] for p in points if p["run"] == r)
        if b != builds:
            ticks.append(x_of[r])
            labels.append(f"{r}\n{(b or '-')[:14]}")
            builds = b
    ax.set_xticks(ticks, labels, fontsize=7)
    ax.set_xlabel("run (build where it changes)")
    ax.set_ylabel(f"{trend['budget']} [{trend['unit'].replace('_', ' ')}]")
    ax.set_title(f"{trend['budget']}: {trend['identity']}", fontsize=9)
    if len({p["test"] for p in points}) <= 6:
        ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    return save(fig, path, dpi=100)


def trend_page(trend: dict, png: Path, path: str | Path) -> Path:
    """The trend as one self-contained page."""
    import jinja2

    from ..verdicts.report import atomic_write

    template = jinja2.Environment(autoescape=True).from_string(
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{{ t.budget }} trend</title>"
        "<style>body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1100px}"
        "table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #d0d7de;padding:.2em .5em}"
        "td.num{text-align:right}.fail{background:#fbdada}.marginal{background:#fff4cc}</style></head><body>"
        "<h1>{{ t.budget }}</h1><p>{{ t.identity }}: {{ runs }} run(s) (the results history, docs/history.md)</p>"
        "<img alt='trend' src='data:image/png;base64,{{ png }}'>"
        "<table><tr><th>run</th><th>started (UTC)</th><th>build</th><th>station</th><th>measured</th><th>limit</th>"
        "<th>verdict</th><th>test</th></tr>{% for p in t.points %}<tr><td>{{ p.run }}</td><td>{{ p.started }}</td>"
        "<td>{{ p.build }}</td><td>{{ p.station }}</td><td class='num {{ p.verdict }}'>"
        "{{ '%.4g' | format(p.measured) }} {{ t.unit }}</td><td class='num'>{{ p.limit_value }}</td>"
        "<td>{{ p.verdict }}</td><td>{{ p.test }}</td></tr>"
        "{% endfor %}</table></body></html>")
    html = template.render(t=trend, runs=len({p["run"] for p in trend["points"]}),
                           png=base64.b64encode(Path(png).read_bytes()).decode())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, html)
    return path
