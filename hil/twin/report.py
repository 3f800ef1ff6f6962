"""The twin check as a page: the tables of the JSON and two figures (sector widths against
speed per slot, real and twin; the residuals' autocorrelation)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np


def _figure(result: dict) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sw = result["sector_widths"]
    bins = np.array(sw["speed_bins_hz_e"])
    centre = 0.5 * (bins[1:] + bins[:-1])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for s in range(6):
        real = np.array(sw["real_deg_e"][s], dtype=float)
        twin = np.array(sw["twin_deg_e"][s], dtype=float)
        (line,) = a.plot(centre, real, "o-", label=f"slot {s} real")
        a.plot(centre, twin, "x--", color=line.get_color(), label=f"slot {s} twin")
    a.set_xlabel("speed (Hz electrical)")
    a.set_ylabel("sector width (deg e)")
    a.set_title("sector width against speed per slot: real (o) and twin (x)")
    a.legend(fontsize=6, ncol=2)
    lags = np.arange(1, len(result["noise"]["real"]["acf"]) + 1)
    b.bar(lags - 0.2, result["noise"]["real"]["acf"], width=0.4, label="real")
    b.bar(lags + 0.2, result["noise"]["twin"]["acf"], width=0.4, label="twin")
    se = result["noise"]["acf_stderr"]
    b.axhspan(-2 * se, 2 * se, color="grey", alpha=0.2)
    b.set_xlabel("lag (edges)")
    b.set_ylabel("autocorrelation of the angle residuals")
    b.legend()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_html(result: dict, path: str | Path) -> None:
    e = html.escape
    rows = []
    for k, f in result["calibration"]["real"].items():
        t = result["calibration"]["twin"].get(k)
        if not isinstance(f, dict) or "value" not in f:
            continue
        c = result["calibration"]["comparison"].get(k, {})

        def fmt(d):
            if not d or d.get("value") is None:
                return "-"
            return f"{d['value']:.4g}" + (f" &plusmn; {d['stderr']:.2g}" if d.get("stderr") is not None else "")

        rows.append(f"<tr><td>{e(k)}</td><td>{fmt(f)}</td><td>{fmt(t)}</td>"
                    f"<td>{'differs' if c.get('beyond') else ''}</td></tr>")
    preds = "".join(
        f"<tr><td>{e(p['name'])}</td><td>{p['real_rms_deg_e']}</td><td>{p['twin_rms_deg_e']}</td><td>{p['ratio']}</td>"
        f"<td>{'' if p['within_band'] else 'outside'}</td></tr>" for p in result["predictors"])
    diffs = "".join(f"<li>{e(d['what'])}: {e(d['effect'])}"
                    f"{' (closed by adding ' + e(d['added']) + ')' if d.get('explained_by_adding') else ''}</li>"
                    for d in result["differences"]) or "<li>none beyond the uncertainty</li>"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>twin check</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}
td,th{{padding:2px 8px;border-bottom:1px solid #ddd}}</style></head><body><h1>Twin check</h1>
<p>capture <code>{e(result['recording'])}</code>, twin <code>{e(result['twin'])}</code></p>
<p>{e(result['replay'])}</p>
<h2>Calibration, real and twin</h2>
<table><tr><th>figure</th><th>real</th><th>twin</th><th></th></tr>{''.join(rows)}</table>
<h2>Predictors (commutation-error RMS, deg e, second half)</h2>
<table><tr><th>predictor</th><th>real</th><th>twin</th><th>twin / real</th><th></th></tr>{preds}</table>
<h2>Differences</h2><ul>{diffs}</ul>
<h2>Figures</h2><img alt="sector widths and residual autocorrelation" src="data:image/png;base64,{_figure(result)}">
</body></html>
"""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(page)
