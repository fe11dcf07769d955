"""Collection policies (pipeline/policies.py) on a stand-in world: known actions, stopping, the walk after contact."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline import registry
from pipeline.policies import GreedyWalkPolicy, ScriptedPolicy
from pipeline.scenes import WalkSpec, load_scene


class FakeWorld:
    """Only what the policies ask of pybullet's world: the gripper's pose, placing it, and collision queries."""

    def __init__(self, at=(0.0, 0.0), touching=()) -> None:
        self.at = np.array([*at, 0.1])
        self.touching = set(touching)

    def gripper_pose(self):
        return self.at.copy(), np.array([0.0, 0.0, 0.0, 1.0])

    def place(self, x, y) -> None:
        self.at = np.array([x, y, 0.1])

    def touches(self, x, y) -> bool:
        return (round(x, 6), round(y, 6)) in self.touching


def _quiet(scene):
    return scene.with_effects(noise_mm=0.0)


def test_scripted_policy_replays_the_scene_actions_cut_at_max_actions():
    scene = _quiet(load_scene("FB"))
    rngs = np.random.default_rng(0), np.random.default_rng(1)
    policy = ScriptedPolicy(scene, *rngs, max_actions=3)
    assert policy.gripper_start == scene.gripper_start and not policy.discards and policy.goal is None
    assert policy.plan() == 3
    for k in range(3):
        np.testing.assert_array_equal(policy.action(FakeWorld(), k, False), np.asarray(scene.actions[k]))


def test_scripted_noise_is_drawn_once_from_the_noise_stream_and_clipped():
    scene = load_scene("FB")
    a = ScriptedPolicy(scene, np.random.default_rng(9), np.random.default_rng(1))
    b = ScriptedPolicy(scene, np.random.default_rng(0), np.random.default_rng(1))  # another policy stream
    n = a.plan()
    assert n == b.plan() == len(scene.actions)
    np.testing.assert_array_equal(a.actions, b.actions)
    assert np.all(np.abs(a.actions) <= 1.0)


def test_the_guarded_replay_gives_a_leg_up_where_the_observed_action_met_the_scenes_force_limit():
    # a guarded sequence of two legs; the policy observes each action's row and ends the first leg after one that
    # met the scene's stop_force_n, not after one that met less, and never without the limit
    seq = ((1.0, 0.0),) * 6 + ((0.0, 1.0),) * 2
    base = dataclasses.replace(_quiet(load_scene("FB")), actions=seq, replay="guarded")
    win = np.zeros((8, 6))
    win[-4:, 0] = 1e3  # in contact (residual far past the threshold) with an in-plane force of 1000 N

    def first_leg(scene, force_scale):
        policy = ScriptedPolicy(scene, np.random.default_rng(0), np.random.default_rng(1))
        policy.plan()
        world, moves = FakeWorld(at=scene.gripper_start), 0
        for k in range(20):
            u = policy.action(world, k, k > 0)
            if u is None or u[1] > 0:
                return moves
            world.place(*(world.at[:2] + u * scene.action_scale))
            policy.observe({"win_wrench": win * force_scale, "in_contact": True})
            moves += 1
        return moves

    assert first_leg(base, 1.0) == 6  # no limit: the whole leg (every action in contact advances fully)
    assert first_leg(dataclasses.replace(base, stop_force_n=10.0), 1e-3) == 6  # 1 N: pushed along
    assert first_leg(dataclasses.replace(base, stop_force_n=10.0), 1.0) == 1  # 1000 N: given up after one


def _walk_scene(**walk):
    scene = _quiet(load_scene("SELECT1"))
    return dataclasses.replace(scene, walk=dataclasses.replace(scene.walk or WalkSpec(), **walk))


def test_greedy_walk_starts_apart_from_its_goal_and_stops_within_tolerance():
    scene = _walk_scene(goal_tolerance=0.05)
    policy = GreedyWalkPolicy(scene, np.random.default_rng(3), np.random.default_rng(4))
    world = FakeWorld()
    policy.start(world)
    start = world.gripper_pose()[0][:2]
    assert np.linalg.norm(start - policy.goal) >= scene.walk.min_start_goal_distance
    assert policy.discards and policy.gripper_start is None
    world.place(*(policy.goal + [0.01, 0.0]))
    assert policy.action(world, 0, False) is None  # at the goal: stop


def test_greedy_walk_heads_for_the_goal_out_of_contact_and_walks_randomly_after_contact():
    scene = _walk_scene(walk_length=2, n_candidates=200)
    policy = GreedyWalkPolicy(scene, np.random.default_rng(5), np.random.default_rng(6))
    world = FakeWorld()
    policy.start(world)
    x = world.gripper_pose()[0][:2]
    u = policy.action(world, 0, False)
    towards = (policy.goal - x) / np.linalg.norm(policy.goal - x)
    assert np.dot(u, towards) > 0.8 * np.linalg.norm(u)  # the best of 200 candidates points at the goal
    policy.action(world, 1, True)  # contact: the next walk_length actions are random
    assert policy.remaining == 1
    policy.action(world, 2, False)
    assert policy.remaining == 0


@pytest.mark.parametrize("name", ["scripted", "greedy-walk"])
def test_registered_policies_build_from_their_spec(name):
    spec = registry.policy(name)
    scene = load_scene("FB" if name == "scripted" else "SELECT1")
    assert all(getattr(scene, key) is not None for key, _ in spec.needs)
    policy = registry.resolve(spec.factory)(scene, np.random.default_rng(0), np.random.default_rng(1), 5,
                                            registry.build_params(spec))
    assert policy.discards == (name == "greedy-walk")
