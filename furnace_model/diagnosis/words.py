"""The diagnosis's words for lists of zones, shared by the held-out split, the located
error and the verdict, so that they name zones alike."""

from __future__ import annotations

from ..identification.residuals import ZONE_WORDS


def zones_words(zones: list[str]) -> str:
    return and_words([ZONE_WORDS[z] for z in zones])


def and_words(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def temperature(x: float) -> str:
    """A temperature (or an error in °C) with the digits its size needs: a floor of 0.03
    °C is not 0.0."""
    if not abs(x) < 1.0:
        return f"{x:.1f}"
    return f"{x:.2g}"
