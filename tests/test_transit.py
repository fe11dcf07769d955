"""Transit of the probing policy (pipeline/probe/transit.py, pipeline/probe/moves.py): the graph of visited
positions and the keep-out around the target's estimate (docs/active.md)."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import Primitive
from pipeline.probe.moves import return_to_start
from pipeline.probe.planning import PlanParams
from pipeline.probe.policy import ProbeParams
from pipeline.probe.transit import Keepout, grasp_transit, grasp_via, path_to, transit_graph

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
DOT = np.zeros((1, 2))  # a gripper of one outline point: clearances are plain distances


def _ring():
    """Visited positions: a straight line across the box's place (y = 0, x from -0.2 to 0.2 in 4 cm steps), then
    a detour around it at y = 0.15, ending back at x = -0.2 (the current position, last)."""
    line = np.column_stack([np.arange(-0.2, 0.2001, 0.04), np.zeros(11)])
    detour = np.column_stack([np.arange(0.2, -0.2001, -0.04), np.full(11, 0.15)])
    return np.vstack([line, detour, [[-0.2, 0.0]]])


def test_clearance_is_the_distance_to_the_box_and_negative_inside():
    k = Keepout(BOX, np.zeros(3), DOT, 0.01)
    c = k.clearance(np.array([[0.1, 0.0], [0.0, 0.0], [0.0, 0.2]]))
    assert c == pytest.approx([0.07, -0.03, 0.12])


def test_a_link_whose_ends_are_clear_but_whose_middle_crosses_the_box_is_not_clear():
    k = Keepout(BOX, np.zeros(3), DOT, 0.01)
    lc = k.link_clearance(np.array([[-0.05, 0.0], [-0.05, 0.09]]), np.array([[0.05, 0.0], [0.05, 0.09]]))
    assert lc[0] == pytest.approx(-0.03)  # through the box's middle
    assert lc[1] == pytest.approx(0.01)  # 1 cm beyond its long face
    far = k.link_clearance(np.array([[1.0, 1.0]]), np.array([[1.02, 1.0]]))
    assert np.isinf(far[0])  # too far to matter: not sampled


def test_transit_goes_around_the_target_with_the_keepout_and_straight_without():
    v = _ring()
    dist, pred = transit_graph(v, 0.02)
    # Without a keep-out the far end (x = 0.2, y = 0) is reached straight along the line: 0.4 m.
    assert dist[10] == pytest.approx(0.4)
    dist, pred = transit_graph(v, 0.02, keepout=Keepout(BOX, np.zeros(3), DOT, 0.015))
    # The line's positions and links within 1.5 cm of the box are out (x = -0.04, 0, 0.04): only the detour is left.
    assert np.isinf(dist[4:7]).all()
    assert dist[10] == pytest.approx(0.15 + 0.4 + 0.15)
    path = path_to(pred, v, 10)
    assert np.all(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(path) >= 0.015)


def test_from_within_the_margin_the_gripper_may_move_along_the_target_but_not_closer():
    # Here: 1 cm from the box's short face x = -0.03 (just backed off from a contact); margin 1.5 cm. Both ends
    # are clear of the margin; only the second move comes closer on the way (to 5 mm).
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    along = np.array([[-0.04, 0.095], [-0.04, 0.0]])
    closer = np.array([[-0.035, 0.095], [-0.04, 0.0]])
    assert np.isfinite(transit_graph(along, 0.001, keepout=keepout)[0][0])
    assert np.isinf(transit_graph(closer, 0.001, keepout=keepout)[0][0])
    assert np.isfinite(transit_graph(closer, 0.001)[0][0])


class _World:
    """A stand-in for the collect stage's act: the gripper is a point, the box a wall it cannot enter."""

    def __init__(self, start):
        self.here = np.asarray(start, dtype=np.float64)
        self.moves = []

    def act(self, dx, dy):
        nxt = self.here + [dx, dy]
        contact = Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(nxt[None, :])[0] < 0.0
        if not contact:
            self.here = nxt
        self.moves.append(nxt)
        return {"ee_x_m": float(self.here[0]), "ee_y_m": float(self.here[1]), "in_contact": bool(contact)}


class _Sensing:
    def __init__(self, visited, n_scripted):
        self.visited = visited
        self.n_scripted = n_scripted


def _scripted_around_then_across(end=()):
    """The scripted part went up, around the box's place by y = 0.15, down, and back across y = 0 (the box was
    elsewhere then) to (-0.2, 0), then to the positions ``end``; a probe then left the gripper at (0.21, 0).
    The box now sits at the origin."""
    up = np.array([[-0.2, 0.0], [-0.2, 0.05], [-0.2, 0.1]])
    around = np.column_stack([np.arange(-0.2, 0.2001, 0.04), np.full(11, 0.15)])
    down = np.array([[0.2, 0.1], [0.2, 0.05]])
    across = np.column_stack([np.arange(0.2, -0.2001, -0.04), np.zeros(11)])
    visited = np.vstack([up, around, down, across, np.reshape(end, (-1, 2)), [[0.21, 0.0]]])
    return visited, len(visited) - 2  # the start is not an action


@pytest.mark.parametrize("keepout, touches", [(Keepout(BOX, np.zeros(3), DOT, 0.015), False), (None, True)])
def test_return_to_start_goes_around_the_target_it_was_pushed_into(keepout, touches):
    visited, n_scripted = _scripted_around_then_across()
    world = _World(visited[-1])
    limits = [(np.zeros(len(visited), dtype=bool), keepout)]
    n = return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1)
    assert n > 0
    touched = np.any(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(np.array(world.moves)) < 0.0)
    assert touched == touches
    if not touches:
        assert world.here == pytest.approx([-0.2, 0.0])  # where the scripted part ended, the long way round


def test_probe_transit_keeps_positions_out_and_the_return_keeps_its_clearance_first():
    from pipeline.probe.belief import PoseSet
    from pipeline.probe.moves import reaching, transit_limits

    class S:
        visited = np.array([[0.0, 0.05], [0.0, 0.2], [0.0, 0.3]])  # the first is now inside the box
        avoided = np.zeros(3, dtype=bool)

    belief = PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=0)
    probe = transit_limits(S, BOX, belief, DOT, PlanParams())
    back = transit_limits(S, BOX, belief, DOT, PlanParams(), returning=True)
    assert [(k.margin, k.links) if k else None for _, k in probe] == [(0.0, False), None]
    assert [(round(k.margin, 6), k.links) if k else None for _, k in back] == [
        (0.015, True), (0.01, True), (0.005, True), (0.0, True), (0.0, False), None]
    assert [k for _, k, _ in reaching(S, probe, 0.001)] == [k for _, k in probe]  # the second is still reachable
    touching, keepout = probe[0]
    dist, _ = transit_graph(S.visited, 0.001, touching, keepout)
    assert np.isinf(dist[0]) and np.isfinite(dist[1])


def test_return_to_start_stops_short_of_a_scripted_end_pressed_against_the_target():
    # The scripted part ended 5 mm from the box's short face (it pushed the box there): the return goes to the
    # last scripted position clear of the keep-out instead, (-0.2, 0), and never touches the box.
    visited, n_scripted = _scripted_around_then_across(end=[[-0.1, 0.0], [-0.035, 0.0]])
    world = _World(visited[-1])
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    limits = [(np.zeros(len(visited), dtype=bool), keepout), (np.zeros(len(visited), dtype=bool), None)]
    return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1)
    assert not np.any(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(np.array(world.moves)) < 0.0)
    assert world.here == pytest.approx([-0.1, 0.0])


def test_grasp_transit_moves_diagonally_then_along_one_axis_as_the_script_commands():
    way = grasp_transit(np.zeros(2), np.array([0.09, 0.03]), 0.03)
    assert way == pytest.approx(np.array([[0.0, 0.0], [0.03, 0.03], [0.06, 0.03], [0.09, 0.03]]))
    assert grasp_transit(np.zeros(2), np.array([0.005, 0.0]), 0.03).shape == (1, 2)  # already within reach


def _grasp_from(pre):
    return lambda at: grasp_transit(at, np.asarray(pre, dtype=np.float64), 0.03)


def test_the_return_stops_at_the_nearest_position_whose_grasp_move_keeps_clear_of_the_target():
    # The grasp will approach from -x (pre-grasp point at (-0.25, 0)): from where the probe left the gripper,
    # (0.21, 0), its move would cross the box. Going around the top, (0, 0.15) is the first visited position
    # from which the move passes the box's corner at more than 1.5 cm; the return stops there, short of the
    # scripted part's end at (-0.2, 0).
    visited, n_scripted = _scripted_around_then_across()
    world = _World(visited[-1])
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    limits = [(np.zeros(len(visited), dtype=bool), keepout), (np.zeros(len(visited), dtype=bool), None)]
    n = return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1,
                        grasp_path=_grasp_from([-0.25, 0.0]))
    assert n > 0 and world.here == pytest.approx([0.0, 0.15])
    assert np.min(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(np.array(world.moves))) >= 0.015
    way = grasp_transit(world.here, np.array([-0.25, 0.0]), 0.03)
    assert np.min(keepout.link_clearance(way[:-1], way[1:])) >= 0.015


def test_the_return_stays_put_when_the_grasp_move_from_here_keeps_clear():
    visited, n_scripted = _scripted_around_then_across()
    world = _World(visited[-1])
    limits = [(np.zeros(len(visited), dtype=bool), Keepout(BOX, np.zeros(3), DOT, 0.015))]
    n = return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1,
                        grasp_path=_grasp_from([0.0, -0.25]))  # from (0.21, 0) down-left, below the box
    assert n == 0 and world.moves == []
def test_grasp_start_is_not_bought_with_a_return_through_the_target():
    # Scripted part: (0.2, 0.1) -> (0.21, 0.015) (its end); a probe then left the gripper at (-0.1, 0) and it is now
    # at (0.21, 0), the move between crossing the box's place. The scripted end is reachable with the full 1.5 cm
    # clearance, but no position reachable that way gives a clear grasp move to (-0.25, 0); (-0.1, 0) does, but only
    # through the positions-only keep-out (links not checked), i.e. straight through the box.
    visited = np.array([[0.2, 0.1], [0.21, 0.015], [-0.1, 0.0], [0.21, 0.0]])
    n_scripted = 1
    none = np.zeros(len(visited), dtype=bool)
    limits = [(none, Keepout(BOX, np.zeros(3), DOT, 0.015)), (none, Keepout(BOX, np.zeros(3), DOT, 0.0, links=False)),
              (none, None)]
    pre = np.array([-0.25, 0.0])
    base = _World(visited[-1])
    return_to_start(base.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1)
    assert not np.any(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(np.array(base.moves)) < 0.0)  # without: clean
    world = _World(visited[-1])
    return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1,
                    grasp_path=lambda at: grasp_transit(at, pre, 0.03))
    # a grasp start reachable only through the positions-only keep-out (a move across the box) is not taken
    assert not np.any(Keepout(BOX, np.zeros(3), DOT, 0.0).clearance(np.array(world.moves)) < 0.0)



def test_no_visited_position_gives_a_clear_grasp_move_falls_back_to_the_scripted_end():
    # the pre-grasp point is inside the keep-out, so no start qualifies: the return ends at the scripted end
    visited, n_scripted = _scripted_around_then_across()
    world = _World(visited[-1])
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    limits = [(np.zeros(len(visited), dtype=bool), keepout), (np.zeros(len(visited), dtype=bool), None)]
    n = return_to_start(world.act, _Sensing(visited, n_scripted), ProbeParams(), limits, attempts=1,
                        grasp_path=lambda at: grasp_transit(at, np.array([0.0, 0.09]), 0.03))
    assert n > 0 and np.allclose(world.here, [-0.2, 0.0])


def _crosses(keepout, way) -> bool:
    return bool(np.min(keepout.link_clearance(way[:-1], way[1:])) < keepout.margin)


def test_grasp_via_is_empty_when_the_straight_move_keeps_clear():
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    assert grasp_via(np.array([-0.2, 0.0]), np.array([-0.2, 0.25]), keepout, 0.03).shape == (0, 2)


def test_grasp_via_goes_around_the_target_the_straight_move_would_cross():
    # From the box's right to the pre-grasp point on its left: the straight move crosses the box.
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    start, pre = np.array([0.15, 0.0]), np.array([-0.15, 0.0])
    assert _crosses(keepout, grasp_transit(start, pre, 0.03))
    via = grasp_via(start, pre, keepout, 0.03)
    assert via.shape == (1, 2)
    first = grasp_transit(start, via[0], 0.03)
    second = grasp_transit(first[-1], pre, 0.03)
    assert not _crosses(keepout, first) and not _crosses(keepout, second)


def test_grasp_via_from_against_the_target_first_moves_no_closer():
    # The return ended pressed against the box's long face (the outline 5 mm inside it): every route starts within
    # the margin, so the first action may not go deeper; the rest keeps the margin.
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    start, pre = np.array([0.025, 0.0]), np.array([-0.1, 0.05])
    via = grasp_via(start, pre, keepout, 0.03)
    assert via.shape == (1, 2)
    first = grasp_transit(start, via[0], 0.03)
    lc = keepout.link_clearance(first[:-1], first[1:])
    assert lc[0] >= keepout.clearance(start[None, :])[0] - 1e-12 and np.all(lc[1:] >= 0.015)
    assert not _crosses(keepout, grasp_transit(first[-1], pre, 0.03))


def test_grasp_via_gives_up_when_no_route_keeps_clear():
    # A box so long that every waypoint route from one side to the other crosses it (the waypoints lie within
    # 35 cm of the pre-grasp point): the straight move is kept.
    wall = Primitive(kind="box", half=(0.01, 2.0), centre=np.zeros(2), yaw=0.0)
    keepout = Keepout(wall, np.zeros(3), DOT, 0.015)
    assert grasp_via(np.array([0.1, 0.0]), np.array([-0.1, 0.0]), keepout, 0.03).shape == (0, 2)


def test_the_set_grasp_moves_through_the_waypoint_its_keepout_asks_for(monkeypatch):
    import pipeline.probe.set_grasp as set_grasp
    from pipeline.scenes import load_scene

    seen = {}
    monkeypatch.setattr(set_grasp, "grasp_with", lambda *a: seen.update(via=a[-1]) or "simulated")
    scene = load_scene("FB")
    g = set_grasp.SetGrasp(yaw=0.0, centre=np.zeros(2), advance=4, share=1.0, pregrasp=np.array([-0.15, 0.0]),
                           approach=np.array([1.0, 0.0]))
    keepout = Keepout(BOX, np.zeros(3), DOT, 0.015)
    start = np.array([0.15, 0.0])
    assert set_grasp.simulate_set_grasp(scene, np.zeros((1, 3)), start, g, keepout=keepout) == "simulated"
    assert seen["via"].shape == (1, 2)
    np.testing.assert_array_equal(seen["via"], grasp_via(start, g.pregrasp, keepout, scene.action_scale))
    set_grasp.simulate_set_grasp(scene, np.zeros((1, 3)), start, g)  # no keep-out: the script's straight move
    assert seen["via"] is None


def test_a_transit_that_met_an_object_routes_around_it_afterwards():
    """The straight line of ``_ring`` is the short way to its far end; once a transit met an object in the line's
    middle (where the target was pushed, say), the positions there are left out and the way goes around."""
    from pipeline.probe.belief import Sensing
    from pipeline.probe.moves import BLOCK_RADIUS

    ring = _ring()
    # The current position at the line's start, so the short way to its far end (index 10) is the line itself.
    visited = np.vstack([ring[1:], ring[:1]])
    sensing = Sensing.__new__(Sensing)  # the visited positions only: no tracker is needed here
    sensing.ee = [v for v in visited]
    sensing.touching = [False] * len(visited)
    sensing.blocked = [False] * len(visited)
    far = 9  # (0.2, 0) in the shifted order
    before, _ = transit_graph(sensing.visited, 0.05, sensing.avoided)
    sensing.block_near(np.array([0.0, 0.0]), BLOCK_RADIUS)
    blocked = sensing.avoided
    assert blocked.sum() == 1 and np.allclose(sensing.visited[blocked], [[0.0, 0.0]])
    assert not any(sensing.touching)  # kept apart from the positions a probe reached in contact
    after, pred = transit_graph(sensing.visited, 0.05, blocked)
    assert before[far] == pytest.approx(0.4)
    assert after[far] > 0.4 + 0.25  # around through y = 0.15
    assert not np.any(np.all(np.isclose(path_to(pred, sensing.visited, far), [0.0, 0.0]), axis=1))
    assert not blocked[-1]  # the current position is never left out


def test_consecutive_positions_close_together_count_their_distance_once():
    line = np.column_stack([np.arange(0.0, 0.1001, 0.01), np.zeros(11)])[::-1]  # current position (0, 0) last
    dist, _ = transit_graph(line, 0.02)
    assert dist[0] == pytest.approx(0.1)  # not 0.2: each 1 cm link is both consecutive and within the radius


class _Probing:
    """The sensing the planner reads: visited positions (the box's place is clear of them), no probe contact."""

    visited = np.array([[0.0, 0.2], [0.0, 0.3], [0.0, 0.4]])
    touching = [False, False, False]
    blocked = [False, False, False]
    avoided = np.zeros(3, dtype=bool)
    probe_points: list = []
    probe_steps: list = []


@pytest.mark.parametrize("plans, expected", [
    ({"keepout": "strict", "free": "lax"}, ("strict", [True])),
    ({"keepout": None, "free": "lax"}, ("lax", [True, False])),
    ({"keepout": None, "free": None}, (None, [True, False])),
])
def test_a_keepout_that_leaves_no_probe_gives_way_to_the_next_limit(monkeypatch, plans, expected):
    # The planner under the keep-out around the estimate finds no line (a gripper walled in by a wrong estimate):
    # the policy plans again without it rather than stop probing with the set wide.
    from pipeline.probe import policy as policy_mod
    from pipeline.probe.belief import PoseSet
    from pipeline.probe.params import ProbeLog

    kept = []

    def plan(*args, touching, keepout, graph=None):
        assert len(touching) == len(_Probing.visited)
        kept.append(keepout is not None)
        return plans["keepout" if keepout is not None else "free"]

    monkeypatch.setattr(policy_mod, "choose_probe", plan)
    belief = PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=0)
    got = policy_mod.next_probe(BOX, belief, _Probing, DOT, np.zeros((0, 2)), ProbeLog(), False, ProbeParams())
    assert (got, kept) == expected


class _WalledIn(_Probing):
    """A transit met an object near the positions behind the gripper: they are blocked, none reached by a probe."""

    blocked = [True, True, False]
    avoided = np.array([True, True, False])


@pytest.mark.parametrize("sensing, planned_with", [
    # nothing blocked: under the keep-out, then without it; no last resort
    (_Probing, [([False] * 3, True), ([False] * 3, False)]),
    # walled in: no limit reaches another position, so the laxest alone; then the blocked positions allowed
    (_WalledIn, [([True, True, False], False), ([False] * 3, False)]),
])
def test_a_gripper_walled_in_by_a_transits_contact_probes_as_a_last_resort(monkeypatch, sensing, planned_with):
    # Every limit leaves out the blocked positions, so no probe can be planned; the last resort leaves out only
    # the positions a probe reached in contact (none here) and has no keep-out.
    from pipeline.probe import policy as policy_mod
    from pipeline.probe.belief import PoseSet
    from pipeline.probe.params import ProbeLog

    seen = []

    def plan(*args, touching, keepout=None, graph=None):
        seen.append((np.asarray(touching).tolist(), keepout is not None))
        return "line" if not np.any(touching) and keepout is None and any(sensing.blocked) else None

    monkeypatch.setattr(policy_mod, "choose_probe", plan)
    belief = PoseSet(poses=np.zeros((1, 3)), weights=np.ones(1), best=0, segment=0)
    got = policy_mod.next_probe(BOX, belief, sensing, DOT, np.zeros((0, 2)), ProbeLog(), False, ProbeParams())
    assert seen == planned_with
    assert got == ("line" if sensing is _WalledIn else None)


def test_reaching_is_the_last_limit_alone_when_no_limit_reaches():
    from pipeline.probe.moves import reaching

    class Alone:
        visited = np.array([[0.0, 0.2]])  # only the current position: nowhere to go under any limit

    limits = [(np.zeros(1, dtype=bool), Keepout(BOX, np.zeros(3), DOT, 0.0, links=False)),
              (np.zeros(1, dtype=bool), None)]
    assert [k for _, k, _ in reaching(Alone, limits, 0.02)] == [None]
