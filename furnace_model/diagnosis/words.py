"""The diagnosis's words shared by the held-out split, the located error, the verdict, the
text summary and the report, so that they name zones, models and temperatures alike."""

from __future__ import annotations

import math

from ..identification.residuals import ZONE_WORDS
from ..simulation.furnace import Furnace


def zones_words(zones: list[str]) -> str:
    return and_words([ZONE_WORDS[z] for z in zones])


def and_words(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def temp_c(x: float, decimals: int = 1, *, sign: bool = False) -> str:
    """A temperature, or a difference of temperatures, in °C (the number alone) with the
    digits its size needs: `decimals` decimals, and more below 1 °C, so that two significant
    digits are always shown. A noise floor of 0.03 °C reads 0.030, never 0.0, and a floor
    beside an error of 0.31 °C is as readable as the error; above 1 °C a tenth is already
    finer than any thermocouple. Not a number reads '-'. `sign`: a '+' before a rise."""
    x = float(x)
    if not math.isfinite(x):
        return "-"
    plus = "+" if sign else ""
    if x == 0.0:
        return f"{0.0:{plus}.{decimals}f}"
    two = float(f"{abs(x):.2g}")  # as two significant digits round it: 0.996 is 1.0
    places = decimals if two >= 1.0 else max(decimals, 1 - math.floor(math.log10(two)))
    return f"{x:{plus}.{places}f}"


def paper_like(furnace: Furnace) -> bool:
    """Whether the records are of a furnace read as the paper's: eq. 11's network with two
    thermocouples in every zone. Only then may a page speak of 'the paper's model' and of
    'the two thermocouples of a zone'; a plant with one thermocouple per zone or another
    network is its own furnace, however its model is built."""
    return furnace.paper_structure and all(n == 2 for n in furnace.thermocouples)


def model_words(furnace: Furnace) -> str:
    """The baseline model in a sentence, lower case: 'the paper's model' on the paper's
    furnace, 'the model of furnace NAME' on any other."""
    return "the paper's model" if paper_like(furnace) else f"the model of furnace '{furnace.name}'"


def baseline_label(furnace: Furnace) -> str:
    """The baseline's short name in a legend or a table head."""
    return "baseline (paper's model)" if paper_like(furnace) else "baseline"


def capital(text: str) -> str:
    return text[:1].upper() + text[1:]
