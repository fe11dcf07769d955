"""Attributing a probe contact to the target or to another object (pipeline/probe/attribution.current_set;
docs/active.md, "Whose contact (attribution)"): none of the set's hypotheses explains it ->
another object's; all of them -> the target's; some -> the target's only if fitting it as the target's costs less
than ``clutter_cost`` more than fitting it as another object's."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.geometry import Primitive
from pipeline.probe import attribution as attribution_mod
from pipeline.probe.belief import PoseSet, Sensing, TargetChoice, explaining
from pipeline.probe.params import ProbeLog, ProbeParams

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
UPRIGHT, TURNED = [0.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2]
ON_LONG_FACE = np.array([0.031, 0.0])  # on the upright box's +x face; inside the turned one (8 cm deep)
CHOICE = TargetChoice(0, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))


class _Sensing:
    """One probe contact at ``point`` (action 40), no force measured (attributed by position)."""

    def __init__(self, point):
        self.probe_points = [np.asarray(point, dtype=np.float64)]
        self.probe_steps = [40]
        self.probe_forces = [np.full(2, np.nan)]
        self.probe_force_n = [np.nan]
        self.light_n = 0.0
        self.probe_pinned = [False]

    is_light = Sensing.is_light  # the real rule on this fake's light_n


@pytest.fixture
def fits(monkeypatch):
    """set_from_steps stubbed: the set costs ``with`` when action 40 is the target's and ``without`` when it is
    another object's; every call is recorded."""
    state = {"with": 1.0, "without": 0.0, "calls": []}

    def fake_set(choice, target, sensing, root_seed, run, target_steps):
        state["calls"].append(tuple(target_steps))
        cost = state["with"] if 40 in target_steps else state["without"]
        return PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=choice.segment, cost=cost)

    monkeypatch.setattr(attribution_mod, "set_from_steps", fake_set)
    return state


def _previous(*poses):
    poses = np.array(poses, dtype=np.float64)
    return PoseSet(poses=poses, weights=np.full(len(poses), 1.0 / len(poses)), best=0, segment=0)


def _attribute(point, previous, params):
    log = ProbeLog()
    attribution_mod.current_set(CHOICE, BOX, _Sensing(point), 0, "FB/100", log, previous, params)
    return log


def test_explaining_says_which_hypotheses_put_their_surface_at_the_contact():
    hit = explaining(BOX, np.array([UPRIGHT, TURNED]), ON_LONG_FACE, 0.025)
    assert hit.tolist() == [True, False]
    assert explaining(BOX, np.zeros((0, 3)), ON_LONG_FACE, 0.025).shape == (0,)


@pytest.mark.parametrize("clutter_cost, mine", [(0.5, False), (2.0, True)])
def test_a_contact_some_hypotheses_explain_is_the_targets_only_if_it_costs_little_more_there(fits, clutter_cost,
                                                                                               mine):
    log = _attribute(ON_LONG_FACE, _previous(UPRIGHT, TURNED), ProbeParams(clutter_cost=clutter_cost))
    assert (log.target_steps, log.other_steps) == (([40], []) if mine else ([], [40]))
    # both fits were made once; the set returned is one of them, not fitted again
    assert sorted(fits["calls"]) == [(), (40,)]


def test_a_contact_every_or_no_hypothesis_explains_needs_no_second_fit(fits):
    params = ProbeParams(clutter_cost=0.0)  # would send every ambiguous contact elsewhere
    log = _attribute(ON_LONG_FACE, _previous(UPRIGHT, [0.0, 0.001, 0.0]), params)
    assert log.target_steps == [40] and fits["calls"] == [(40,)]
    fits["calls"].clear()
    log = _attribute(np.array([0.5, 0.5]), _previous(UPRIGHT, TURNED), params)
    assert log.other_steps == [40] and fits["calls"] == [()]


def test_without_a_fitted_set_every_contact_is_the_targets(fits):
    no_segment = PoseSet(poses=np.array([TURNED]), weights=np.ones(1), best=0, segment=-1)
    log = _attribute(np.array([0.5, 0.5]), no_segment, ProbeParams(clutter_cost=0.0))
    assert log.target_steps == [40]


@pytest.mark.parametrize("mode, mine", [("off", False), ("explained", True), ("fit", True)])
def test_a_contact_once_given_to_another_object_is_tried_again_against_the_later_set(fits, mode, mine):
    # Action 40 went elsewhere against the set of its decision; the set now puts its surface there in every
    # hypothesis: with reattribute it becomes the target's (no second fit needed), without it stays elsewhere.
    log = ProbeLog(other_steps=[40])
    previous = _previous([0.469, 0.5, 0.0], [0.469, 0.501, 0.0])  # both put their +x face at (0.5, 0.5)
    attribution_mod.current_set(CHOICE, BOX, _Sensing(np.array([0.5, 0.5])), 0, "FB/100", log, previous,
                           ProbeParams(reattribute=mode))
    assert (log.target_steps, log.other_steps) == (([40], []) if mine else ([], [40]))


@pytest.mark.parametrize("mode, with_cost, mine", [("explained", 0.1, False), ("fit", 0.1, True), ("fit", 5.0, False)])
def test_a_contact_no_hypothesis_explains_is_tried_by_its_cost_only_with_fit(fits, mode, with_cost, mine):
    # "fit": the cost rule decides even where the set put no surface near it (the set may lie away from it
    # because it counted as another object's); "explained" leaves it where it is.
    fits["with"], fits["without"] = with_cost, 0.0
    log = ProbeLog(other_steps=[40])
    attribution_mod.current_set(CHOICE, BOX, _Sensing(np.array([0.5, 0.5])), 0, "FB/100", log, _previous(UPRIGHT),
                           ProbeParams(reattribute=mode, clutter_cost=0.3))
    assert (log.target_steps, log.other_steps) == (([40], []) if mine else ([], [40]))


class _Contacts:
    """Probe contacts {action: point}, no force measured."""

    def __init__(self, points):
        self.probe_steps = list(points)
        self.probe_points = [np.asarray(p, dtype=np.float64) for p in points.values()]
        self.probe_forces = [np.full(2, np.nan) for _ in points]
        self.probe_force_n = [np.nan for _ in points]
        self.light_n = 0.0
        self.probe_pinned = [False for _ in points]

    is_light = Sensing.is_light  # the real rule on this fake's light_n


def test_a_decision_tries_again_at_most_one_contact_by_a_fit_the_nearest_first(fits):
    # Neither earlier contact is explained; the one nearer the estimate's surface (action 41) is fitted, the
    # other waits for a later decision: one fit beyond the set's own.
    log = ProbeLog(other_steps=[40, 41])
    sensing = _Contacts({40: [0.5, 0.5], 41: [0.1, 0.0]})
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "FB/100", log, _previous(UPRIGHT),
                                ProbeParams(reattribute="fit"))
    assert log.target_steps == [41] and log.other_steps == [40]
    assert sorted(fits["calls"]) == [(), (41,)]


def test_no_contact_is_tried_again_by_a_fit_when_a_new_contact_needed_one(fits):
    log = ProbeLog(other_steps=[40])
    sensing = _Contacts({40: [0.5, 0.5], 42: ON_LONG_FACE})  # 42 is new, and some hypotheses explain it
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "FB/100", log, _previous(UPRIGHT, TURNED),
                           ProbeParams(reattribute="fit", clutter_cost=2.0))
    assert log.target_steps == [42] and log.other_steps == [40]
    assert sorted(fits["calls"]) == [(), (42,)]


def test_a_pinned_contact_is_another_objects_even_where_every_hypothesis_puts_the_target(fits):
    # a carried object pressed against something heavy (ProbeParams.push_through): its contact is not the target's
    # surface, and it refutes nothing
    sensing = _Sensing(ON_LONG_FACE)
    sensing.probe_pinned, sensing.probe_force_n, sensing.light_n = [True], [12.0], 5.0
    log = ProbeLog()
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "FB/100", log, _previous(UPRIGHT), ProbeParams())
    assert log.target_steps == [] and log.other_steps == [40] and log.refuted == 0
