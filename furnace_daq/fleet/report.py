"""The fleet report: one self-contained HTML page (no network, no script) from the tables a
fleet job wrote in its output directory, for whoever looks after the furnaces.

First a row per furnace: its latest identified parameters, its drift events, its verdicts
with their effects; then per furnace a figure of every parameter the data determine over
time (95% interval shaded, drift events and segment cuts marked) and the detail. Figures are
matplotlib PNGs embedded as base64, drawn on a private canvas (the caller's backend is never
touched). Whatever table is missing (a refit not run yet) is said so, not guessed.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np
import pandas as pd

from .tables import DIAGNOSE_FAILURES, DRIFT_EVENTS, REFIT, REFIT_FAILURES, REPORT, VERDICTS

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif;
       margin: 2em auto; max-width: 1200px; color: #222; line-height: 1.4; padding: 0 1em; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; vertical-align: top; }
th:first-child, td:first-child, td.text { text-align: left; }
th { background: #eee; }
.no_gap { color: #2e7d32; } .explained { color: #1565c0; } .explained_in_part { color: #ef6c00; }
.unexplained { color: #c62828; }
.failed { color: #c62828; font-weight: bold; }
.meta { color: #666; font-size: 0.9em; }
img { max-width: 100%; }
"""


def _e(x: object) -> str:
    return html.escape(str(x))


def _read(path: Path) -> pd.DataFrame | None:
    try:
        return pd.read_parquet(path)
    except (OSError, ValueError):
        return None


def write_report(out_dir: Path) -> Path:
    """Write fleet_report.html from the tables in `out_dir`; returns its path."""
    out_dir = Path(out_dir)
    refit = _read(out_dir / REFIT)
    events = _read(out_dir / DRIFT_EVENTS)
    verdicts = _read(out_dir / VERDICTS)
    failures = [f for f in (_read(out_dir / REFIT_FAILURES),
                            _read(out_dir / DIAGNOSE_FAILURES))
                if f is not None and not f.empty]
    path = out_dir / REPORT
    path.write_text(render(refit, events, verdicts,
                           pd.concat(failures) if failures else None), encoding="utf-8")
    return path


def render(refit: pd.DataFrame | None, events: pd.DataFrame | None,
           verdicts: pd.DataFrame | None, failures: pd.DataFrame | None) -> str:
    furnaces = sorted({*(_names(refit)), *(_names(verdicts)), *(_names(failures))})
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             "<title>Furnace fleet report</title>", f"<style>{CSS}</style></head><body>",
             "<h1>Furnace fleet report</h1>",
             f'<p class="meta">Made {_e(pd.Timestamp.now("UTC").strftime("%Y-%m-%d %H:%M"))} '
             f"UTC from the tables beside this file: "
             f"{'refit' if refit is not None else 'no refit yet'}, "
             f"{'diagnoses' if verdicts is not None else 'no diagnosis yet'}.</p>"]
    if failures is not None:
        parts += ["<h2>Failed tasks</h2>", '<table><tr><th>furnace</th><th>job</th>'
                  "<th>task</th><th>reason</th></tr>"]
        parts += [f'<tr><td>{_e(r.furnace)}</td><td class="text">{_e(r.job)}</td>'
                  f'<td class="text">{_e(r.task)}</td><td class="text failed">{_e(r.reason)}'
                  "</td></tr>" for r in failures.itertuples()]
        parts.append("</table>")
    parts += ["<h2>Fleet</h2>", _summary(furnaces, refit, events, verdicts)]
    for name in furnaces:
        parts.append(_furnace(name, _of(refit, name), _of(events, name), _of(verdicts, name)))
    parts.append("</body></html>")
    return "\n".join(parts)


def _names(frame: pd.DataFrame | None) -> list[str]:
    return [] if frame is None or frame.empty else list(frame["furnace"].astype(str).unique())


def _of(frame: pd.DataFrame | None, name: str) -> pd.DataFrame | None:
    if frame is None or frame.empty:
        return None
    sub = frame[frame["furnace"] == name]
    return sub if not sub.empty else None


def _latest(refit: pd.DataFrame | None) -> pd.Series | None:
    if refit is None:
        return None
    fitted = refit[refit["fitted"]]
    return None if fitted.empty else fitted.iloc[-1]


def _verdict_words(v: pd.DataFrame | None) -> str:
    if v is None:
        return '<span class="meta">none</span>'
    items = []
    for r in v.itertuples():
        effects = f" ({_e(r.effects)})" if r.effects else ""
        shrink = (f", held-out RMSE -{r.shrink_pct:.0f}%"
                  if r.status in ("explained", "explained_in_part") else "")
        items.append(f'{_e(r.fit_campaign)} &rarr; {_e(r.holdout_campaign)}: '
                     f'<span class="{_e(r.status)}">{_e(r.status.replace("_", " "))}</span>'
                     f'{effects}{shrink}')
    return "<br>".join(items)


def _event_words(ev: pd.DataFrame | None) -> str:
    if ev is None:
        return '<span class="meta">none</span>'
    return "<br>".join(f"{_e(r.window_end.strftime('%Y-%m-%d %H:%M'))}: {_e(r.parameter)} "
                       f"{100 * r.relative_change:+.1f}%" for r in ev.itertuples())


def _summary(furnaces: list[str], refit, events, verdicts) -> str:
    """A row per furnace; furnaces of one kind (the same parameters) share a table, so that a
    fleet of paper furnaces and six-zone ones reads as two tables, not one with holes."""
    kinds: dict[tuple[str, ...], list[str]] = {}
    for name in furnaces:
        kinds.setdefault(tuple(parameters(_of(refit, name))), []).append(name)
    return "\n".join(_summary_table(names, params, refit, events, verdicts)
                     for params, names in kinds.items())


def _summary_table(furnaces: list[str], params: tuple[str, ...], refit, events,
                   verdicts) -> str:
    head = "".join(f"<th>{p}</th>" for p in params)
    rows = ['<table><tr><th>furnace</th><th>windows fitted</th><th>latest window</th>'
            f"{head}<th>drift events</th><th>verdicts</th></tr>"]
    for name in furnaces:
        r = _of(refit, name)
        last = _latest(r)
        n = "-" if r is None else f"{int(r['fitted'].sum())} of {len(r)}"
        when = "-" if last is None else last["window_end"].strftime("%Y-%m-%d %H:%M")
        values = "".join(f"<td>{'-' if last is None else f'{last[p]:.4g}'}</td>"
                         for p in params)
        rows.append(f'<tr><td><a href="#f-{_e(name)}">{_e(name)}</a></td><td>{n}</td>'
                    f"<td>{when}</td>{values}<td class=\"text\">{_event_words(_of(events, name))}"
                    f'</td><td class="text">{_verdict_words(_of(verdicts, name))}</td></tr>')
    rows.append("</table>")
    return "\n".join(rows)


def parameters(refit: pd.DataFrame | None) -> list[str]:
    """One furnace's parameters, in its network's order, read off its refit rows (a fleet's
    table holds every furnace kind's columns; a furnace's own are those it filled)."""
    if refit is None:
        return []
    return [c[:-len("_ci95_lo")] for c in refit.columns if c.endswith("_ci95_lo")
            and refit[[c[:-len("_ci95_lo")], c]].notna().any(axis=None)]


def zones(refit: pd.DataFrame) -> list[str]:
    """One furnace's zones, from its refit rows' RMSE columns."""
    return [c[len("rmse_"):-len("_c")] for c in refit.columns
            if c.startswith("rmse_") and c.endswith("_c") and refit[c].notna().any()]


def determined(refit: pd.DataFrame) -> list[str]:
    """Parameters the data determine (95% interval within +-5%) in most fitted windows: the
    ones worth a line over time (the others wander along a valley of equal fit)."""
    fitted = refit[refit["fitted"]]
    if fitted.empty:
        return []
    out = []
    for p in parameters(refit):
        undetermined = fitted["undetermined"].fillna("").str.split(",").map(lambda s, p=p: p in s)
        if undetermined.mean() < 0.5:
            out.append(p)
    return out


def _furnace(name: str, refit, events, verdicts) -> str:
    parts = [f'<h2 id="f-{_e(name)}">{_e(name)}</h2>']
    if refit is not None:
        params = determined(refit)
        if params:
            parts.append(_figure(_plot(name, refit, events, params),
                                 f"{name}: the parameters the data determine, per refit window "
                                 "(95% interval shaded); red: drift events; grey dashed: "
                                 "segment cuts (each segment started cold)."))
        else:
            parts.append('<p class="meta">No parameter is determined in most windows.</p>')
        bad = refit[~refit["fitted"]]
        if not bad.empty:
            parts.append(f'<p class="meta">{len(bad)} window(s) kept the model in force: '
                         + "; ".join(f"{_e(s)} {n}" for s, n in
                                     bad["status"].value_counts().items()) + "</p>")
        last = _latest(refit)
        if last is not None:
            rmse = ", ".join(f"{z} {last[f'rmse_{z}_c']:.2f}" for z in zones(refit))
            parts.append(f'<p class="meta">Latest window RMSE per zone: {rmse} °C.</p>')
    if events is not None:
        parts.append("<h3>Drift events</h3><ul>" + "".join(
            f"<li>{_e(r.detail)}</li>" for r in events.itertuples()) + "</ul>")
    if verdicts is not None:
        parts.append("<h3>Diagnoses</h3><table><tr><th>fitted</th><th>held out</th>"
                     "<th>verdict</th><th>effects</th><th>shrink %</th><th>why</th></tr>")
        for r in verdicts.itertuples():
            parts.append(f"<tr><td>{_e(r.fit_campaign)}</td><td class=\"text\">"
                         f"{_e(r.holdout_campaign)}</td><td class=\"text {_e(r.status)}\">"
                         f"{_e(r.status)}</td><td class=\"text\">{_e(r.effects)}</td>"
                         f"<td>{r.shrink_pct:.0f}</td><td class=\"text\">{_e(r.sentence)}"
                         "</td></tr>")
        parts.append("</table>")
    return "\n".join(parts)


def _plot(name: str, refit: pd.DataFrame, events, params: list[str]):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 1.8 * len(params) + 0.6), dpi=80)
    axes = np.atleast_1d(fig.subplots(len(params), 1, sharex=True, squeeze=False)[:, 0])
    fitted = refit[refit["fitted"]]
    t = fitted["window_end"].dt.tz_localize(None)
    cuts = refit.groupby("segment")["window_start"].min().iloc[1:]
    for ax, p in zip(axes, params, strict=True):
        ax.fill_between(t, fitted[f"{p}_ci95_lo"], fitted[f"{p}_ci95_hi"], alpha=0.25,
                        color="#1565c0", linewidth=0, step=None)
        ax.plot(t, fitted[p], ".-", color="#1565c0", markersize=3, linewidth=0.8)
        ax.set_ylabel(p)
        for c in cuts:
            ax.axvline(pd.Timestamp(c).tz_localize(None), color="#888", linestyle="--",
                       linewidth=0.8)
        if events is not None:
            for r in events.itertuples():
                ax.axvline(r.window_end.tz_localize(None), color="#c62828", linewidth=1.0)
    axes[0].set_title(f"{name}: identified parameters per refit window", fontsize=10)
    fig.autofmt_xdate()
    fig.tight_layout()
    return fig


def _figure(fig, caption: str) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return (f'<figure><img alt="{_e(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption class=\"meta\">{_e(caption)}</figcaption></figure>")
