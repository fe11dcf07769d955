"""Attributing a probe contact to the target or to another object (pipeline/probe/policy.current_set;
docs/retrieval.md, "Attributing a contact some hypotheses explain"): none of the set's hypotheses explains it ->
another object's; all of them -> the target's; some -> the target's only if fitting it as the target's costs less
than ``clutter_cost`` more than fitting it as another object's."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.geometry import Primitive
from pipeline.probe import policy as policy_mod
from pipeline.probe.belief import PoseSet, TargetChoice, explaining
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


@pytest.fixture
def fits(monkeypatch):
    """set_from_steps stubbed: the set costs ``with`` when action 40 is the target's and ``without`` when it is
    another object's; every call is recorded."""
    state = {"with": 1.0, "without": 0.0, "calls": []}

    def fake_set(choice, target, sensing, root_seed, run, target_steps):
        state["calls"].append(tuple(target_steps))
        cost = state["with"] if 40 in target_steps else state["without"]
        return PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=choice.segment, cost=cost)

    monkeypatch.setattr(policy_mod, "set_from_steps", fake_set)
    return state


def _previous(*poses):
    poses = np.array(poses, dtype=np.float64)
    return PoseSet(poses=poses, weights=np.full(len(poses), 1.0 / len(poses)), best=0, segment=0)


def _attribute(point, previous, params):
    log = ProbeLog()
    policy_mod.current_set(CHOICE, BOX, _Sensing(point), 0, "FB/100", log, previous, params)
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
