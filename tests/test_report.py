"""The HTML report of a diagnosis: one file that opens with no network, the verdict first,
one figure per section, nothing that reaches outside the page."""

from __future__ import annotations

import html
from html.parser import HTMLParser

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.report import write_report
from furnace_model.selfcheck import draw_case


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
    case = draw_case("zone_burners", np.random.default_rng(12))
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
    # every section holds exactly one figure, except the parameter tables
    titles = [s["title"] for s in page.sections]
    assert titles[0] == "Error per zone, before and after" and titles[-1] == "Parameters"
    for s in page.sections:
        assert s["svg"] == (0 if s["title"] == "Parameters" else 1), s
    # the numbers a plant engineer reads: per zone RMSE, the shrink, the parameter intervals
    for z in ("soaking", "heating", "preheating"):
        assert z in text
    assert f"{d.baseline.rmse_holdout_c['soak']:.2f}" in text
    best = d.best()
    assert f"{best.shrink_pct:.0f}" in text
    lo, hi = best.ci95["f_heat"]
    assert f"[{lo:.4g}, {hi:.4g}]" in text


def test_report_of_a_control_says_no_gap_and_draws_what_there_is(tmp_path):
    case = draw_case(None, np.random.default_rng(11))
    d = diagnose(case.fit, case.holdout, effects=("zone_burners",))
    assert d.verdict.status == "no_gap"
    page, raw = _parse(write_report(d, tmp_path / "control.html"))
    _check_self_contained(page, raw)
    assert d.verdict.sentence in html.unescape(raw)
    assert "No candidate was tried" in raw
    by_title = {s["title"]: s["svg"] for s in page.sections}
    assert by_title["Candidate effects"] == 0  # no ranking to draw
    assert by_title["Measured and modelled temperatures"] == 1
    assert by_title["Where the error lies"] == 1
