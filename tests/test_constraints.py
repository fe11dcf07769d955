"""Declared parameter constraints (pipeline/constraints.py): one check for every parameter class."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from pipeline import registry
from pipeline.constraints import Constraint, Params, check, from_dict, integer, number, one_of, rule
from pipeline.estimators.params import RetrievalParams


@dataclass(frozen=True)
class Knobs(Params):
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


@dataclass(frozen=True)
class Outer(Params):
    knobs: Knobs = Knobs()
    steps: tuple[float, ...] = (0.1, 0.2)
    constraints: ClassVar[dict[str, Constraint]] = {"steps": rule("increasing", lambda s: list(s) == sorted(s))}


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


def test_params_checks_its_constraints_on_construction_and_serialises_recursively():
    with pytest.raises(ValueError, match=r"Outer.steps must be increasing, got \(0.2, 0.1\)"):
        Outer(steps=(0.2, 0.1))
    d = Outer(knobs=Knobs(count=np.int64(3))).to_dict()
    assert d == {"knobs": {"size": 1.0, "count": 3, "share": 0.5, "floor": 0.0, "mode": "a", "gate": None,
                           "pair": [0, 1]}, "steps": [0.1, 0.2]}
    assert type(d["knobs"]["count"]) is int  # numpy scalars become Python numbers: JSON-ready


def test_params_from_dict_round_trips_and_names_an_unknown_key_in_one_line():
    o = Outer(knobs=Knobs(size=2.0, pair=(1, 3)), steps=(0.5,))
    assert Outer.from_dict(o.to_dict()) == o
    assert Outer.from_dict({"knobs": {"count": 4}}).knobs == Knobs(count=4)
    with pytest.raises(ValueError, match=r"^unknown parameter\(s\) 'sise' for Knobs; accepted: size, count, .*"):
        Outer.from_dict({"knobs": {"sise": 1.0}})
    with pytest.raises(ValueError, match=r"^unknown parameter\(s\) 'knob' for method 'outer'; accepted: knobs, steps$"):
        Outer.from_dict({"knob": {}}, "outer")


@pytest.mark.parametrize("cls", _registered_param_classes(), ids=lambda c: c.__name__)
def test_every_parameter_class_is_a_params_whose_dict_builds_it_again(cls):
    assert issubclass(cls, Params)
    assert cls.from_dict(cls().to_dict()) == cls()


def test_the_other_parameter_classes_are_params_too():
    from pipeline.detection import DetectionParams, IsolationParams
    from pipeline.grasp import GraspParams
    from pipeline.probe.params import ProbeParams
    from pipeline.probe.planning import PlanParams

    for cls in (DetectionParams, IsolationParams, GraspParams, PlanParams, ProbeParams):
        assert issubclass(cls, Params) and cls.from_dict(cls().to_dict()) == cls(), cls.__name__
    assert ProbeParams.from_dict({"plan": {"max_starts": 5}}).plan == PlanParams(max_starts=5)
