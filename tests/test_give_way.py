"""The probing policy's segment giving way at the end of the budget (pipeline/probe/attribution.give_way_at_budget;
docs/retrieval.md, "Active retrieval"): a set that never agreed on contacts bunched on a short stretch gives way
to the next-ranked segment, whose set re-attributes every probe contact."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline import schema
from pipeline.estimators.target_model import target_primitive
from pipeline.geometry import Primitive
from pipeline.probe import attribution as attribution_mod
from pipeline.probe import policy as policy_mod
from pipeline.probe.belief import NO_TARGET, PoseSet, Sensing, TargetChoice
from pipeline.probe.policy import ProbeParams, bunched, give_way_at_budget
from pipeline.scenes import load_scene

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
CAN = Primitive(kind="cylinder", half=(0.04,), centre=np.zeros(2), yaw=0.0)


def _choice(segment):
    return TargetChoice(segment, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))


class _Sensing:
    """Three probe contacts: two 3 cm apart near (0.3, 0) (on a can, say), one at (0, 0.08) on the box's long face
    (the box at the origin, yaw 0)."""
    probe_points = [np.array([0.3, 0.0]), np.array([0.3, 0.03]), np.array([0.0, 0.08])]
    probe_steps = [10, 20, 30]
    probe_forces = [np.full(2, np.nan)] * 3  # no wrench measured: attributed by position alone
    probe_force_n = [np.nan] * 3
    probe_pinned = [False] * 3
    light_n = 0.0
    is_light = Sensing.is_light  # the real rule on this fake's light_n


@pytest.fixture
def sets(monkeypatch):
    """set_from_steps stubbed: segment 1's set sits on the can's contacts (wide: share set by the test), segment
    2's is the box at the origin."""
    state = {"share": 0.3}

    def fake_set(choice, target, sensing, root_seed, run, target_steps):
        poses = np.array([[0.3, 0.1, 0.0], [0.3, 0.1, 0.5]]) if choice.segment == 1 else np.zeros((1, 3))
        return PoseSet(poses=poses, weights=np.full(len(poses), 1.0 / len(poses)), best=0, segment=choice.segment)

    monkeypatch.setattr(attribution_mod, "set_from_steps", fake_set)
    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: state["share"])
    return state


def _set(choice):
    """The current set of ``choice`` (the stubbed set_from_steps of the ``sets`` fixture)."""
    return attribution_mod.set_from_steps(choice, BOX, _Sensing(), 0, "FB/100", [])


def test_a_wide_set_on_bunched_contacts_gives_way_and_the_contacts_are_attributed_afresh(sets):
    choices = [_choice(1), _choice(2)]
    given = give_way_at_budget(choices, choices[0], _set(choices[0]), BOX, _Sensing(), 0, "FB/100", [10, 20],
                               ProbeParams())
    assert given is not None
    choice, mine, others, belief = given
    assert choice.segment == 2 and belief.segment == 2
    assert mine == [30] and others == [10, 20]  # only the contact on the box's face is the new set's


@pytest.mark.parametrize("share, steps, ranked, why", [
    (0.97, [10, 20], [1, 2], "the set agrees"),
    (0.3, [10, 30], [1, 2], "the contacts span the box"),
    (0.3, [10], [1, 2], "one contact is not a stretch"),
    (0.3, [10, 20], [2, 1], "no segment ranked below"),
])
def test_no_giving_way(sets, share, steps, ranked, why):
    sets["share"] = share
    choices = [_choice(s) for s in ranked]
    current = next(c for c in choices if c.segment == 1)
    assert give_way_at_budget(choices, current, _set(current), BOX, _Sensing(), 0, "FB/100", steps,
                              ProbeParams()) is None, why


def test_a_segment_that_resisted_never_gives_way(sets):
    # the same state that gives way above, but segment 1 was chosen because its contacts resisted the pushes
    resisted = TargetChoice(1, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)), True)
    assert give_way_at_budget([resisted, _choice(2)], resisted, _set(resisted), BOX, _Sensing(), 0, "FB/100",
                              [10, 20], ProbeParams()) is None


def test_no_segment_and_a_can_never_give_way(sets):
    assert give_way_at_budget([_choice(1)], NO_TARGET, _set(_choice(1)), BOX, _Sensing(), 0, "FB/100", [10, 20],
                              ProbeParams()) is None
    # A can has no length to span: its contacts are never bunched.
    assert not bunched(np.array([[0.0, 0.0], [0.01, 0.0]]), CAN, ProbeParams())
    assert bunched(np.array([[0.0, 0.0], [0.01, 0.0]]), BOX, ProbeParams())
    assert not bunched(np.array([[0.0, 0.0], [0.15, 0.0]]), BOX, ProbeParams())


@pytest.mark.parametrize("switch_probes", [0, 2])
def test_a_segment_taken_at_the_budgets_end_gets_probes_of_its_own(monkeypatch, switch_probes):
    """The give-way at the end of the budget raises the limit by ``switch_probes`` for the segment taken (here
    planning finds no reachable line, so the run ends flagged for that instead of for the budget); without
    switch probes the policy grasps at once. It gives way once only."""
    table = schema.read_run(Path(__file__).resolve().parents[1] / "data" / "regression" / "TC-000.parquet")
    start = np.array([table.column("ee_start_x_m")[0].as_py(), table.column("ee_start_y_m")[0].as_py()])
    prim = target_primitive(load_scene("TC"))[1]
    calls = {"give_way": 0, "plan": 0}

    def give_way(choices, choice, belief, *a):
        calls["give_way"] += 1
        return choices[-1], [], [], belief

    def plan(*a, **k):
        calls["plan"] += 1
        return None

    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: 0.2)
    monkeypatch.setattr(policy_mod, "give_way_at_budget", give_way)
    monkeypatch.setattr(policy_mod, "choose_probe", plan)

    def no_act(dx, dy):
        raise AssertionError("no probe was planned")

    log = policy_mod.probe_run(no_act, lambda: table, "TC/0", 0, prim, start,
                               ProbeParams(budget=0, switch_probes=switch_probes), scene=load_scene("TC"))
    assert calls["give_way"] == 1 and log.switches == 1 and log.probes == 0
    assert (calls["plan"] > 0) == bool(switch_probes)  # once per limit from the first that reaches (next_probe)
    assert log.flagged == ("no_reachable_probe" if switch_probes else "budget_spent")
    assert len(log.history) == 1  # the decision's state is the taken segment's, not a second entry


def test_a_smaller_budget_stops_where_the_policy_would_have_stopped():
    from pipeline.studies.probe_budget import stop_decision

    # Decision 1 agrees on 3 target contacts, but they are bunched: the policy went on (stop false) until 3.
    history = [{"share": 0.2, "target_steps": [], "stop": False},
               {"share": 0.97, "target_steps": [1, 2, 3], "stop": False},
               {"share": 0.5, "target_steps": [1, 2, 3, 4], "stop": False},
               {"share": 0.99, "target_steps": [1, 2, 3, 4, 5], "stop": True}]
    assert [stop_decision(history, b, 3, 0.95) for b in (0, 1, 2, 4, 8)] == [0, 1, 2, 3, 3]
    # A run file without the verdict: the first agreeing decision with enough contacts.
    old = [{k: v for k, v in h.items() if k != "stop"} for h in history]
    assert [stop_decision(old, b, 3, 0.95) for b in (0, 1, 2, 4, 8)] == [0, 1, 1, 1, 1]


def test_the_largest_budget_is_the_run_itself_but_only_the_budget_it_was_collected_with():
    from pipeline.studies.probe_budget import decision_at

    # Collected with budget 8; the segment gave way at 8 and made 3 probes of its own (decisions 9-11).
    history = [{"share": 0.2, "target_steps": [], "stop": False} for _ in range(12)]
    assert decision_at(history, 8, 8, 3, 0.95) == 11
    assert decision_at(history, 10, 8, 3, 0.95) == 11
    assert decision_at(history, 4, 8, 3, 0.95) == 4  # a smaller budget is a cut, even if it is the largest asked


def test_an_agreeing_set_on_bunched_contacts_at_the_budgets_end_is_flagged_not_stopped(monkeypatch):
    # the set agrees but the target's contacts are bunched: the policy does not stop on it, so the budget's end
    # flags the run (budget spent without a stop) while ``agreed`` records the agreement
    table = schema.read_run(Path(__file__).resolve().parents[1] / "data" / "regression" / "TC-000.parquet")
    start = np.array([table.column("ee_start_x_m")[0].as_py(), table.column("ee_start_y_m")[0].as_py()])
    prim = target_primitive(load_scene("TC"))[1]
    monkeypatch.setattr(attribution_mod, "agreement", lambda *a, **k: 1.0)
    monkeypatch.setattr(policy_mod, "bunched", lambda *a, **k: True)

    def no_act(dx, dy):
        raise AssertionError("no probe")

    log = policy_mod.probe_run(no_act, lambda: table, "TC/0", 0, prim, start,
                               ProbeParams(budget=0, min_target_contacts=0), scene=load_scene("TC"))
    assert log.agreed and log.flagged == "budget_spent" and log.probes == 0


def test_a_budget_larger_than_a_spent_collected_one_is_refused(tmp_path, monkeypatch):
    # a run whose policy spent its budget of 2 says nothing of what a budget of 4 would have done
    from pipeline.collect import output_path
    from pipeline.studies import probe_budget as bench_mod

    path = output_path(tmp_path, "TC", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    info = bench_mod.load_run(Path(__file__).resolve().parents[1] / "data" / "regression" / "TC-000.parquet")
    monkeypatch.setattr(bench_mod, "load_run", lambda p: info)
    spent = {"params": {"probe": {"params": {"budget": 2}, "flagged": "budget_spent",
                                  "history": [{"rows": 40, "share": 0.1, "target_steps": [], "stop": False}] * 3}}}
    monkeypatch.setattr(bench_mod.schema, "read_metadata", lambda p: spent)
    monkeypatch.setattr(bench_mod.schema, "probe_record", lambda p: spent["params"]["probe"])
    monkeypatch.setattr(bench_mod, "check_run_settings", lambda *a, **k: None)  # (a fake run: its budget alone)
    with pytest.raises(ValueError, match="collected with a probe budget of 2, spent"):
        bench_mod._one("TC", 0, tmp_path, (0, 4), 0, ProbeParams(budget=4))


@pytest.mark.parametrize("unsupported", [0, 2])
def test_a_segment_no_probe_contact_is_given_to_gives_way_after_so_many_probes(monkeypatch, unsupported):
    """Probes that each meet another object (here: contacts the attribution gives to other objects) leave the
    segment's set with nothing of the probes on it; after ``unsupported`` probes it gives way to the next-ranked
    segment, and after the last to the no-segment prior (-1), which never gives way. 0: the segment stays."""
    table = schema.read_run(Path(__file__).resolve().parents[1] / "data" / "regression" / "TC-000.parquet")
    start = np.array([table.column("ee_start_x_m")[0].as_py(), table.column("ee_start_y_m")[0].as_py()])
    prim = target_primitive(load_scene("TC"))[1]

    def current_set(choice, target, sensing, root_seed, run, log, previous, params):
        log.other_steps.append(1000 + len(log.other_steps))  # each probe's contact is another object's
        return PoseSet(poses=np.zeros((2, 3)), weights=np.full(2, 0.5), best=0, segment=choice.segment)

    def plan(*a, **k):
        return policy_mod.ProbePlan(path=np.zeros((1, 2)), start=np.zeros(2), direction=np.array([1.0, 0.0]),
                                    predicted=np.full(2, 0.05), gain=1.0, mode="gain")

    observe = Sensing.observe  # the probes act on nothing here: no rows are added after the scripted part's
    monkeypatch.setattr(Sensing, "observe", lambda self, rows: observe(self, rows) if rows.num_rows else None)
    monkeypatch.setattr(policy_mod, "current_set", current_set)
    monkeypatch.setattr(policy_mod, "set_share", lambda *a, **k: 0.2)
    monkeypatch.setattr(policy_mod, "next_probe", plan)
    monkeypatch.setattr(policy_mod, "retrace", lambda act, here, *a: (here, 1, False))
    monkeypatch.setattr(policy_mod, "guarded_move", lambda act, here, *a: (here, 3, True, 0.05))
    monkeypatch.setattr(policy_mod, "return_to_start", lambda *a, **k: 0)
    log = policy_mod.probe_run(lambda dx, dy: {}, lambda: table, "TC/0", 0, prim,
                               start, ProbeParams(budget=8, unsupported=unsupported), scene=load_scene("TC"))
    segments = [h["segment"] for h in log.history]
    assert log.probes == 8 and len(segments) == 9
    if not unsupported:
        assert log.switches == 0 and len(set(segments)) == 1 and segments[0] >= 0
        return
    # a switch every `unsupported` probes while a segment is taken, then the prior keeps the rest
    assert segments[0] >= 0 and segments[-1] == -1 and log.switches == len(set(segments)) - 1 >= 1
    changes = [i for i in range(1, len(segments)) if segments[i] != segments[i - 1]]
    assert all(b - a == unsupported for a, b in zip(changes, changes[1:])) and changes[0] == unsupported
