"""Parameter dataclasses: each field's constraint declared once, checked in one place.

A frozen parameter dataclass derives from :class:`Params` and declares its fields' constraints as a class
attribute; :class:`Params` checks them on construction (:func:`check`)::

    @dataclass(frozen=True)
    class BirchParams(Params):
        threshold: float = 0.08
        branching_factor: int = 50
        constraints: ClassVar[dict[str, Constraint]] = {"threshold": number(lo=0, lo_open=True),
                                                        "branching_factor": integer(lo=2, whole=True)}

A value out of its constraint raises ValueError in one line, ``BirchParams.threshold must be a positive finite
number, got 0.0``. :meth:`Params.to_dict` is the JSON form recorded in output metadata; :func:`from_dict` (and
:meth:`Params.from_dict`) builds such a class from a mapping of overrides (``--set KEY=VALUE``, a study's settings),
refusing unknown names and values of the wrong kind before the constraints are checked.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

__all__ = ["Constraint", "Params", "number", "integer", "one_of", "rule", "check", "from_dict", "plain"]


@dataclass(frozen=True)
class Constraint:
    """What one field accepts: ``text`` completes "must be ...", ``ok(value, params)`` tests a value (``params``
    is the whole instance, for a bound that depends on another field)."""

    text: str
    ok: Callable[[Any, Any], bool]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.number)) and not isinstance(v, (bool, np.bool_))


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False,
           finite: bool = True, nullable: bool = False, hi_of: Callable[[Any], float] | None = None,
           text: str | None = None) -> Constraint:
    """A real number (not a flag), finite unless ``finite=False``, within [lo, hi] (open ends with ``lo_open``,
    ``hi_open``; ``hi_of(params)`` for a bound set by another field), or None when ``nullable``."""

    def ok(v: Any, params: Any) -> bool:
        if v is None:
            return nullable
        if not _is_number(v) or (finite and not math.isfinite(v)) or math.isnan(v):
            return False
        top = hi_of(params) if hi_of is not None else hi
        return ((lo is None or (v > lo if lo_open else v >= lo))
                and (top is None or (v < top if hi_open else v <= top)))

    if text is None:
        fin = "finite " if finite else ""
        if lo == 0 and hi is None and hi_of is None:
            text = f"a {'positive' if lo_open else 'non-negative'} {fin}number"
        elif lo is not None and hi is None and hi_of is None:
            text = f"a {fin}number {'>' if lo_open else '>='} {lo:g}"
        elif lo is None and hi is None:
            text = f"a {fin}number"
        else:
            text = f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        if nullable:
            text = f"None or {text}"
    return Constraint(text, ok)


def integer(lo: int = 1, hi: int | None = None, *, whole: bool = False) -> Constraint:
    """An integer in [lo, hi] (no upper bound for None; not a flag); ``whole`` also accepts a whole-valued float
    (2.0). An upper bound keeps a size within what the machine can hold (its reason beside the declaration)."""

    def ok(v: Any, params: Any) -> bool:
        if whole:
            good = _is_number(v) and math.isfinite(v) and int(v) == v and v >= lo
        else:
            good = isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= lo
        return good and (hi is None or v <= hi)

    text = "a positive integer" if lo == 1 else f"an integer >= {lo}"
    return Constraint(text if hi is None else f"{text} at most {hi}", ok)


def one_of(*choices: Any) -> Constraint:
    """One of ``choices``."""
    return Constraint(f"one of {', '.join(map(str, choices))}", lambda v, params: v in choices)


def rule(text: str, ok: Callable[[Any], bool]) -> Constraint:
    """Any other test of one value, described by ``text``."""
    return Constraint(text, lambda v, params: bool(ok(v)))


def check(params: Any) -> None:
    """Check every field of a parameter dataclass against its class's ``constraints``; ValueError naming the first
    field out of its constraint (``Class.field must be ..., got value``)."""
    for name, c in type(params).constraints.items():
        value = getattr(params, name)
        try:
            good = c.ok(value, params)
        except (TypeError, ValueError, OverflowError):
            good = False
        if not good:
            raise ValueError(f"{type(params).__name__}.{name} must be {c.text}, got {value!r}")


def from_dict(cls: type, values: dict[str, Any], method: str | None = None) -> Any:
    """Build the parameter dataclass ``cls`` (of ``method``, when given) from a mapping of overrides, refusing
    (ValueError, one line naming the parameter) unknown names and values of the wrong kind: a number where the
    default is a number (finite; an integer where the default is one), a flag where it is a flag. Ranges are the
    class's declared constraints, checked by its ``__post_init__`` (:func:`check`)."""
    owner = f"method {method!r}" if method else cls.__name__
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(map(repr, unknown))} for {owner}; "
                         f"accepted: {', '.join(fields)}")
    for name, value in values.items():
        default = fields[name].default
        if isinstance(default, bool):
            ok = isinstance(value, bool)
            kind = "true or false"
        elif isinstance(default, int):
            ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
            kind = "an integer"
        elif isinstance(default, float):
            ok = _is_number(value) and math.isfinite(value)
            kind = "a finite number"
        else:
            continue
        if not ok:
            raise ValueError(f"parameter {name!r} of {owner} must be {kind}, got {value!r}")
    return cls(**values)


def plain(value: Any) -> Any:
    """``value`` in JSON-ready form: a :class:`Params` by its :meth:`~Params.to_dict`, any other dataclass field by
    field, mappings, lists and tuples item by item (tuples as lists), numpy scalars as Python numbers."""
    if isinstance(value, Params):
        return value.to_dict()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class Params:
    """Base of the frozen parameter dataclasses: checks the class's declared ``constraints`` on construction
    (:func:`check`), :meth:`to_dict` for output metadata, :meth:`from_dict` from a mapping of overrides.

    A subclass that normalises a field before the check (``object.__setattr__`` in its own ``__post_init__``)
    calls ``super().__post_init__()`` after it."""

    #: Field name -> what it accepts (fields without an entry accept anything).
    constraints: ClassVar[dict[str, Constraint]] = {}

    def __post_init__(self) -> None:
        check(self)

    def to_dict(self) -> dict[str, Any]:
        """Every field, JSON-ready (:func:`plain`: nested parameters as dicts, tuples as lists), in field order."""
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, values: dict[str, Any], method: str | None = None) -> Any:
        """Build from a mapping (e.g. :meth:`to_dict`'s): a nested parameter field from its dict, a tuple field
        from a list; ValueError in one line naming an unknown key (:func:`from_dict`; ``method`` names the owner
        in the message, the class's name by default)."""
        values = dict(values)
        for f in dataclasses.fields(cls):
            if f.name not in values:
                continue
            default = f.default if f.default is not dataclasses.MISSING else (
                f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
            v = values[f.name]
            if isinstance(default, Params) and isinstance(v, dict):
                values[f.name] = type(default).from_dict(v, method)
            elif isinstance(default, tuple) and isinstance(v, list):
                values[f.name] = tuple(tuple(x) if isinstance(x, list) else x for x in v)
        return from_dict(cls, values, method)
