"""Parameter dataclasses built from user input: the kind of each value checked in one place.

:func:`from_dict` builds a frozen parameter dataclass from a mapping of overrides (``--set KEY=VALUE``, a study's
settings), refusing unknown names and values of the wrong kind before the class's own range checks run.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

__all__ = ["from_dict"]


def from_dict(cls: type, values: dict[str, Any], method: str) -> Any:
    """Build the parameter dataclass ``cls`` of ``method`` from a mapping of overrides, refusing (ValueError, one
    line naming the parameter) unknown names and values of the wrong kind: a number where the default is a number
    (finite; an integer where the default is one), a flag where it is a flag. Ranges are the dataclass's own
    ``__post_init__`` checks."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(map(repr, unknown))} for method {method!r}; "
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
            ok = isinstance(value, (int, float, np.number)) and not isinstance(value, bool) and math.isfinite(value)
            kind = "a finite number"
        else:
            continue
        if not ok:
            raise ValueError(f"parameter {name!r} of method {method!r} must be {kind}, got {value!r}")
    return cls(**values)
