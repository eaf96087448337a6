"""What an effect's optional parts share (`tried.Tried`, how the diagnosis tries it;
`drawn.Drawn`, how the selfcheck draws it): each is declared once on an effect class and
bound to every class that has it, so that a part a subclass inherits makes the subclass's
effect (a derated burner drawn by a fuel switch's part is still the derating)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Self

if TYPE_CHECKING:
    from .base import Effect


@dataclass
class Part:
    effect: type[Effect] | None = field(default=None, kw_only=True, repr=False, compare=False)
    """The effect class the part belongs to (`Effect.__init_subclass__` binds it)."""

    def bound(self, effect: type[Effect]) -> Self:
        """This part for `effect`: itself when it is already, else a copy."""
        return self if self.effect is effect else dataclasses.replace(self, effect=effect)

    @property
    def name(self) -> str:
        """The effect's name, for messages."""
        return getattr(self.effect, "name", type(self).__name__)
