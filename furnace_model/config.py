"""Checked access to YAML: every wrong key, type or value is reported by its key path.

Scenarios and the daemon's config are written by hand on a plant floor; a typo must stop the
program with `file: burners.steps[2].at_min: expected a number, got 'ten'`, never a
traceback and never a silently ignored key.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from .errors import ConfigError

_MISSING = object()


def load_yaml(path: str | Path) -> Node:
    """Parse a YAML file safely (no tags that build objects) into a checked Node."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(path), "", "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), "", f"cannot read: {exc}") from None
    return parse_yaml(text, str(path))


def parse_yaml(text: str, file: str = "<string>") -> Node:
    try:
        value = yaml.safe_load(text)
    except RecursionError:
        raise ConfigError(file, "", "not valid YAML: nested too deeply") from None
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        tag = str(exc.problem or "").split("'")[1:2] or ["?"]
        raise ConfigError(file, "", f"not valid YAML: {where}the tag "
                          f"'{tag[0].replace('tag:yaml.org,2002:', '!!')}' is not allowed: a "
                          "setting is text, a number, a list or a mapping") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(file, "", f"not valid YAML: {where}{problem}") from None
    return Node({} if value is None else value, file)


class Node:
    """A value read from YAML together with where it came from."""

    def __init__(self, value: Any, file: str, path: str = ""):
        self.value, self.file, self.path = value, file, path

    def error(self, message: str) -> ConfigError:
        return ConfigError(self.file, self.path, message)

    def _sub(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else str(key)

    # -- containers -------------------------------------------------------------------------
    def mapping(self, allowed: set[str] | list[str] | tuple[str, ...] | None = None) -> Node:
        if not isinstance(self.value, dict):
            raise self.error(f"expected a mapping of keys, got {_kind(self.value)}")
        for key in self.value:
            if not isinstance(key, str):
                raise self.error(f"keys must be text, got {key!r}")
            if allowed is not None and key not in allowed:
                raise ConfigError(self.file, self._sub(key),
                                  f"unknown key (expected one of: {', '.join(sorted(allowed))})")
        return self

    def keys(self) -> list[str]:
        return list(self.mapping().value)

    def has(self, key: str) -> bool:
        return isinstance(self.value, dict) and key in self.value

    def child(self, key: str, default: Any = _MISSING) -> Node:
        self.mapping()
        if key not in self.value:
            if default is _MISSING:
                raise ConfigError(self.file, self._sub(key), "required key is missing")
            return Node(default, self.file, self._sub(key))
        return Node(self.value[key], self.file, self._sub(key))

    def items(self) -> Iterator[tuple[str, Node]]:
        for key in self.mapping().value:
            yield key, self.child(key)

    def elements(self, min_len: int = 0, max_len: int | None = None) -> list[Node]:
        if not isinstance(self.value, list):
            raise self.error(f"expected a list, got {_kind(self.value)}")
        if len(self.value) < min_len:
            raise self.error(f"expected at least {min_len} entries, got {len(self.value)}")
        if max_len is not None and len(self.value) > max_len:
            raise self.error(f"expected at most {max_len} entries, got {len(self.value)}")
        return [Node(v, self.file, self._sub(i)) for i, v in enumerate(self.value)]

    # -- scalars ----------------------------------------------------------------------------
    def number(self, lo: float | None = None, hi: float | None = None) -> float:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(f"expected a number, got {_kind(v)}")
        try:
            v = float(v)
        except OverflowError:
            raise self.error(f"expected a finite number, got {_show(v)}") from None
        if not math.isfinite(v):
            raise self.error(f"expected a finite number, got {v}")
        if lo is not None and v < lo:
            raise self.error(f"must be at least {lo}, got {v:g}")
        if hi is not None and v > hi:
            raise self.error(f"must be at most {hi}, got {v:g}")
        return v

    def integer(self, lo: int | None = None, hi: int | None = None) -> int:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(f"expected a whole number, got {_kind(v)}")
        if lo is not None and v < lo:
            raise self.error(f"must be at least {lo}, got {_show(v)}")
        if hi is not None and v > hi:
            raise self.error(f"must be at most {hi}, got {_show(v)}")
        return v

    def boolean(self) -> bool:
        if not isinstance(self.value, bool):
            raise self.error(f"expected true or false, got {_kind(self.value)}")
        return self.value

    def string(self, choices: tuple[str, ...] | list[str] | None = None) -> str:
        if not isinstance(self.value, str):
            raise self.error(f"expected text, got {_kind(self.value)}")
        if choices is not None and self.value not in choices:
            raise self.error(f"must be one of {', '.join(choices)}, got '{self.value}'")
        return self.value

    def timestamp(self) -> pd.Timestamp:
        """An ISO 8601 time with an explicit offset, in UTC: a plant's clock is never guessed."""
        try:
            value = pd.Timestamp(str(self.value))
        except ValueError:
            raise self.error(f"not an ISO 8601 time: '{self.value}'") from None
        if value.tzinfo is None:
            raise self.error("give a UTC offset or Z, e.g. 2026-03-04T06:00:00Z")
        return value.tz_convert("UTC")

    # -- shorthands for optional keys ------------------------------------------------------
    def get_number(self, key: str, default: float | None = None, **bounds: float) -> float:
        node = self.child(key, _MISSING if default is None else default)
        return node.number(**bounds)

    def get_integer(self, key: str, default: int | None = None, **bounds: int) -> int:
        node = self.child(key, _MISSING if default is None else default)
        return node.integer(**bounds)

    def get_string(self, key: str, default: str | None = None, choices=None) -> str:
        node = self.child(key, _MISSING if default is None else default)
        return node.string(choices)

    def get_bool(self, key: str, default: bool | None = None) -> bool:
        node = self.child(key, _MISSING if default is None else default)
        return node.boolean()


def _show(v: int) -> str:
    """A whole number short enough for a one-line message."""
    text = str(v)
    return text if len(text) <= 24 else f"{text[:12]}...({len(text)} digits)"


def _kind(v: Any) -> str:
    if v is None:
        return "nothing (null)"
    if isinstance(v, bool):
        return f"a boolean ({v})"
    if isinstance(v, int):
        return f"a number ({_show(v)})"
    if isinstance(v, float):
        return f"a number ({v})"
    if isinstance(v, str):
        short = v if len(v) <= 40 else v[:37] + "..."
        return f"text '{short}'"
    if isinstance(v, list):
        return "a list"
    if isinstance(v, dict):
        return "a mapping"
    return type(v).__name__
