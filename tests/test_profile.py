"""Profile intervals on criteria whose crossings are known."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.profile import profile_interval


def test_a_quadratic_criterion_gives_the_linearised_interval():
    lo, hi = profile_interval(lambda z: 100.0 + 4.0 * (z - 1.0) ** 2, 1.0, 0.9, 100.0, 4.0,
                              -10.0, 10.0)
    assert lo == pytest.approx(0.0, abs=0.02) and hi == pytest.approx(2.0, abs=0.02)


def test_a_skewed_criterion_gives_a_skewed_interval():
    """Rising four times as steeply on the right: the crossings at -2 and +0.5."""
    def sse(z):
        return 10.0 + (z ** 2 if z < 0 else 16.0 * z ** 2)

    lo, hi = profile_interval(sse, 0.0, 1.0, 10.0, 4.0, -50.0, 50.0)
    assert lo == pytest.approx(-2.0, rel=0.03) and hi == pytest.approx(0.5, rel=0.03)


def test_a_criterion_flat_up_to_the_box_reaches_it():
    lo, hi = profile_interval(lambda z: 5.0 + min(z, 0.0) ** 2, 0.0, 0.5, 5.0, 1.0, -3.0, 3.0)
    assert lo == pytest.approx(-1.0, rel=0.03) and hi == 3.0


def test_only_the_bracket_is_trusted_beyond_the_crossing():
    """Past the crossing at 2 the criterion falls again (another parameter at its bound):
    the end stays at the first crossing."""
    def sse(z):
        return z * z if z < 3.0 else max(9.0 - 5.0 * (z - 3.0), 0.5)

    lo, hi = profile_interval(sse, 0.0, 0.5, 0.0, 4.0, -np.inf, 40.0)
    assert hi == pytest.approx(2.0, rel=0.03)
