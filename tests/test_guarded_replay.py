"""The guarded replay of a scripted sequence (pipeline.guarded_replay): waypoints from the sequence, followed in
closed loop on the gripper's position, a leg given up when an object stops or is pushed along it."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipeline.guarded_replay import ARRIVED_M, STALL_ACTIONS, GuardedReplay, legs

SCALE = 0.03


def _replay(actions, start=(0.0, 0.0), noise_mm=0.0, seed=0):
    return GuardedReplay(np.asarray(actions, dtype=np.float64), np.asarray(start), SCALE,
                         np.random.default_rng(seed), noise_mm)


def _drive(replay, here, blocked=lambda here, u: False, limit=200):
    """Apply each action exactly (or not at all where ``blocked``: the gripper stays, in contact); the positions."""
    here = np.asarray(here, dtype=np.float64)
    trail, contact = [here.copy()], False
    for _ in range(limit):
        u = replay.next(here, contact)
        if u is None:
            return np.array(trail)
        contact = blocked(here, u)
        if not contact:
            here = here + u * SCALE
        trail.append(here.copy())
    raise AssertionError("the replay did not end")


def test_legs_are_the_planned_ends_of_runs_of_equal_actions():
    actions = [[1.0, 0.0]] * 3 + [[0.0, -0.5]] * 2 + [[-1.0, 0.0]] * 3
    ends = legs(actions, np.array([0.1, 0.2]), SCALE)
    assert ends == pytest.approx(np.array([[0.19, 0.2], [0.19, 0.17], [0.1, 0.17]]))
    assert legs([], np.zeros(2), SCALE).shape == (0, 2)


def test_an_unobstructed_replay_reaches_every_waypoint_in_the_sequences_own_steps():
    actions = [[1.0, 0.0]] * 4 + [[0.0, 1.0]] * 2 + [[-1.0, 0.0]] * 4
    trail = _drive(_replay(actions), (0.0, 0.0))
    assert len(trail) == len(actions) + 1
    assert trail[-1] == pytest.approx([0.0, 0.06], abs=1e-12)
    planned = np.cumsum(np.asarray(actions) * SCALE, axis=0)
    assert trail[1:] == pytest.approx(planned, abs=1e-12)


def test_a_stopped_poke_is_given_up_and_its_retreat_ends_where_planned():
    # a poke of 8 actions along +x blocked from x = 0.1 on, then the retreat: the open-loop replay would end
    # 0.14 m behind the start; the guarded one ends on it
    actions = [[1.0, 0.0]] * 8 + [[-1.0, 0.0]] * 8
    replay = _replay(actions)
    trail = _drive(replay, (0.0, 0.0), blocked=lambda here, u: here[0] + u[0] * SCALE > 0.1 + 1e-9)
    assert trail[-1] == pytest.approx([0.0, 0.0], abs=ARRIVED_M)
    assert trail[:, 0].max() <= 0.1 + 1e-9
    assert replay.given_up == [0]
    assert len(trail) - 1 <= 8 + STALL_ACTIONS + 4  # no pressing on beyond the stall


def test_pushing_an_object_along_does_not_give_the_leg_up():
    # the gripper advances (it pushes something light) with every action in contact from x = 0.06 on: it goes on to
    # the waypoint, then back to the start
    actions = [[1.0, 0.0]] * 10 + [[-1.0, 0.0]] * 10
    replay = _replay(actions)
    here, contact, deepest = np.zeros(2), False, 0.0
    while (u := replay.next(here, contact)) is not None:
        here = here + u * SCALE
        contact = here[0] > 0.06 + 1e-9
        deepest = max(deepest, here[0])
    assert deepest == pytest.approx(0.3) and replay.given_up == []
    assert here == pytest.approx([0.0, 0.0], abs=ARRIVED_M)


def test_noise_is_drawn_per_action_from_the_noise_stream_and_stays_in_bounds():
    actions = [[1.0, 0.0]] * 5 + [[-1.0, 0.0]] * 5
    first, second = _replay(actions, noise_mm=0.5, seed=3), _replay(actions, noise_mm=0.5, seed=3)
    a = np.array([first.next(np.zeros(2), False) for _ in range(5)])
    b = np.array([second.next(np.zeros(2), False) for _ in range(5)])
    assert np.array_equal(a, b) and np.all(np.abs(a) <= 1.0)
    assert not np.array_equal(a[0], a[1])  # a draw per action, not one for the run


def test_the_replay_makes_at_most_twice_the_sequences_actions():
    actions = [[1.0, 0.0]] * 5
    replay = _replay(actions)
    # never arriving (the gripper slides back each time) and never in contact: the policy's plan caps the run
    assert replay.limit == 2 * len(actions)


def test_the_replay_key_is_read_and_a_bad_one_refused_in_one_line(tmp_path):
    from pipeline.scenes import SceneError, load_scene

    text = Path(load_scene("FB").path).read_text()
    assert load_scene("FB").replay == "open"
    good = tmp_path / "FB.toml"
    good.write_text(text.replace("[actions]\n", '[actions]\nreplay = "guarded"\n', 1))
    assert load_scene(good).replay == "guarded"
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("[actions]\n", '[actions]\nreplay = "fast"\n', 1))
    with pytest.raises(SceneError, match="replay") as info:
        load_scene(bad)
    assert str(bad) in str(info.value) and "\n" not in str(info.value)


def test_a_guarded_scene_collects_with_the_scripted_policy_and_ends_where_planned(tmp_path):
    # moves away from FB's clutter and sideways, replayed in closed loop: the same command gives the same run, the
    # noise drawn per action; the gripper ends within a millimetre of the sequence's planned end
    from pipeline.collect import collect_run
    from pipeline.scenes import load_scene

    text = Path(load_scene("FB").path).read_text().replace("[actions]\n", '[actions]\nreplay = "guarded"\n', 1)
    path = tmp_path / "FB.toml"
    path.write_text(text)
    scene = load_scene(path)
    short = replace(scene, actions=((-1.0, 0.0),) * 4 + ((0.0, 0.5),) * 6)
    a, _, _ = collect_run(short, 0, policy="scripted")
    b, _, _ = collect_run(short, 0, policy="scripted")
    cols = ["ee_x_m", "ee_y_m", "cmd_ux", "cmd_uy", "in_contact"]
    assert a.select(cols).equals(b.select(cols))
    assert a.num_rows == 4 + 3  # each step as long as one full action: 0.09 m sideways in 3, not the 6 half actions
    planned = np.asarray(scene.gripper_start) + np.sum(np.asarray(short.actions), axis=0) * short.action_scale
    end = np.array([a.column("ee_x_m")[-1].as_py(), a.column("ee_y_m")[-1].as_py()])
    assert np.hypot(*(end - planned)) < 0.002


def test_touch_mode_gives_a_leg_up_at_its_first_contact_even_when_the_object_gives_way():
    # the object is met at x > 0.05 and gives way (the gripper still advances): the guarded rule pushes it along the
    # whole leg; with stall_actions 1 and an infinite stall share the leg ends at the first action in contact
    import math

    actions = [[1.0, 0.0]] * 6 + [[-1.0, 0.0]] * 6
    touch = GuardedReplay(np.asarray(actions), np.zeros(2), SCALE, np.random.default_rng(0), 0.0,
                          stall_actions=1, stall_share=math.inf)
    trail = _drive(touch, (0.0, 0.0), blocked=lambda here, u: False)
    assert trail[:, 0].max() == pytest.approx(0.18)  # nothing in contact: the whole poke
    touch = GuardedReplay(np.asarray(actions), np.zeros(2), SCALE, np.random.default_rng(0), 0.0,
                          stall_actions=1, stall_share=math.inf)
    here, contact, xs = np.zeros(2), False, []
    for _ in range(40):
        u = touch.next(here, contact)
        if u is None:
            break
        here = here + u * SCALE  # the object gives way: every action advances in full
        contact = here[0] > 0.05 + 1e-9
        xs.append(here[0])
    assert max(xs) == pytest.approx(0.06) and touch.given_up == [0]
    assert here == pytest.approx([0.0, 0.0], abs=ARRIVED_M)


@pytest.mark.parametrize("stall_actions", [1, 2, 3])
def test_stall_actions_sets_how_many_stalled_actions_give_a_leg_up(stall_actions):
    # a wall at x = 0.1 stops the poke: the leg is given up after exactly stall_actions actions in contact
    actions = [[1.0, 0.0]] * 8 + [[-1.0, 0.0]] * 8
    replay = GuardedReplay(np.asarray(actions), np.zeros(2), SCALE, np.random.default_rng(0), 0.0,
                           stall_actions=stall_actions)
    hits = []

    def blocked(here, u):
        hits.append(here[0] + u[0] * SCALE > 0.1 + 1e-9)
        return hits[-1]

    trail = _drive(replay, (0.0, 0.0), blocked=blocked)
    assert replay.given_up == [0] and trail[:, 0].max() <= 0.1 + 1e-9
    assert sum(hits) == stall_actions


def test_a_leg_is_given_up_after_an_action_that_met_the_force_limit():
    # a poke along +x into something that gives way (the gripper advances in contact): without a force limit the
    # leg goes on to its end; with one, the first action in contact that met it ends the leg
    actions = [[1.0, 0.0]] * 8 + [[0.0, 1.0]] * 2

    def drive(replay, force_n):
        here, contact, force, trail = np.zeros(2), False, np.nan, []
        while (u := replay.next(here, contact, force)) is not None:
            here = here + u * SCALE
            contact = here[0] > 0.1 and here[1] < 0.005  # an object along the first leg only
            force = force_n if contact else np.nan
            trail.append(here.copy())
        return np.array(trail)

    def replay(**kw):
        return GuardedReplay(np.asarray(actions), np.zeros(2), SCALE, np.random.default_rng(0), 0.0, **kw)

    free = replay()
    assert drive(free, 20.0)[:, 0].max() == pytest.approx(0.24) and free.given_up == []
    light = replay(stop_force_n=10.0)
    assert drive(light, 3.0)[:, 0].max() == pytest.approx(0.24) and light.given_up == []
    heavy = replay(stop_force_n=10.0)
    trail = drive(heavy, 20.0)
    assert heavy.given_up == [0] and trail[trail[:, 1] < 0.005, 0].max() == pytest.approx(0.12)
    assert trail[-1] == pytest.approx([0.24, 0.06])  # the next leg is driven to its own planned end
