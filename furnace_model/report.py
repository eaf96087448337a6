"""The diagnosis as one self-contained HTML page for the people who must act on it: the
verdict in a sentence first, then the evidence behind it, each figure an inline SVG.

The page needs no network and no script: CSS inline, figures drawn by matplotlib on a
private canvas (the caller's backend is never touched) and embedded as SVG markup. All
numbers come from the `Diagnosis`; nothing is computed here but what a figure needs.
"""

from __future__ import annotations

import html
import io
import re
from pathlib import Path

import matplotlib
import matplotlib.dates as mdates
import numpy as np
import pandas as pd
from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.figure import Figure

from .diagnosis import MIN_GAP_CLOSED, RULE, CandidateResult, Diagnosis, shortfall, where_lines
from .diagnosis.verdict import NAMING
from .diagnosis.words import baseline_label, model_words, paper_like, temp_c
from .experiment import Experiment
from .identification.residuals import ZONE_WORDS

STATUS_WORDS = {"no_gap": "no gap", "explained": "explained",
                "explained_in_part": "explained in part", "unexplained": "unexplained"}
STATUS_COLOURS = {"no_gap": "#2e7d32", "explained": "#1565c0", "explained_in_part": "#ef6c00",
                  "unexplained": "#c62828"}
LONG_RECORD_MIN = 3 * 24 * 60.0
"""A record longer than this is plotted in days, not minutes, when it has no start time."""

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif;
       margin: 2em auto; max-width: 1100px; color: #222; line-height: 1.4; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
.verdict { border-left: 8px solid; padding: 0.8em 1em; background: #f6f6f6; font-size: 1.1em; }
.status { display: inline-block; color: white; padding: 0.1em 0.6em; border-radius: 0.3em;
          font-weight: bold; margin-right: 0.5em; }
.meta { color: #666; font-size: 0.9em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #eee; }
td.no { color: #999; }
td.bar { padding: 0.1em 0.4em; }
figure { margin: 0.8em 0; }
figure svg { max-width: 100%; height: auto; }
figcaption { color: #555; font-size: 0.9em; }
"""


def write_report(diagnosis: Diagnosis, path: str | Path) -> Path:
    """Write the report for `diagnosis` to `path` (one .html file) and return the path."""
    path = Path(path)
    page = render(diagnosis)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path


def render(d: Diagnosis) -> str:
    v = d.verdict
    furnace = d.fit_data[0].furnace
    best = d.best() if v.status in NAMING else None
    drawn = best if best is not None else _partial_candidate(d)
    colour = STATUS_COLOURS.get(v.status, "#555")
    model = model_words(furnace)
    base = baseline_label(furnace)
    pairs = ("the two thermocouples of a zone" if paper_like(furnace) else
             "the thermocouples of a zone against each other; a zone of one thermocouple "
             "borrows the record's pairs, or reads its own (a first-order fit's one-step "
             "error or its second differences, the lower)")
    if drawn is None:
        extension = ("no extension (none closes any of the gap)" if d.candidates
                     else "no extension (none was tried)")
    elif drawn is best and v.status == "explained":
        extension = f"the model with {_e(drawn.label)} (blue)"
    else:
        extension = (f"the model with {_e(drawn.label)} (blue), which closes "
                     f"{drawn.gap_closed_pct:.0f}% of the held-out gap above the noise floor, "
                     "not all of it")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        "<title>Model error diagnosis</title>",
        f"<style>{CSS}</style></head><body>",
        "<h1>Why the furnace model errs: diagnosis</h1>",
        f'<p class="verdict" style="border-color:{colour}">'
        f'<span class="status" style="background:{colour}">{_e(STATUS_WORDS.get(v.status, v.status))}'
        f"</span>{_e(v.sentence)}</p>",
        f'<p class="meta">Fitted: {_e(", ".join(e.name for e in d.fit_data))}; held out: '
        f"{_e(d.holdout_how)}. Diagnosed in {d.elapsed_s:.1f} s.</p>",
        _section("Error per zone, before and after", _rmse_table(d, best) + _floor_table(d)
                 + "".join(f"<p>{_e(line)}</p>" for line in d.offset_lines()),
                 _figure(_fig_noise(d, best), "noise",
                         "Held-out RMSE per zone against the noise floor the thermocouples "
                         f"allow: the {_e(base)}, the best extension, and the floor."),
                 "Fit: the data the model was fitted to. Held out: data it never saw, scored "
                 "with the model's parameters fixed. The noise floor is estimated from the "
                 f"data themselves, record by record ({pairs}); an "
                 "RMSE near it is as good as the sensors allow, and a zone has a gap when "
                 "its held-out RMSE passes the limit shown (1.25 floors, or more where the "
                 "record holds few independent samples, and beyond what the fitted "
                 "parameters' own uncertainty carries onto the held-out data)."),
        *([_section("What the kept effects explain, and what remains", _parts_tables(d),
                    _figure(_fig_parts(d), "parts",
                            "The baseline's held-out gap above the noise floor (100%), and the "
                            "share each kept effect closes, in the order they were added; the "
                            "grey rest is what none of the candidates closes."),
                    "Each step is one effect added to those before it; its share is of the "
                    "baseline's held-out squared error above the floor, so that the steps "
                    "add up to the whole closed.")]
          if v.status == "explained_in_part" else []),
        _section("Measured and modelled temperatures", "",
                 _figure(_fig_traces(d, drawn), "traces",
                         f"Zone temperature measured (grey), {_e(model)} (red) and "
                         + extension + "; fitted experiments first, held-out ones after."), ""),
        _section("Where the error lies", _where_table(d.where, _zones(d)),
                 _figure(_fig_residuals(d), "residuals",
                         f"The error of {_e(model)} over time per zone (measured minus model), "
                         "with the spans that hold most of it shaded (orange: the furnace; "
                         "purple: a thermocouple) and the noise floor as dashed lines; an error "
                         "that runs throughout a record is listed, not shaded."), ""),
        _section("Residual tests", _tests_table(d),
                 _figure(_fig_tests(d), "tests",
                         "Autocorrelation of the baseline's held-out residual per zone with its "
                         "99% band (a white residual stays inside): a model that leaves "
                         "structure behind shows outside the band."), ""),
        _section("Candidate effects", _candidate_table(d), "",
                 "Each candidate is fitted on the fit data (its parameters and the "
                 "baseline's together) and scored on the held-out data. dBIC < 0 means the "
                 "extension is worth its extra parameters on the fitted data. A candidate "
                 f"earns credit with its {RULE}. The bar is the share of the gap closed "
                 f"(from -{BAR_LEFT_PCT:.0f} to {BAR_RIGHT_PCT:.0f}%, dotted at the "
                 "threshold): filled when the candidate earns credit (blue: the verdict's), "
                 "outlined when it does not."),
        _section("Parameters", _param_table(d, best), "", ""),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def _partial_candidate(d: Diagnosis) -> CandidateResult | None:
    """With no effect named, the best-ranked candidate if it closes part of the held-out gap:
    drawn beside the baseline, it shows how far the nearest candidate gets."""
    c = d.candidates[0] if d.candidates else None
    if c is None or not np.isfinite(c.gap_closed_pct) or c.gap_closed_pct <= 0:
        return None
    return c


# --- text --------------------------------------------------------------------------------

def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _zones(d: Diagnosis) -> tuple[str, ...]:
    """The diagnosed furnace's zones, in order."""
    return d.fit_data[0].furnace.zones


def _section(title: str, body: str, figure: str, note: str) -> str:
    note_html = f"<p>{_e(note)}</p>" if note else ""
    return f"<section><h2>{_e(title)}</h2>{note_html}{body}{figure}</section>"


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}" if np.isfinite(x) else "-"


def _c(x: float) -> str:
    """A temperature in a table: two decimals, more below 0.1 °C (`temp_c`)."""
    return temp_c(x, 2)


def _g(x: float) -> str:
    return f"{x:.4g}" if np.isfinite(x) else "-"


def _rmse_table(d: Diagnosis, best: CandidateResult | None) -> str:
    zone_names = _zones(d)
    b = d.baseline
    head = ["zone", "noise floor fitted (°C)", "baseline fit", "noise floor held out (°C)",
            "baseline held out"]
    if best is not None:
        head += [f"{best.label} fit", f"{best.label} held out"]
    head += ["gap limit (°C)", "gap"]
    rows = []
    fit_floor, limit = d.noise_floor_fit_c or {}, d.gap_limit_c or {}
    for z in zone_names:
        cells = [ZONE_WORDS[z], _c(fit_floor.get(z, np.nan)), _c(b.rmse_fit_c[z]),
                 _c(d.noise_floor_c[z]), _c(b.rmse_holdout_c[z])]
        if best is not None:
            cells += [_c(best.rmse_fit_c[z]), _c(best.rmse_holdout_c[z])]
        cells += [_c(limit.get(z, np.nan)), "yes" if z in d.gap_zones else "no"]
        rows.append(cells)
    caption = "RMSE per zone (°C)"
    if best is not None:
        caption += (f"; held-out error {best.shrink_pct:.0f}% smaller with {best.label} "
                    f"({best.gap_closed_pct:.0f}% of the gap above the noise floor closed)")
    return _table(head, rows, caption)


def _floor_table(d: Diagnosis) -> str:
    """Each record's own floor per zone, and how it was estimated and how sure it is."""
    zone_names = _zones(d)
    if not d.record_floors:
        return ""
    rows = []
    for i, f in enumerate(d.record_floors):
        role = "fitted" if i < len(d.fit_data) else "held out"
        for z in zone_names:
            zf = f.zones[z]
            rows.append([f.record, role, ZONE_WORDS[z], _c(zf.floor_c), _c(zf.tc_sd_c),
                         zf.words()])
    return _table(["record", "role", "zone", "noise floor (°C)", "one thermocouple (°C)",
                   "estimated"], rows, "Noise floor per record and zone")


def _where_table(where, zones: tuple[str, ...], caption: str = "") -> str:
    if not where:
        return "<p>No span holds a notable share of the error.</p>"
    rows = [[w.who, w.experiment,
             (f"throughout ({w.span})" if w.kind == "throughout" else w.span)
             + (f" ({w.clock})" if w.clock else ""), w.share, w.regime]
            for w in where_lines(where, zones)]
    return _table(["where", "experiment", "when", "share of the zone's squared error",
                   "operating regime"], rows, caption)


def _parts_tables(d: Diagnosis) -> str:
    """A partial explanation: each kept effect's step, what remains per zone against the
    floor, and where the remaining error lies."""
    v, zones = d.verdict, _zones(d)
    rows = [[p.effect, _f(p.gap_closed_pct, 0), _f(p.shrink_pct, 0),
             " / ".join(_c(p.rmse_holdout_c[z]) for z in zones)] for p in v.parts]
    rows.append(["together", _f(v.gap_closed_pct, 0), _f(v.shrink_pct, 0), ""])
    out = _table(["effect, in the order added", "gap closed %", "shrink %",
                  f"held out after, {' / '.join(zones)} (°C)"], rows,
                 "The kept effects, step by step: each one's share of the baseline's held-out "
                 "gap above the noise floor")
    rest = v.remaining
    if rest is None:
        return out
    out += _table(["zone", "held out with the kept effects (°C)", "noise floor held out (°C)"],
                  [[ZONE_WORDS[z], _c(rest.rmse_holdout_c[z]), _c(rest.noise_floor_c[z])]
                   for z in zones], "What remains")
    return out + _where_table(
        rest.where, zones,
        "Where what remains lies, on the kept model's held-out residual"
        if rest.where_from == "kept" else
        "Where what remains lies: not found on the kept model's residual; the baseline's "
        "error, as located below")


def _tests_table(d: Diagnosis) -> str:
    zone_names = _zones(d)
    rows = []
    for z in zone_names:
        t = d.residual_tests.get(z)
        if not t:
            continue
        worst = max(t.get("xcorr", {}).items(), key=lambda kv: kv[1]["max_abs"] / kv[1]["bound"],
                    default=None)
        if worst is None:
            rows.append([ZONE_WORDS[z], "yes" if t["white"] else "no", "-", "-"])
            continue
        name, x = worst
        rows.append([ZONE_WORDS[z], "yes" if t["white"] else "no",
                     f"{name} (lag {x['at_lag']} min: {x['max_abs']:.2f}, band {x['bound']:.2f})",
                     "yes" if x["independent"] else "no"])
    if not rows:
        return ""
    return _table(["zone", "residual white", "input it correlates with most",
                   "independent of the inputs"], rows,
                  "The baseline's held-out residual, tested as MATLAB's resid does.")


def _candidate_table(d: Diagnosis) -> str:
    """The candidates, best first, each with its credit and the bar that draws it: the
    credit is `credit.shortfall`'s, the rule the verdict keeps effects by."""
    zone_names = _zones(d)
    if not d.candidates:
        return "<p>No candidate was tried: there is no gap to explain.</p>"
    kept = set(d.verdict.effects) if d.verdict.status in NAMING else set()
    head = ["effect(s)", "gap closed", f"held-out RMSE {' / '.join(zone_names)} (°C)", "shrink %",
            "gap closed %", "dBIC", "credit", "note"]
    rows = []
    for c in d.candidates:
        short = shortfall(c)
        ho = " / ".join(_f(c.rmse_holdout_c[z]) for z in zone_names)
        cells = [_e(c.label), _bar(c, not short, set(c.effects) == kept), _e(ho),
                 _e(_f(c.shrink_pct, 0)), _e(_f(c.gap_closed_pct, 0)), _e(_f(c.delta_bic, 0)),
                 _e("no: " + "; ".join(short) if short else "yes"), _e(c.note)]
        classes = ["", ' class="bar"', "", "", "", "", ' class="credit"', ""]
        rows.append("<tr>" + "".join(f"<td{k}>{x}</td>" for k, x in zip(classes, cells,
                                                                         strict=True)) + "</tr>")
    th = "".join(f"<th>{_e(h)}</th>" for h in head)
    return (f"<table><caption>Best first</caption><thead><tr>{th}</tr></thead>"
            f"<tbody>{''.join(rows)}</tbody></table>")


BAR_LEFT_PCT, BAR_RIGHT_PCT = 50.0, 100.0
"""The bar's scale in percent of the gap closed; a candidate beyond it is drawn to the edge
(its number stands beside it)."""
BAR_PX = 1.2
"""Pixels per percent of the gap closed."""


def _bar(c: CandidateResult, credited: bool, chosen: bool) -> str:
    """The share of the gap a candidate closes as a small inline SVG: filled only when it
    earns credit, so that the picture cannot say more than the rule."""
    width, height = (BAR_LEFT_PCT + BAR_RIGHT_PCT) * BAR_PX, 14
    zero = BAR_LEFT_PCT * BAR_PX
    v = c.gap_closed_pct
    parts = [f'<svg width="{width:.0f}" height="{height}" viewBox="0 0 {width:.0f} {height}" '
             'role="img">']
    if np.isfinite(v):
        x = zero + float(np.clip(v, -BAR_LEFT_PCT, BAR_RIGHT_PCT)) * BAR_PX
        colour = STATUS_COLOURS["explained"] if chosen else STATUS_COLOURS["no_gap"]
        style = (f'fill="{colour}" stroke="{colour}"' if credited else
                 'fill="none" stroke="#888" stroke-dasharray="3,2"')
        parts += [f"<title>{_e(f'{v:.0f}% of the gap closed')}</title>",
                  f'<rect class="{"credited" if credited else "uncredited"}" '
                  f'x="{min(zero, x):.1f}" y="2" width="{abs(x - zero):.1f}" '
                  f'height="{height - 4}" {style}/>']
    else:
        parts.append("<title>fit failed</title>")
    threshold = zero + MIN_GAP_CLOSED * BAR_PX
    parts += [f'<line x1="{zero:.1f}" x2="{zero:.1f}" y1="0" y2="{height}" stroke="#444"/>',
              f'<line x1="{threshold:.1f}" x2="{threshold:.1f}" y1="0" y2="{height}" '
              'stroke="#444" stroke-dasharray="1,2"/>', "</svg>"]
    return "".join(parts)


def _param_table(d: Diagnosis, best: CandidateResult | None) -> str:
    models = [(baseline_label(d.fit_data[0].furnace), d.baseline)]
    if best is not None:
        models.append((f"with {best.label}", best))
    out = []
    for title, c in models:
        rows = []
        for name, value in c.params.items():
            lo, hi = c.ci95.get(name, (np.nan, np.nan))
            rows.append([name, _g(value), f"[{_g(lo)}, {_g(hi)}]"])
        out.append(_table(["parameter", "value", "95% interval"], rows, title))
    return "".join(out)


def _table(head: list[str], rows: list[list[str]], caption: str = "") -> str:
    cap = f"<caption>{_e(caption)}</caption>" if caption else ""
    th = "".join(f"<th>{_e(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{cap}<thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


# --- figures -----------------------------------------------------------------------------

def _figure(fig: Figure | None, name: str, caption: str) -> str:
    if fig is None:
        return ""
    return f"<figure>{_svg(fig, name)}<figcaption>{caption}</figcaption></figure>"


def _svg(fig: Figure, name: str) -> str:
    """The figure as inline SVG markup: no XML prologue, DOCTYPE or metadata (they would
    name external documents), ids salted by the figure's name so that several figures can
    share one page."""
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": f"report-{name}", "svg.fonttype": "none"}):
        FigureCanvasSVG(fig)
        fig.savefig(buf, format="svg", metadata={"Date": None})
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    text = re.sub(r"<metadata>.*?</metadata>", "", text, flags=re.S)
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text)
    return text


def _new(rows: int, cols: int, width: float, height: float,
         sharex: str | bool = False) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=(width, height), dpi=72)
    axes = np.atleast_2d(fig.subplots(rows, cols, squeeze=False, sharex=sharex))
    return fig, axes


def _records(d: Diagnosis) -> list[tuple[Experiment, str, int]]:
    """(experiment, 'fit'|'held out', index into that list's predictions)."""
    return ([(e, "fit", j) for j, e in enumerate(d.fit_data)]
            + [(e, "held out", j) for j, e in enumerate(d.holdout)])


def _pred(c: CandidateResult | None, kind: str, j: int) -> np.ndarray | None:
    if c is None:
        return None
    preds = c.fit_pred if kind == "fit" else c.holdout_pred
    return preds[j] if j < len(preds) else None


def _time(exp: Experiment, t_min) -> np.ndarray:
    """Where minutes of a record lie on its plots' time axis: dates (UTC) for a record with
    a start time, days for a long one without, else the minutes themselves. A plant's record
    is read against its calendar; 40,000 minutes say nothing to the crew that ran them."""
    t = np.atleast_1d(np.asarray(t_min, dtype=float))
    if exp.start_time is not None:
        start = pd.Timestamp(exp.start_time)
        start = start.tz_convert("UTC").tz_localize(None) if start.tzinfo else start
        return (start + pd.to_timedelta(t, unit="min")).to_numpy()
    if _span_min(exp) > LONG_RECORD_MIN:
        return t / 1440.0
    return t


def _span_min(exp: Experiment) -> float:
    return float(exp.t_min[-1] - exp.t_min[0]) if len(exp) else 0.0


def _time_label(exp: Experiment) -> str:
    if exp.start_time is not None:
        return "time (UTC)"
    return "time (days)" if _span_min(exp) > LONG_RECORD_MIN else "time (min)"


def _date_axis(ax, exp: Experiment) -> None:
    """Concise date ticks on a record with a start time (the year and month said once)."""
    if exp.start_time is not None:
        locator = mdates.AutoDateLocator(minticks=2, maxticks=5)
        ax.xaxis.set_major_locator(locator)
        ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))


def _fig_traces(d: Diagnosis, best: CandidateResult | None) -> Figure:
    zone_names = _zones(d)
    recs = _records(d)
    base_name = baseline_label(d.fit_data[0].furnace)
    fig, axes = _new(len(zone_names), len(recs), 4.2 * len(recs) + 0.8, 8.0 * len(zone_names) / 3,
                     sharex="col")
    for k, (exp, kind, j) in enumerate(recs):
        base, ext = _pred(d.baseline, kind, j), _pred(best, kind, j)
        x = _time(exp, exp.t_min)
        for w, z in enumerate(zone_names):
            ax = axes[w, k]
            ax.plot(x, exp.zone_temp[:, w], "-", lw=2.2, color="0.7", label="measured")
            if base is not None:
                ax.plot(x, base[:, w], "-", lw=1.0, color="C3", label=base_name)
            if ext is not None:
                ax.plot(x, ext[:, w], "--", lw=1.0, color="C0", label=f"with {best.label}")
            _frame(ax, w, k, f"{exp.name} ({kind})", f"{ZONE_WORDS[z]} (°C)", len(zone_names),
                   exp)
    axes[0, 0].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return fig


def _frame(ax, row: int, col: int, title: str, ylabel: str, rows: int = 3,
           exp: Experiment | None = None) -> None:
    """Grid, and the labels only on the panel edges of a zones-by-records grid; the time
    axis as the record's (`_time`)."""
    ax.grid(alpha=0.3)
    if exp is not None:
        _date_axis(ax, exp)
    if row == 0:
        ax.set_title(title, fontsize=10)
    if col == 0:
        ax.set_ylabel(ylabel)
    if row == rows - 1:
        ax.set_xlabel("time (min)" if exp is None else _time_label(exp))


def _fig_residuals(d: Diagnosis) -> Figure:
    zone_names = _zones(d)
    recs = _records(d)
    fig, axes = _new(len(zone_names), len(recs), 4.2 * len(recs) + 0.8, 6.5 * len(zone_names) / 3,
                     sharex="col")
    for k, (exp, kind, j) in enumerate(recs):
        base = _pred(d.baseline, kind, j)
        x = _time(exp, exp.t_min)
        for w, z in enumerate(zone_names):
            ax = axes[w, k]
            if base is not None:
                ax.plot(x, exp.zone_temp[:, w] - base[:, w], "-", lw=0.6, color="C3")
            floors = d.record_floors or []
            at = k if k < len(floors) else None  # records in the same order: fit, held out
            fl = floors[at].zones[z].floor_c if at is not None else d.noise_floor_c.get(z, np.nan)
            if np.isfinite(fl):
                for s in (-1, 1):
                    ax.axhline(s * fl, color="k", lw=0.7, ls="--")
            for loc in d.where:
                if loc.experiment == exp.name and loc.zone == z and loc.kind != "throughout":
                    lo, hi = _time(exp, [loc.start_min, max(loc.end_min, loc.start_min + 1)])
                    ax.axvspan(lo, hi, color="C4" if loc.sensor else "C1", alpha=0.3, lw=0)
            ax.axhline(0.0, color="0.3", lw=0.6)
            _frame(ax, w, k, f"{exp.name} ({kind})", f"{ZONE_WORDS[z]} error (°C)",
                   len(zone_names), exp)
    fig.tight_layout()
    return fig


def _fig_parts(d: Diagnosis) -> Figure | None:
    """The baseline's held-out gap above the floor as one bar of 100%: each kept effect's
    share in the order added, then the rest none closes."""
    v = d.verdict
    if not v.parts:
        return None
    fig, axes = _new(1, 1, 6.5, 2.2)
    ax = axes[0, 0]
    left = 0.0
    for i, p in enumerate(v.parts):
        width = float(np.clip(p.gap_closed_pct, 0.0, 100.0 - left)) if np.isfinite(
            p.gap_closed_pct) else 0.0
        ax.barh(0, width, left=left, color=f"C{i}", label=f"{p.effect} ({p.gap_closed_pct:.0f}%)")
        left += width
    ax.barh(0, max(100.0 - left, 0.0), left=left, color="0.8",
            label=f"remains ({max(100.0 - left, 0.0):.0f}%)")
    ax.set_xlim(0, 100)
    ax.set_yticks([])
    ax.set_xlabel("share of the held-out gap above the noise floor (%)")
    ax.legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.02), ncol=len(v.parts) + 1,
              frameon=False)
    fig.tight_layout()
    return fig


def _fig_tests(d: Diagnosis) -> Figure | None:
    zone_names = _zones(d)
    zones = [z for z in zone_names if d.residual_tests.get(z)]
    if not zones:
        return None
    fig, axes = _new(1, len(zones), 3.6 * len(zones) + 0.6, 2.8)
    for k, z in enumerate(zones):
        t = d.residual_tests[z]
        ax = axes[0, k]
        lags, acf, bound = np.asarray(t["lags"]), np.asarray(t["autocorr"]), t["autocorr_bound"]
        ax.vlines(lags, 0, acf, color="C0", lw=1.5)
        ax.axhspan(-bound, bound, color="C2", alpha=0.2, lw=0)
        ax.axhline(0, color="0.3", lw=0.6)
        ax.set_title(f"{ZONE_WORDS[z]}: " + ("white" if t["white"] else "not white"),
                     fontsize=10)
        ax.set_xlabel("lag (samples)")
        if k == 0:
            ax.set_ylabel("autocorrelation")
    fig.tight_layout()
    return fig


def _fig_noise(d: Diagnosis, best: CandidateResult | None) -> Figure:
    zone_names = _zones(d)
    fig, axes = _new(1, 1, 6.5, 2.8)
    ax = axes[0, 0]
    x = np.arange(len(zone_names))
    series = [(baseline_label(d.fit_data[0].furnace), d.baseline.rmse_holdout_c, "C3")]
    if best is not None:
        series.append((f"with {best.label}", best.rmse_holdout_c, "C0"))
    series.append(("noise floor", d.noise_floor_c, "0.6"))
    width = 0.8 / len(series)
    for k, (label, vals, colour) in enumerate(series):
        ax.bar(x + (k - (len(series) - 1) / 2) * width,
               [vals.get(z, np.nan) for z in zone_names], width, label=label, color=colour)
    ax.set_xticks(x)
    ax.set_xticklabels([ZONE_WORDS[z] for z in zone_names])
    ax.set_ylabel("held-out RMSE (°C)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return fig
