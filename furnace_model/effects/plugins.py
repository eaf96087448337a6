"""Effects written by users: loaded from their own Python file or from an installed
package's `furnace_model.effects` entry point, checked, and registered beside ours.

A plug-in is checked before anything uses it, so that a mistake in it is one line naming
its file and what is wrong, never a traceback in the middle of a diagnosis: its file must
compile and load, each effect class must say what it is (name, physics, parameters within
their bounds, the strength parameters that vanish with it), and its physics must run on a
short heat-up with its default values. An effect whose physics still fails inside a fit
costs that candidate only (the diagnosis reports it as failed, with the reason)."""

from __future__ import annotations

import importlib.util
import re
import sys
import traceback
import zlib
from pathlib import Path

import numpy as np

from ..errors import FurnaceError
from ..simulation.furnace import PAPER
from ..simulation.parameters import BASELINE, PAPER_TABLE_V, Param
from . import BUILT_IN, EFFECTS
from .base import Drawn, Effect, Option, Tried

ENTRY_POINT_GROUP = "furnace_model.effects"
RESERVED = ("none", "baseline", "door_open", "tc_reads_low")
"""Names the selfcheck and the reports already give a meaning."""
OPTION_KINDS = ("number", "integer", "choice", "choices")
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")

_SOURCES: dict[str, str] = {}
"""Plug-in effect name -> the file or entry point it came from."""
_installed_loaded = False


class PluginError(FurnaceError):
    """A user's effect cannot be used: the message names its file and the problem."""

    exit_code = 2


def load_file(path: str | Path) -> list[type[Effect]]:
    """Load, check and register every effect class defined in the Python file `path`."""
    path = Path(path)
    where = str(path)
    if path.suffix != ".py":
        raise PluginError(f"{where}: an effect plug-in is a Python file (.py)")
    try:
        source = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise PluginError(f"{where}: cannot read: {exc.strerror or exc}") from None
    try:
        code = compile(source, where, "exec")
    except SyntaxError as exc:
        raise PluginError(f"{where}: line {exc.lineno}: syntax error: {exc.msg}") from None
    stem = re.sub(r"\W", "_", path.stem)
    name = f"furnace_model_plugin_{stem}_{zlib.crc32(str(path.resolve()).encode()):08x}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look classes up by module
    try:
        exec(code, module.__dict__)  # noqa: S102 - running the user's own file is the point
    except Exception as exc:  # noqa: BLE001 - whatever the file raises is reported as its fault
        del sys.modules[name]
        raise PluginError(f"{where}: fails when loaded{_line(exc, where)}: "
                          f"{type(exc).__name__}: {exc}") from None
    classes = [v for v in vars(module).values() if isinstance(v, type) and issubclass(v, Effect)
               and v.__module__ == name and "name" in vars(v)]
    if not classes:
        raise PluginError(f"{where}: defines no effect (a subclass of "
                          "furnace_model.effects.Effect with a `name`)")
    for cls in classes:
        register(cls, where)
    return classes


def load_installed() -> list[str]:
    """Register the effects of installed packages (entry point group `furnace_model.effects`,
    each naming an Effect class or a module of them), once. A broken one is skipped with a
    warning on stderr: a package installed for another furnace must not stop every command.
    Returns the warnings."""
    global _installed_loaded
    if _installed_loaded:
        return []
    _installed_loaded = True
    from importlib.metadata import entry_points

    warnings = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        where = f"entry point {ep.name} ({ep.value})"
        try:
            obj = ep.load()
            classes = [obj] if isinstance(obj, type) else [
                v for v in vars(obj).values() if isinstance(v, type) and issubclass(v, Effect)
                and v.__module__ == obj.__name__ and "name" in vars(v)]
            for cls in classes:
                register(cls, where)
        except PluginError as exc:
            warnings.append(f"effect plug-in not loaded: {exc}")
        except Exception as exc:  # noqa: BLE001 - an installed package's failure, reported
            warnings.append(f"effect plug-in not loaded: {where}: {type(exc).__name__}: {exc}")
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    return warnings


def register(cls: type[Effect], where: str | None = None) -> type[Effect]:
    """Check `cls` and add it to the registry (`effects.EFFECTS`); usable as a decorator."""
    where = where or f"{cls.__module__}.{cls.__qualname__}"
    name = vars(cls).get("name")
    known = EFFECTS.get(name) if isinstance(name, str) else None
    if known is not None and (known is cls or _SOURCES.get(name) == where):
        return cls  # the same file loaded again
    problem = check(cls)
    if problem:
        label = f"effect {name!r}" if isinstance(name, str) else f"class {cls.__name__}"
        raise PluginError(f"{where}: {label}: {problem}")
    EFFECTS[name] = cls
    _SOURCES[name] = where
    return cls


def unregister(name: str) -> None:
    """Take a plug-in out of the registry (the built-in effects stay)."""
    if name in BUILT_IN:
        raise ValueError(f"{name} is built in")
    EFFECTS.pop(name, None)
    _SOURCES.pop(name, None)


def source_of(name: str) -> str | None:
    """Where a plug-in effect came from; None for the built-in ones."""
    return _SOURCES.get(name)


def guarded(effects, call):
    """`call()`, with a failure inside a plug-in's physics reported as the plug-in's (its
    file and line), not as a traceback of ours."""
    try:
        return call()
    except FurnaceError:
        raise
    except Exception as exc:
        plugged = [e for e in effects if source_of(e.name)]
        if not plugged:
            raise
        e = plugged[0]
        file = getattr(sys.modules.get(type(e).__module__), "__file__", None)
        raise PluginError(f"{source_of(e.name)}: effect {e.name!r}: its physics fails"
                          f"{_line(exc, file)}: {type(exc).__name__}: {exc}") from None


def check(cls: type[Effect]) -> str | None:
    """What is wrong with an effect class, in words; None when it can be used."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        return "not a subclass of furnace_model.effects.Effect"
    name = vars(cls).get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        return f"`name` must be lowercase letters, digits and _ (got {name!r})"
    if name in EFFECTS or name in RESERVED:
        return f"the name {name!r} is taken: choose another"
    if not isinstance(getattr(cls, "physics", None), str) or not cls.physics.strip():
        return "`physics` must say in words what the effect is (the verdict quotes it)"
    for key, spec in cls.option_specs.items():
        if not isinstance(spec, Option) or spec.kind not in OPTION_KINDS:
            return f"option {key!r} must be an Option of kind {', '.join(OPTION_KINDS)}"
    tried, drawn = cls.tried, cls.drawn
    if not isinstance(tried, Tried) or not isinstance(drawn, Drawn):
        return ("`tried` must be a furnace_model.effects.Tried and `drawn` a "
                "furnace_model.effects.Drawn")
    for forms in ({"candidate_options": tried.candidate_options},
                  *({"further_laws": f} for f in tried.further_laws)):
        (what, opts), = forms.items()
        if set(opts) - set(cls.option_specs):
            return f"`{what}` sets undeclared option(s) {sorted(set(opts) - set(cls.option_specs))}"
    try:
        # checked on the paper's furnace, before any command names one: every built-in
        # effect applies to it, and its parameters (Table V) give a finite heat-up
        effect = cls(furnace=PAPER)
        params = effect.params
    except Exception as exc:  # noqa: BLE001
        return f"cannot be made with its default options: {type(exc).__name__}: {exc}"
    problem = _check_params(params)
    if problem:
        return problem
    names = {p.name for p in params}
    if not tried.null:
        return ("`null` must name at least one strength parameter and the value at which the "
                "effect vanishes (the diagnosis credits an effect only away from it)")
    if set(tried.null) - names:
        return f"`null` names {sorted(set(tried.null) - names)}, which are not its parameters"
    for key, bounds in drawn.ranges.items():
        if not (isinstance(bounds, tuple) and len(bounds) == 2 and bounds[0] <= bounds[1]):
            return f"`ranges[{key!r}]` must be a (low, high) pair with low <= high"
    return _check_physics(effect, getattr(sys.modules.get(cls.__module__), "__file__", None))


def _check_params(params) -> str | None:
    if not isinstance(params, tuple) or not params or \
            not all(isinstance(p, Param) for p in params):
        return "`_params()` must return a non-empty tuple of Param"
    taken = {p.name for p in BASELINE}
    for cls in EFFECTS.values():
        taken |= {p.name for p in cls(furnace=PAPER).params}
    seen = set()
    for p in params:
        if not _NAME.match(p.name) or p.name in seen:
            return f"parameter name {p.name!r} is not a new lowercase identifier"
        if p.name in taken:
            return f"parameter {p.name!r} is already a parameter of the model or an effect"
        seen.add(p.name)
        if not (np.isfinite(p.lo) and np.isfinite(p.hi) and p.lo < p.hi):
            return f"parameter {p.name!r}: bounds {p.lo:g}..{p.hi:g} are not finite with low < high"
        if p.log and p.lo <= 0:
            return f"parameter {p.name!r}: searched on a log scale, its low bound must be > 0"
        if not p.lo <= p.default <= p.hi:
            return f"parameter {p.name!r}: default {p.default:g} outside its bounds " \
                   f"{p.lo:g}..{p.hi:g}"
    return None


def _check_physics(effect: Effect, file: str | None) -> str | None:
    """The effect at its defaults on two hours of a heat-up with a burner step."""
    from ..simulation.structure import Inputs, ModelStructure

    structure = ModelStructure([effect], furnace=PAPER)
    values = {**PAPER_TABLE_V, **{p.name: p.default for p in effect.params}}
    inputs = Inputs(np.array([0.0, 60.0]), np.array([[4.0, 0.0, 0.0], [10.0, 4.0, 2.0]]),
                    np.array([30.0, 30.0]))
    t = np.arange(0.0, 121.0, 1.0)
    try:
        y = structure.simulate(values, inputs, t, np.full(PAPER.n_zones, 30.0)).sensors
    except Exception as exc:  # noqa: BLE001
        return (f"its physics fails on a short heat-up at its default values"
                f"{_line(exc, file)}: "
                f"{type(exc).__name__}: {exc}")
    if y.shape[-2:] != (t.size, len(PAPER.sensors)) or not np.all(np.isfinite(y)):
        return ("its physics gives no finite temperatures on a short heat-up at its default "
                "values")
    return None


def _line(exc: BaseException, file: str | None) -> str:
    """' at FILE line N' of the innermost frame of the plug-in's file, if there is one."""
    mine = [f for f in traceback.extract_tb(exc.__traceback__) if file and f.filename == file]
    return f" at line {mine[-1].lineno}" if mine else ""
