"""The HTML report of a diagnosis: one file that opens with no network, the verdict first,
one figure per section, nothing that reaches outside the page."""

from __future__ import annotations

import dataclasses
import html
from html.parser import HTMLParser

import numpy as np
import pytest

from furnace_model.cli.diagnose import summary
from furnace_model.diagnosis import (
    CandidateResult,
    credited,
    diagnose,
    rmse_per_zone,
    score_against,
)
from furnace_model.diagnosis.cases import draw_case
from furnace_model.report import write_report
from furnace_model.simulation.furnace import PAPER


class _Page(HTMLParser):
    """Sections, the SVGs inside each, every attribute that can load something, and text."""

    def __init__(self):
        super().__init__()
        self.sections: list[dict] = []
        self.links: list[tuple[str, str, str]] = []
        self.tags: list[str] = []
        self.text: list[str] = []
        self.depth = 0

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "section":
            self.sections.append({"svg": 0, "title": ""})
        if tag == "svg" and self.sections:
            self.sections[-1]["svg"] += 1
        for name, value in attrs:
            if name in ("src", "href", "xlink:href", "data", "action", "srcset") and value:
                self.links.append((tag, name, value))

    def handle_data(self, data):
        self.text.append(data)
        if self.sections and self.tags and self.tags[-1] == "h2" and not self.sections[-1]["title"]:
            self.sections[-1]["title"] = data


def _parse(path) -> tuple[_Page, str]:
    raw = path.read_text(encoding="utf-8")
    page = _Page()
    page.feed(raw)
    page.close()
    return page, raw


def _check_self_contained(page: _Page, raw: str) -> None:
    assert "http://" not in raw and "https://" not in raw
    assert "script" not in page.tags and "link" not in page.tags and "img" not in page.tags
    assert all(value.startswith("#") for _tag, _name, value in page.links), page.links
    assert raw.lstrip().startswith("<!DOCTYPE html>")


@pytest.fixture(scope="module")
def explained(tmp_path_factory):
    case = draw_case("zone_burners", np.random.default_rng(12), furnace=PAPER)
    d = diagnose(case.fit, case.holdout, effects=("zone_burners", "sensor_lag"))
    assert d.verdict.status == "explained"
    path = write_report(d, tmp_path_factory.mktemp("report") / "deep" / "er" / "report.html")
    return d, path


def test_report_is_one_self_contained_page_with_the_verdict_first(explained):
    d, path = explained
    page, raw = _parse(path)
    _check_self_contained(page, raw)
    text = " ".join(page.text)
    assert d.verdict.sentence in html.unescape(raw)
    assert text.index("heating- and preheating-zone burners") < text.index("Candidate effects")
    # every section holds exactly one figure, except the parameter tables and the
    # candidates, which draw one bar per candidate
    titles = [s["title"] for s in page.sections]
    assert titles[0] == "Error per zone, before and after" and titles[-1] == "Parameters"
    for s in page.sections:
        want = {"Parameters": 0, "Candidate effects": len(d.candidates)}.get(s["title"], 1)
        assert s["svg"] == want, s
    # the numbers a plant engineer reads: per zone RMSE, the shrink, the parameter intervals
    for z in ("soaking", "heating", "preheating"):
        assert z in text
    assert f"{d.baseline.rmse_holdout_c['soak']:.2f}" in text
    best = d.best()
    assert f"{best.shrink_pct:.0f}" in text
    lo, hi = best.ci95["f_heat"]
    assert f"[{lo:.4g}, {hi:.4g}]" in text


def test_report_of_a_control_says_no_gap_and_draws_what_there_is(tmp_path):
    case = draw_case(None, np.random.default_rng(11), furnace=PAPER)
    d = diagnose(case.fit, case.holdout, effects=("zone_burners",))
    assert d.verdict.status == "no_gap"
    page, raw = _parse(write_report(d, tmp_path / "control.html"))
    _check_self_contained(page, raw)
    assert d.verdict.sentence in html.unescape(raw)
    assert "No candidate was tried" in raw
    by_title = {s["title"]: s["svg"] for s in page.sections}
    assert by_title["Candidate effects"] == 0  # no candidate, no bar
    assert by_title["Measured and modelled temperatures"] == 1
    assert by_title["Where the error lies"] == 1


class _CandidateRows(HTMLParser):
    """Each row of the candidates' table: its cells' text by column, and the bar's rect."""

    def __init__(self):
        super().__init__()
        self.head: list[str] = []
        self.rows: list[dict] = []
        self.in_table = self.in_cell = False
        self.cell: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "h2":
            self.in_table = False
        if tag == "table" and self.in_title == "Candidate effects":
            self.in_table = True
        if not self.in_table:
            return
        if tag == "tr":
            self.rows.append({"cells": [], "rect": None})
        if tag in ("td", "th"):
            self.in_cell, self.cell = True, []
        if tag == "rect":
            self.rows[-1]["rect"] = a

    def handle_endtag(self, tag):
        if self.in_table and tag in ("td", "th"):
            text = " ".join("".join(self.cell).split())
            if tag == "th":
                self.head.append(text)
            else:
                self.rows[-1]["cells"].append(text)
            self.in_cell = False
        if tag == "table":
            self.in_table = False

    in_title = ""

    def handle_data(self, data):
        if self.lasttag == "h2":
            self.in_title = data
        if self.in_cell and self.lasttag != "title":
            self.cell.append(data)


def _worse(d, factor: float) -> CandidateResult:
    """A candidate that fits the fitted data better than the baseline (smaller squared
    error, so a lower BIC) with its strength determined, but whose held-out error is
    `factor` times the baseline's in every zone: the residual scaled, sample by sample."""
    b = d.baseline
    hold = [e.zone_temp - factor * (e.zone_temp - p) for e, p in
            zip(d.holdout, b.holdout_pred, strict=True)]
    c = CandidateResult(("dead_time",), {**b.params, "theta_dead": 3.0},
                        {**b.ci95, "theta_dead": (2.0, 4.0)}, dict(b.rmse_fit_c),
                        rmse_per_zone(d.holdout, hold), identifiable=True, fit_pred=b.fit_pred,
                        holdout_pred=hold, sse_fit=0.8 * b.sse_fit, n_obs=b.n_obs,
                        n_params=b.n_params + 1, rho1=b.rho1, rho1_holdout=b.rho1_holdout,
                        n_holdout=b.n_holdout)
    score_against(c, b, d.noise_floor_c)
    return c


def test_a_candidate_that_worsens_the_held_out_error_is_drawn_uncredited(explained, tmp_path):
    """The report shows the credit the verdict's rule gives, read back from the HTML: a
    candidate with a lower BIC and a determined strength that makes the held-out error 35%
    worse says no, with why, and its bar is an outline; every credited row is the rule's,
    with a filled bar, and the text summary and the JSON say the same."""
    d0, _ = explained
    bad = _worse(d0, 1.35)
    assert bad.identifiable and bad.delta_bic < 0 and bad.gap_closed_pct < 0
    assert bad.shrink_pct == pytest.approx(-35.0, abs=0.5)
    d = dataclasses.replace(d0, candidates=[*d0.candidates, bad])
    page = _CandidateRows()
    page.feed((write_report(d, tmp_path / "r.html")).read_text(encoding="utf-8"))
    col = {h: i for i, h in enumerate(page.head)}
    rows = {r["cells"][col["effect(s)"]]: r for r in page.rows if r["cells"]}
    assert set(rows) == {c.label for c in d.candidates}
    worse = rows["dead_time"]
    assert worse["cells"][col["credit"]].startswith("no:")
    assert "worse (35% larger)" in worse["cells"][col["credit"]]
    assert worse["rect"]["fill"] == "none"
    for c in d.candidates:
        cells, rect = rows[c.label]["cells"], rows[c.label]["rect"]
        assert (cells[col["credit"]] == "yes") == credited(c), (c.label, cells)
        assert (rect["fill"] != "none") == credited(c), (c.label, rect)
    chosen = rows["+".join(d.verdict.effects)]
    assert chosen["cells"][col["credit"]] == "yes" and chosen["rect"]["fill"] != "none"
    text = {line.split("|")[1].strip(): line for line in summary(d).splitlines()
            if line.startswith("| ") and line.count("|") == 8}
    for c in d.candidates:
        assert text[c.label].rstrip(" |").endswith(rows[c.label]["cells"][col["credit"]]), \
            text[c.label]
    assert [c["credit"] for c in d.to_json()["candidates"]] == [credited(c)
                                                              for c in d.candidates]
    assert all(np.isfinite(bad.rmse_holdout_c[z]) for z in PAPER.zones)
