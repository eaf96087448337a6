"""The held-out data a diagnosis is judged on: given, a whole experiment the others cover, or
the last part of a lone one; and the data that cannot be diagnosed, refused with what is
missing."""

from __future__ import annotations

import numpy as np

from ..errors import FurnaceError
from ..experiment import Experiment
from .words import zones_words

TAIL_SHARE = 0.3
"""Share of a lone experiment held out (its last part) when no holdout is given."""
MIN_FIT_SAMPLES = 100
MIN_HOLDOUT_SAMPLES = 30


def split(data: list[Experiment], holdout: list[Experiment] | None
          ) -> tuple[list[Experiment], list[Experiment], list[int | None], str]:
    """Fit data, held-out data, which fit experiment each held-out tail continues, and how
    the holdout was chosen. Refuses, with what is missing, data that cannot be diagnosed."""
    if not data:
        raise FurnaceError("no data to diagnose")
    furnace = data[0].furnace
    for e in [*data, *(holdout or [])]:
        if e.furnace != furnace:
            raise FurnaceError(f"{e.source or e.name}: a record of furnace '{e.furnace.name}', "
                               f"the others are of furnace '{furnace.name}'")
        for w, z in enumerate(furnace.zones):
            if not np.isfinite(e.zone_temp[:, w]).any():
                raise FurnaceError(f"{e.source or e.name}: zone '{z}' has no thermocouple "
                                   "readings: every zone needs at least one")
        if len(e) < 2:
            raise FurnaceError(f"{e.source or e.name}: only {len(e)} sample(s)")
    if holdout:
        fit_data, hold, tail_of, how = list(data), list(holdout), [None] * len(holdout), "given"
        missing = uncovered(fit_data, hold)
        if missing:
            how += (f"; it fires {zones_words(missing)}-zone burners, which the fitted data "
                    "never fire")
    elif len(data) > 1:
        # The last experiment whose burners the others cover: an effect of burners that
        # never fire in the fitted data cannot be learnt from them, only stumbled upon.
        missing = [uncovered(data[:i] + data[i + 1:], [data[i]]) for i in range(len(data))]
        k = next((i for i in reversed(range(len(data))) if not missing[i]), len(data) - 1)
        fit_data, hold, tail_of = list(data[:k] + data[k + 1:]), [data[k]], [None]
        how = f"whole experiments: {data[k].name} held out"
        if k != len(data) - 1:
            how += (f" (the others fire every zone's burners it fires; {data[-1].name} fires "
                    f"{zones_words(missing[-1])}-zone burners the rest never fire)")
        elif missing[k]:
            how += (f"; it fires {zones_words(missing[k])}-zone burners, which no other "
                    "experiment fires")
    else:
        e = data[0]
        t0, t1 = float(e.t_min[0]), float(e.t_min[-1])
        cut = t0 + (1 - TAIL_SHARE) * (t1 - t0)
        head, tail = e.between(t0, cut), e.between(cut, np.inf)
        if len(head) < MIN_FIT_SAMPLES or len(tail) < MIN_HOLDOUT_SAMPLES:
            raise FurnaceError(
                f"{e.source or e.name}: too short to hold out part of it ({len(e)} samples; "
                f"its first {100 * (1 - TAIL_SHARE):.0f}% needs at least {MIN_FIT_SAMPLES} "
                f"and the rest {MIN_HOLDOUT_SAMPLES}): give a second experiment or --holdout")
        if head.burner_steps == 0:
            raise FurnaceError(
                f"{e.source or e.name}: only one experiment and no burner change in its first "
                f"{100 * (1 - TAIL_SHARE):.0f}% (up to {cut:.0f} min), which would be fitted "
                "while the rest is held out: nothing identifies the model; give a second "
                "experiment or --holdout")
        fit_data, hold, tail_of = [head], [tail], [0]
        how = f"last {100 * TAIL_SHARE:.0f}% of {e.name} (from {cut:.0f} min)"
    if all(e.burner_steps == 0 for e in fit_data):
        raise FurnaceError(
            f"no burner change in the data to fit ({', '.join(e.source or e.name for e in fit_data)}): "
            "too little excitation to identify the model; the data need at least one step in "
            "the number of burners firing")
    return fit_data, hold, tail_of, how


def uncovered(fit_data: list[Experiment], holdout: list[Experiment]) -> list[str]:
    """Zones whose burners fire in the held-out data but never in the fitted data."""
    zones = next((e.furnace.zones for e in [*fit_data, *holdout]), ())

    def firing(data):
        return {z for e in data for k, z in enumerate(zones) if np.any(e.burners[:, k] > 0)}
    return [z for z in zones if z in firing(holdout) - firing(fit_data)]
