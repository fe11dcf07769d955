"""Declared parameter constraints (pipeline/constraints.py): one check for every parameter class."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from pipeline import registry
from pipeline.constraints import Constraint, check, from_dict, integer, number, one_of, rule
from pipeline.estimators.params import RetrievalParams


@dataclass(frozen=True)
class Knobs:
    size: float = 1.0
    count: int = 2
    share: float = 0.5
    floor: float = 0.0
    mode: str = "a"
    gate: float | None = None
    pair: tuple = (0, 1)
    constraints: ClassVar[dict[str, Constraint]] = {
        "size": number(0, lo_open=True), "count": integer(2), "share": number(0, 1, hi_open=True),
        "floor": number(0, hi_of=lambda k: 1.0 / k.count, hi_open=True, text="in [0, 1/count)"),
        "mode": one_of("a", "b"), "gate": number(0, nullable=True),
        "pair": rule("an increasing pair", lambda p: len(p) == 2 and p[0] < p[1])}

    def __post_init__(self) -> None:
        check(self)


@pytest.mark.parametrize("kwargs, match", [
    (dict(size=0.0), r"Knobs.size must be a positive finite number, got 0.0"),
    (dict(size=math.inf), r"Knobs.size must be a positive finite number, got inf"),
    (dict(size=math.nan), r"Knobs.size must be a positive finite number"),
    (dict(size=True), r"Knobs.size must be a positive finite number, got True"),  # a flag is not a number
    (dict(size="1"), r"Knobs.size must be a positive finite number, got '1'"),
    (dict(count=1), r"Knobs.count must be an integer >= 2, got 1"),
    (dict(count=2.0), r"Knobs.count must be an integer >= 2, got 2.0"),  # strict: not a whole float
    (dict(share=1.0), r"Knobs.share must be in \[0, 1\), got 1.0"),
    (dict(count=4, floor=0.25), r"Knobs.floor must be in \[0, 1/count\), got 0.25"),
    (dict(mode="c"), r"Knobs.mode must be one of a, b, got 'c'"),
    (dict(gate=-1.0), r"Knobs.gate must be None or a non-negative finite number"),
    (dict(pair=(1, 0)), r"Knobs.pair must be an increasing pair, got \(1, 0\)"),
    (dict(pair=None), r"Knobs.pair must be an increasing pair, got None"),  # a failing test is a refusal
])
def test_a_value_out_of_its_declared_constraint_is_refused_in_one_line(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Knobs(**kwargs)


def test_values_within_their_constraints_pass_including_numpy_scalars_and_none():
    k = Knobs(size=np.float64(0.1), count=np.int64(3), share=0.0, floor=0.3, mode="b", gate=None)
    assert k.count == 3 and Knobs(gate=0.0).gate == 0.0


def test_whole_integers_accept_whole_floats_only():
    c = integer(2, whole=True)
    assert c.ok(2.0, None) and c.ok(50, None) and not c.ok(2.5, None) and not c.ok(1.0, None)
    assert not c.ok(math.inf, None) and not c.ok(True, None)


def test_from_dict_refuses_unknown_names_and_wrong_kinds_before_the_constraints():
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) 'sise' for method 'knobs'; accepted: size, count"):
        from_dict(Knobs, {"sise": 1.0}, "knobs")
    with pytest.raises(ValueError, match=r"parameter 'count' of method 'knobs' must be an integer, got 2.5"):
        from_dict(Knobs, {"count": 2.5}, "knobs")
    with pytest.raises(ValueError, match=r"Knobs.size must be a positive finite number, got -1"):
        from_dict(Knobs, {"size": -1}, "knobs")
    assert from_dict(Knobs, {"size": 3}, "knobs").size == 3


def _registered_param_classes():
    specs = (*registry.trackers(), *registry.estimators(), *registry.policies())
    classes = {registry.resolve(s.params) for s in specs} | {RetrievalParams}
    return sorted((c for c in classes if c is not None), key=lambda c: c.__name__)


@pytest.mark.parametrize("cls", _registered_param_classes(), ids=lambda c: c.__name__)
def test_every_parameter_class_declares_a_constraint_for_each_non_flag_field_and_its_defaults_pass(cls):
    fields = [f for f in dataclasses.fields(cls) if not isinstance(f.default, bool) and f.name != "robot"]
    missing = [f.name for f in fields if f.name not in cls.constraints]
    assert not missing, f"{cls.__name__}: no declared constraint for {missing}"
    assert set(cls.constraints) <= {f.name for f in dataclasses.fields(cls)}
    check(cls())  # the defaults satisfy their own constraints
