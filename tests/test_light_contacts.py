"""Light probe contacts (docs/active.md, "Whose contact (attribution)"): for a heavy target, a probe contact whose
action met less than ``ProbeParams.light_contact_n`` is another object's whatever the set says, one the set explained
counts against its segment (``ProbeLog.refuted``), and the policy takes the next-ranked segment after
``light_refutations`` of them; the scripted part's tracked points under ``light_scripted_n`` leave the segments the
target is chosen from (``heavy_choices``)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.geometry import Primitive
from pipeline.probe import attribution as attribution_mod
from pipeline.probe.attribution import light_limit
from pipeline.probe.belief import PoseSet, Sensing, TargetChoice
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.retrieval import _recorded_params

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
CHOICE = TargetChoice(0, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))
ON_LONG_FACE = np.array([0.031, 0.0])  # on the upright box's +x face


class _Sensing:
    """Probe contacts {action: (point, force N)}; no force direction measured (attributed by position)."""

    def __init__(self, contacts, light_n):
        self.probe_steps = list(contacts)
        self.probe_points = [np.asarray(p, dtype=np.float64) for p, _ in contacts.values()]
        self.probe_forces = [np.full(2, np.nan) for _ in contacts]
        self.probe_force_n = [float(f) for _, f in contacts.values()]
        self.probe_pinned = [False] * len(contacts)
        self.light_n = light_n

    is_light = Sensing.is_light  # the real rule on this fake's light_n


@pytest.fixture(autouse=True)
def fits(monkeypatch):
    """set_from_steps stubbed: every set is the upright box at the origin, costing nothing."""

    def fake_set(choice, target, sensing, root_seed, run, target_steps):
        return PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=choice.segment, cost=0.0)

    monkeypatch.setattr(attribution_mod, "set_from_steps", fake_set)


def _upright(segment=0):
    return PoseSet(poses=np.zeros((2, 3)), weights=np.full(2, 0.5), best=0, segment=segment)


def test_the_limit_applies_to_a_heavy_target_only():
    params = ProbeParams(light_contact_n=3.0)
    assert light_limit(params, 5.0, 1.0) == 3.0
    assert light_limit(params, 0.4, 1.0) == 0.0  # a light target gives way like the clutter
    assert light_limit(params, 5.0, None) == 0.0  # the resistance rule off
    assert light_limit(params, float("nan"), 1.0) == 0.0  # mass unknown
    assert light_limit(ProbeParams(light_contact_n=0.0), 5.0, 1.0) == 0.0


@pytest.mark.parametrize("force_n, light", [(0.0, True), (2.99, True), (3.0, False), (25.0, False),
                                             (float("nan"), False), (float("inf"), False)])
def test_a_contact_is_light_below_the_limit_and_never_without_a_force(force_n, light):
    assert _Sensing({}, 3.0).is_light(force_n) is light


@pytest.mark.parametrize("force_n, mine, refuted", [(1.5, False, 1), (12.0, True, 0), (float("nan"), True, 0)])
def test_a_light_contact_the_set_explains_is_another_objects_and_refutes_the_segment(force_n, mine, refuted):
    log = ProbeLog()
    attribution_mod.current_set(CHOICE, BOX, _Sensing({40: (ON_LONG_FACE, force_n)}, 3.0), 0, "GEN/0", log,
                                _upright(), ProbeParams())
    assert (log.target_steps, log.other_steps) == (([40], []) if mine else ([], [40]))
    assert log.refuted == refuted


def test_a_light_contact_the_set_does_not_explain_refutes_nothing():
    log = ProbeLog()
    attribution_mod.current_set(CHOICE, BOX, _Sensing({40: (np.array([0.5, 0.5]), 1.0)}, 3.0), 0, "GEN/0", log,
                                _upright(), ProbeParams())
    assert log.other_steps == [40] and log.refuted == 0


def test_without_the_limit_a_light_contact_is_attributed_by_position():
    log = ProbeLog()
    attribution_mod.current_set(CHOICE, BOX, _Sensing({40: (ON_LONG_FACE, 1.0)}, 0.0), 0, "GEN/0", log, _upright(),
                                ProbeParams())
    assert log.target_steps == [40] and log.refuted == 0


def test_the_no_segment_prior_takes_every_contact_but_a_light_one():
    log = ProbeLog()
    sensing = _Sensing({40: (np.array([0.5, 0.5]), 1.0), 41: (np.array([0.6, 0.5]), 20.0)}, 3.0)
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "GEN/0", log, _upright(segment=-1), ProbeParams())
    assert (log.target_steps, log.other_steps, log.refuted) == ([41], [40], 0)


def test_a_light_contact_given_to_another_object_is_never_tried_again():
    # action 40 went elsewhere at an earlier decision; the set now explains it in every hypothesis, which would
    # make it the target's (tests/test_attribution.py) were it not light
    log = ProbeLog(other_steps=[40])
    previous = PoseSet(poses=np.array([[0.469, 0.5, 0.0], [0.469, 0.501, 0.0]]), weights=np.full(2, 0.5), best=0,
                       segment=0)
    attribution_mod.current_set(CHOICE, BOX, _Sensing({40: (np.array([0.5, 0.5]), 1.0)}, 3.0), 0, "GEN/0", log,
                                previous, ProbeParams(reattribute="fit"))
    assert (log.target_steps, log.other_steps) == ([], [40])


def test_a_run_probed_before_the_rule_is_retrieved_without_it():
    old = {k: v for k, v in ProbeParams().to_dict().items() if k not in ("light_contact_n", "light_refutations")}
    assert (_recorded_params(old).light_contact_n, _recorded_params(old).light_refutations) == (0.0, 0)
    now = ProbeParams().to_dict()
    assert _recorded_params(now).light_contact_n == ProbeParams().light_contact_n
    assert math.isclose(_recorded_params({**now, "light_contact_n": 4.5}).light_contact_n, 4.5)


def test_the_contacts_of_one_action_refute_once():
    # two fingertip pads on the same light object in one action: one refutation, not the two that drop a segment
    log = ProbeLog()
    sensing = _Sensing({}, 3.0)
    sensing.probe_steps = [40, 40, 41]
    sensing.probe_points = [ON_LONG_FACE, ON_LONG_FACE + [0.0, 0.01], ON_LONG_FACE]
    sensing.probe_forces = [np.full(2, np.nan)] * 3
    sensing.probe_force_n, sensing.probe_pinned = [1.0, 1.0, 1.0], [False] * 3
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "REAL/0", log, _upright(), ProbeParams())
    assert log.other_steps == [40, 40, 41] and log.refuted == 2
    log = ProbeLog()
    sensing.probe_steps, sensing.probe_points = [40, 40], sensing.probe_points[:2]
    sensing.probe_forces, sensing.probe_force_n = sensing.probe_forces[:2], [1.0, 1.0]
    attribution_mod.current_set(CHOICE, BOX, sensing, 0, "REAL/0", log, _upright(), ProbeParams())
    assert log.refuted == 1


class _Scripted:
    """The scripted part as heavy_choices reads it: actions' steps and the force (N) each met."""

    def __init__(self, forces):
        self.steps = list(range(len(forces)))
        self.forces = list(forces)
        self.visited = np.zeros((len(forces) + 1, 2))
        self.sdf = None


@pytest.fixture
def ranked(monkeypatch):
    """choose_target stubbed: every segment it is given, in order, with the others' points; the segments seen."""
    seen = []

    def fake_choose(segments, target, ee, sdf, rngs, steps=None, force=None, mass=float("nan")):
        seen.append(segments)
        return [TargetChoice(s.id, s.points, s.steps, np.vstack([t.points for t in segments if t.id != s.id]
                                                                 or [np.zeros((0, 2))]), np.zeros((0, 3)))
                for s in segments]

    monkeypatch.setattr(attribution_mod, "choose_target", fake_choose)
    return seen


def _segments():
    from pipeline.estimators.estimate import Segment
    # segment 0: actions 0 (1 N), 1 (20 N), 2 (no wrench); segment 1: actions 3 and 4, both under 5 N
    return [Segment(0, np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]]), np.array([0, 1, 2])),
            Segment(1, np.array([[1.0, 1.0], [1.1, 1.0]]), np.array([3, 4]))]


def test_light_scripted_points_leave_the_segments_and_become_obstacles(ranked):
    sensing = _Scripted([1.0, 20.0, float("nan"), 4.9, 2.0])
    choices = attribution_mod.heavy_choices(_segments(), BOX, sensing, 0, "GEN/0", ProbeParams(), 5.0)
    assert [c.segment for c in choices] == [0]  # segment 1 met only light forces: it cannot be the target
    np.testing.assert_array_equal(choices[0].steps, [1, 2])  # an action without a wrench is never light
    np.testing.assert_array_equal(choices[0].points, [[0.1, 0.0], [0.2, 0.0]])
    # the other segments' points, light ones too, are obstacles; the segment's own light point is neither
    assert {tuple(p) for p in choices[0].others} == {(1.0, 1.0), (1.1, 1.0)}


@pytest.mark.parametrize("params, mass", [(ProbeParams(light_scripted_n=0.0), 5.0), (ProbeParams(), 0.4),
                                          (ProbeParams(), float("nan"))])
def test_without_the_rule_or_for_a_light_target_the_segments_are_ranked_whole(ranked, params, mass):
    sensing = _Scripted([1.0, 20.0, float("nan"), 4.9, 2.0])
    choices = attribution_mod.heavy_choices(_segments(), BOX, sensing, 0, "GEN/0", params, mass)
    assert [c.segment for c in choices] == [0, 1] and [len(c.points) for c in choices] == [3, 2]


def test_every_segment_light_leaves_no_choice(ranked):
    sensing = _Scripted([1.0, 1.0, 1.0, 1.0, 1.0])
    assert attribution_mod.heavy_choices(_segments(), BOX, sensing, 0, "GEN/0", ProbeParams(), 5.0) == []
    assert attribution_mod.heavy_choices([], BOX, sensing, 0, "GEN/0", ProbeParams(), 5.0) == []


def test_a_run_probed_before_the_scripted_rule_is_retrieved_without_it():
    old = {k: v for k, v in ProbeParams().to_dict().items() if k != "light_scripted_n"}
    assert _recorded_params(old).light_scripted_n == 0.0
    assert _recorded_params(old).light_contact_n == ProbeParams().light_contact_n
    assert _recorded_params(ProbeParams().to_dict()).light_scripted_n == ProbeParams().light_scripted_n
