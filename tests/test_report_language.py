"""The report speaks the record's language: a partial explanation with its parts, the model
and the thermocouples named as the furnace has them, temperatures with the digits their size
needs, and time on the record's calendar when it has one."""

from __future__ import annotations

import dataclasses
import html
import re

import matplotlib.dates as mdates
import numpy as np
import pytest
from wandering import wandering_holdout

from furnace_model import report
from furnace_model.cli.diagnose import summary
from furnace_model.diagnosis import Verdict, diagnose
from furnace_model.diagnosis.cases import case_rng, draw_case
from furnace_model.simulation.furnace import PAPER

ONE_TC = dataclasses.replace(PAPER, name="plant7", thermocouples=(1, 1, 1))
"""Eq. 11's network measured as plants measure it: one thermocouple per zone."""


@pytest.fixture(scope="module")
def one_tc_partial():
    """Selfcheck wall draw 2 on the one-thermocouple furnace, its held-out ambient wandering
    (tests/wandering.py): the wall explains part of the gap."""
    case = draw_case("wall_storage", case_rng(0, "wall_storage", 2), furnace=ONE_TC)
    case = dataclasses.replace(case, holdout=[wandering_holdout(case, "wall_storage")])
    d = diagnose(case.fit, case.holdout, effects=("wall_storage",))
    assert d.verdict.status == "explained_in_part", d.verdict.sentence
    return d


def _text(page: str) -> str:
    """The page's words: markup and figures out, entities read."""
    return html.unescape(re.sub(r"<[^>]+>", " ", re.sub(r"<svg.*?</svg>", " ", page,
                                                        flags=re.S)))


def test_a_partial_explanation_has_its_word_colour_and_parts(one_tc_partial):
    d = one_tc_partial
    page = report.render(d)
    assert ('<span class="status" style="background:'
            f'{report.STATUS_COLOURS["explained_in_part"]}">explained in part</span>') in page
    assert len(set(report.STATUS_COLOURS.values())) == len(report.STATUS_COLOURS)
    text = _text(page)
    assert "What the kept effects explain, and what remains" in text
    part = d.verdict.parts[0]
    assert re.search(rf"wall_storage\s+{part.gap_closed_pct:.0f}\s+{part.shrink_pct:.0f}", text)
    assert "Where what remains lies, on the kept model's held-out residual" in text
    # the kept model is drawn beside the baseline, and its numbers are in the tables
    assert "with wall_storage" in page.split("Measured and modelled temperatures")[1]
    assert "wall_storage held out" in text


def test_on_a_furnace_of_one_thermocouple_a_zone_the_words_are_its_own(one_tc_partial):
    d = one_tc_partial
    for words in (_text(report.render(d)), summary(d), d.verdict.sentence):
        assert "paper's model" not in words and "paper's" not in words.replace(
            "the paper's model, eq. 11", "")
        assert "two thermocouples" not in words
    text = _text(report.render(d))
    assert "the model of furnace 'plant7'" in text and "baseline" in text
    assert "eq. 11 on furnace 'plant7'" in summary(d)
    # the paper's own furnace keeps its words
    page = report.render(dataclasses.replace(d, fit_data=[dataclasses.replace(
        e, furnace=PAPER, tc=np.repeat(e.tc, 2, axis=1)) for e in d.fit_data]))
    assert "the two thermocouples of a zone" in _text(page)
    assert "the paper's model" in _text(page)


def test_a_small_noise_floor_keeps_its_digits(one_tc_partial):
    d = one_tc_partial
    small = dataclasses.replace(d, noise_floor_c={z: 0.03 for z in ONE_TC.zones})
    text = _text(report.render(small))
    rows = re.findall(r"soaking\s+\S+\s+\S+\s+(\S+)\s+\S+", text)
    assert "0.030" in rows, rows
    assert "0.030" in summary(small) and "| 0.00 |" not in summary(small)


def test_a_record_with_a_start_time_is_drawn_against_dates(one_tc_partial):
    d = one_tc_partial
    fig = report._fig_traces(d, d.best())
    ax = fig.axes[0]
    assert isinstance(ax.xaxis.get_major_formatter(), mdates.ConciseDateFormatter)
    start = d.fit_data[0].start_time
    lo = mdates.num2date(ax.get_xlim()[0])
    assert abs((lo - start).total_seconds()) < 86400
    assert "time (UTC)" in [a.get_xlabel() for a in fig.axes]
    svg = report._svg(report._fig_residuals(d), "residuals")
    assert f">{start.year}-{start.strftime('%b')}" in svg  # the date's year and month, said once


def test_a_record_without_a_start_time_keeps_minutes_and_a_long_one_days(one_tc_partial):
    d = one_tc_partial

    def without(e, stretch=1.0):
        return dataclasses.replace(e, start_time=None, t_min=e.t_min * stretch)

    short = dataclasses.replace(d, fit_data=[without(e) for e in d.fit_data],
                                holdout=[without(e) for e in d.holdout])
    fig = report._fig_traces(short, None)
    assert fig.axes[0].get_xlim()[1] == pytest.approx(d.fit_data[0].t_min[-1], rel=0.1)
    assert "time (min)" in [a.get_xlabel() for a in fig.axes]
    long = dataclasses.replace(d, fit_data=[without(e, 20.0) for e in d.fit_data],
                               holdout=[without(e, 20.0) for e in d.holdout])
    fig = report._fig_traces(long, None)
    days = 20.0 * d.fit_data[0].t_min[-1] / 1440.0
    assert fig.axes[0].get_xlim()[1] == pytest.approx(days, rel=0.1)
    assert "time (days)" in [a.get_xlabel() for a in fig.axes]


def test_the_best_candidate_is_drawn_when_it_explains_only_part_of_the_gap(one_tc_partial):
    """With no effect named, the top candidate that closes part of the gap is still drawn
    beside the baseline, and said to close only part of it."""
    d = one_tc_partial
    gone = dataclasses.replace(d, kept=None, verdict=Verdict("unexplained", [], 0.0, "none"))
    page = report.render(gone)
    traces = page.split("Measured and modelled temperatures")[1].split("</section>")[0]
    assert "with wall_storage" in traces
    assert "not all of it" in _text(traces)
