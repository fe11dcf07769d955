"""Data-collection policies: how the gripper moves while a run is collected (docs/simulation.md, "`stucco collect`").

``scripted``
    The scene's hand-made action sequence plus uniform replay noise (``[effects] noise_mm``), drawn once for the
    whole sequence before the run; or, for a scene whose ``[actions] replay`` is ``"guarded"`` (the generated
    scenes), the sequence's waypoints followed in closed loop (:mod:`pipeline.guarded_replay`).
``greedy-walk``
    Start and goal uniform in the scene's square (rejected if closer than the scene's minimum distance or if the
    gripper would touch anything at either); stop within the goal tolerance; after an action that ends in contact
    take ``walk_length`` uniform random actions, otherwise the best of ``n_candidates`` uniform random actions
    towards the goal. Runs failing the discard rule (paper §V-B) are not written unless asked.
``rummage``
    A long run for timing the stages against the number of contacts (docs/evaluation.md, "Scale"): the scene's
    sequence played again and again, the world put back in the state it started in before each repeat (objects
    and gripper; the simulator's saved state), each repeat with its own replay noise, until
    :attr:`RummageParams.contacts` actions have ended in contact, or after ``max_actions`` actions. Restarting
    keeps the objects in reach, which pushing on from where a play ends did not (docs/evaluation.md, "Scale").

A policy is built per run by its registry factory (:class:`pipeline.registry.PolicySpec`) and driven by
:func:`pipeline.collect.collect_run`: :attr:`Policy.gripper_start` opens the world, :meth:`Policy.start` places
the gripper, :meth:`Policy.plan` fixes the number of actions, :meth:`Policy.action` gives each (None stops). A
policy with a second phase in the same world (the active protocol's probes, :mod:`pipeline.probe.mover`) also has
``after(world, rows, summarize, table, seed, root_seed) -> dict``: it appends its own actions to ``rows`` (marked in
the run's ``probe`` column) and returns what the run's metadata records of them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from pipeline.constraints import Constraint, Params, integer
from pipeline.detection import scene_detection, window_force
from pipeline.guarded_replay import GuardedReplay
from pipeline.scenes import Scene
from pipeline.sim import World, action_noise

__all__ = ["Policy", "ScriptedPolicy", "GreedyWalkPolicy", "RummageParams", "RummagePolicy"]


class Policy(Protocol):
    """What :func:`pipeline.collect.collect_run` asks of a policy.

    Attributes
    ----------
    gripper_start : tuple of 2 floats or None
        Where the world places the gripper when it opens (None: the world's default, then :meth:`start`).
    goal : ndarray, shape (2,), or None
        Recorded in the run's metadata (``goal_xy_m``).
    discards : bool
        Whether runs are checked against the discard rule (:func:`pipeline.collect.discard_reason`).
    """

    gripper_start: Any
    goal: np.ndarray | None
    discards: bool

    def start(self, world) -> None:
        """Place the gripper before the initial state is recorded."""

    def plan(self) -> int:
        """Most actions of the run (after :meth:`start`)."""

    def action(self, world, k: int, last_contact: bool) -> np.ndarray | None:
        """Normalised action (2,) in [-1, 1] of step ``k``, or None to stop."""

    # Optional: ``observe(row)``, called with each action's ``sim_run`` row before the next :meth:`action`, for a
    # policy that reads more of it than the contact verdict (the scripted policy's guarded replay: its force).


class ScriptedPolicy:
    """The scene's action sequence with replay noise (``noise_rng``): drawn once before the run and added to each
    action (``[actions] replay = "open"``), or drawn per action as the guarded replay drives the gripper through the
    sequence's waypoints (``"guarded"``, :class:`pipeline.guarded_replay.GuardedReplay`)."""

    discards = False
    goal = None

    def __init__(self, scene: Scene, policy_rng: np.random.Generator, noise_rng: np.random.Generator,
                 max_actions: int | None = None, params: Any = None) -> None:
        self.scene, self.noise_rng, self.max_actions = scene, noise_rng, max_actions
        self.gripper_start = scene.gripper_start
        self.detection = scene_detection(scene)
        self.last_force_n = math.nan  # the force the last action met (N; :meth:`observe`)

    def start(self, world) -> None:
        pass

    def plan(self) -> int:
        seq = np.asarray(self.scene.actions, dtype=np.float64)
        eff = self.scene.effects
        if self.scene.replay == "guarded":
            # Closed loop on the gripper's position; noise drawn per action as it is made.
            self.guarded = GuardedReplay(seq, np.asarray(self.scene.gripper_start, dtype=np.float64),
                                         self.scene.action_scale, self.noise_rng, eff.noise_mm,
                                         stop_force_n=self.scene.stop_force_n or math.inf)
            limit = self.guarded.limit
            return limit if self.max_actions is None else min(limit, self.max_actions)
        if self.max_actions is not None:
            seq = seq[:self.max_actions]
        # Drawn once for the whole sequence before the run, as the authors do.
        self.actions = np.clip(seq + action_noise(self.noise_rng, len(seq), eff.noise_mm, self.scene.action_scale),
                               -1.0, 1.0)
        return len(self.actions)

    def observe(self, row: dict) -> None:
        """Read the action just made (its ``sim_run`` row): the force it met, for the guarded replay's limit."""
        if self.scene.replay == "guarded" and self.scene.stop_force_n:
            self.last_force_n = window_force(row["win_wrench"], self.detection)

    def action(self, world, k: int, last_contact: bool) -> np.ndarray | None:
        if self.scene.replay == "guarded":
            return self.guarded.next(world.gripper_pose()[0][:2], last_contact, self.last_force_n)
        return self.actions[k]


class GreedyWalkPolicy:
    """The training set's greedy random walk towards a random goal (paper §V-B; the scene's ``[walk]`` table)."""

    discards = True
    gripper_start = None

    def __init__(self, scene: Scene, policy_rng: np.random.Generator, noise_rng: np.random.Generator,
                 max_actions: int | None = None, params: Any = None) -> None:
        self.scene, self.rng, self.noise_rng, self.max_actions = scene, policy_rng, noise_rng, max_actions
        self.goal: np.ndarray | None = None
        self.remaining = 0

    def start(self, world) -> None:
        start, self.goal = _sample_start_goal(world, self.rng, self.scene)
        world.place(*start)

    def plan(self) -> int:
        walk = self.scene.walk
        return walk.max_actions if self.max_actions is None else min(self.max_actions, walk.max_actions)

    def action(self, world, k: int, last_contact: bool) -> np.ndarray | None:
        walk, scale = self.scene.walk, self.scene.action_scale
        x = world.gripper_pose()[0][:2]
        if math.hypot(*(x - self.goal)) < walk.goal_tolerance:
            return None
        if last_contact:
            self.remaining = walk.walk_length
        if self.remaining > 0:
            u = self.rng.uniform(-1.0, 1.0, 2)
            self.remaining -= 1
        else:
            cand = self.rng.uniform(-1.0, 1.0, (walk.n_candidates, 2))
            u = cand[np.argmin(np.linalg.norm(x + scale * cand - self.goal, axis=1))]
        return np.clip(u + action_noise(self.noise_rng, 1, self.scene.effects.noise_mm, scale)[0], -1.0, 1.0)


@dataclass(frozen=True)
class RummageParams(Params):
    """Parameters of the ``rummage`` policy; recorded in the run file's metadata (``policy_params``).

    Attributes
    ----------
    contacts : int
        Stop once this many actions have ended in contact (2000).
    actions_per_contact : int
        At most ``contacts`` x this many actions in all (10), so a scene whose script makes no contact still
        stops; ``max_actions`` caps it further.
    """

    contacts: int = 2000
    actions_per_contact: int = 10
    # The upper bounds keep a run's arrays (8 sim steps x 13 floats per action) well within memory.
    constraints: ClassVar[dict[str, Constraint]] = {"contacts": integer(lo=1, hi=1_000_000),
                                                    "actions_per_contact": integer(lo=1, hi=1000)}


class RummagePolicy:
    """The scene's sequence repeated from the scene's starting state until enough actions end in contact."""

    discards = False
    goal = None

    def __init__(self, scene: Scene, policy_rng: np.random.Generator, noise_rng: np.random.Generator,
                 max_actions: int | None = None, params: RummageParams | None = None) -> None:
        self.scene, self.noise_rng, self.max_actions = scene, noise_rng, max_actions
        self.params = params or RummageParams()
        self.gripper_start = scene.gripper_start
        self.script = np.asarray(scene.actions, dtype=np.float64)
        self.n_contact = 0
        self.saved: int | None = None
        self.start_xy = (0.0, 0.0)

    def start(self, world) -> None:
        import pybullet as p  # imported here: the world that calls this has loaded it (pipeline.sim)

        # the settled starting state, restored before every repeat of the script
        self.saved = p.saveState(physicsClientId=world.client)
        x, y = world.gripper_pose()[0][:2]
        self.start_xy = (float(x), float(y))

    def plan(self) -> int:
        cap = self.params.contacts * self.params.actions_per_contact
        return cap if self.max_actions is None else min(cap, self.max_actions)

    def action(self, world, k: int, last_contact: bool) -> np.ndarray | None:
        self.n_contact += bool(last_contact)  # whether action k - 1 ended in contact
        if self.n_contact >= self.params.contacts:
            return None
        i = k % len(self.script)
        if i == 0 and k > 0:
            import pybullet as p  # imported here, as in start

            p.restoreState(stateId=self.saved, physicsClientId=world.client)
            world.place(*self.start_xy, settle=False)  # the gripper's constraint is not part of the saved state
        eff = self.scene.effects
        # noise drawn per action, so a repeat's noise differs from the last one's
        return np.clip(self.script[i] + action_noise(self.noise_rng, 1, eff.noise_mm, self.scene.action_scale)[0],
                       -1.0, 1.0)

    def metadata(self) -> dict:
        """What the run's metadata records of the policy (``policy_params``)."""
        return self.params.to_dict()


def _sample_start_goal(world: World, rng: np.random.Generator, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    walk = scene.walk
    lo, hi = walk.bounds
    for _ in range(10000):
        start = rng.uniform(lo, hi, 2)
        goal = rng.uniform(lo, hi, 2)
        if math.hypot(*(start - goal)) < walk.min_start_goal_distance:
            continue
        if world.touches(*goal) or world.touches(*start):
            continue
        return start, goal
    raise RuntimeError(f"{scene.path}: no collision-free start/goal pair found in 10000 draws")
