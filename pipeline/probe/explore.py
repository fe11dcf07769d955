"""The ``explore`` collection policy: no action list. From the scene's start, a guarded search of the target region,
then the active protocol's probes until the target's pose is known, within one action budget (docs/active.md,
"Exploring without an action list").

What it is told is what a user knows: where the gripper starts, the target's shape and mass (the scene's target
object) and the rectangle the target lies in (the scene's ``[target_region]``), besides the static walls. The
search pokes the region from the start's side (by default; or from every side the walls leave open, the generated
scenes' rummage: :func:`pipeline.scenes.coverage.coverage_passes`, made here from the region and the start, never
read from the scene's action list), each leg followed in closed loop and given up when an object stops the hand
(:class:`pipeline.guarded_replay.GuardedReplay`); then the probing
loop of :mod:`pipeline.probe.policy` takes the search as what was sensed before it, plans each probe by its expected
information about the target's pose and switches segment when the probes say the one taken is not the target.
The search is the run's rows before the first probe (the ``probe`` column marks the probes); the run's metadata
records it under ``probe.search``.

The search does not stop early when a segment's set agrees: on the training scenes the set of the segment ranked
first agrees on another object long before the target is first touched (docs/experiments/explore.md).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pipeline.constraints import Constraint, integer, number, rule
from pipeline.guarded_replay import GuardedReplay
from pipeline.probe.params import ProbeLog, ProbeParams
from pipeline.probe.policy import recorder, run_policy, run_record
from pipeline.scenes import SceneError, declared_region
from pipeline.scenes.coverage import DEFAULT_LANE_SPACING_M, SIDES, coverage_passes
from pipeline.scenes.footprint import wall_outline

__all__ = ["ExploreParams", "ExplorePolicy", "search_actions", "region_reachable", "BUDGET_SPENT",
           "REGION_UNREACHABLE"]

#: The run's flag (``probe.flagged``) when the action budget ends it before the set agrees.
BUDGET_SPENT = "budget_spent"
#: ... when no point of the target region lies outside the walls: the run ends at once.
REGION_UNREACHABLE = "region_unreachable"
#: Points per axis of the grid on which the region's reachability is checked.
_REACH_GRID = 9


@dataclass(frozen=True)
class ExploreParams(ProbeParams):
    """Parameters of the ``explore`` policy: the probing policy's (:class:`~pipeline.probe.params.ProbeParams`)
    and the search's; serialised into the run file's metadata.

    Attributes
    ----------
    action_budget : int
        Most actions of the run, search and probes together (2000; 0: the run ends at once, ``budget_spent``).
        The probes get what the search leaves, checked before each probe; the return after the last probe is
        not counted.
    lane_spacing : float, metres
        Largest lateral distance between two of the search's pokes (0.2: the hand's width).
    search_sides : tuple of str
        The sides the search pokes from, among :data:`pipeline.scenes.coverage.SIDES` (``("front",)``: the
        start's side; every side grasped fewer of the training runs, docs/experiments/explore.md).
    search_stop : str
        When a leg of the search is given up: ``stall``, after ``stall_actions`` actions in contact that advance
        less than half their length (the guarded replay's rule: objects that give way are pushed along the leg);
        ``touch``, at its first action in contact.
    stall_actions : int
        Consecutive stalled actions that give a leg up under ``stall`` (1: the hand pushes what gives way and
        turns back at the first object that does not; the guarded replay's 2 grasped fewer of the training runs,
        docs/experiments/explore.md).
    """

    action_budget: int = 2000
    lane_spacing: float = DEFAULT_LANE_SPACING_M
    search_sides: tuple = ("front",)
    search_stop: str = "stall"
    stall_actions: int = 1

    constraints: ClassVar[dict[str, Constraint]] = {**ProbeParams.constraints,
                                                    "action_budget": integer(0, 100_000),
                                                    "lane_spacing": number(0.02, 1.0),
                                                    "stall_actions": integer(1, 100),
                                                    "search_sides": rule(f"a non-empty tuple of {', '.join(SIDES)}",
                                                                         lambda v: bool(v) and set(v) <= set(SIDES)),
                                                    "search_stop": rule("stall or touch",
                                                                        lambda v: v in ("stall", "touch"))}


def region_reachable(region, walls) -> bool:
    """Whether some point of ``region`` ((x_min, y_min), (x_max, y_max), metres), on a 9 x 9 grid, lies outside
    every wall of ``walls`` (:class:`pipeline.scenes.WallSpec`)."""
    (x0, y0), (x1, y1) = region
    gx, gy = np.meshgrid(np.linspace(x0, x1, _REACH_GRID), np.linspace(y0, y1, _REACH_GRID))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    free = np.ones(len(pts), dtype=bool)
    for w in walls:
        c, s = math.cos(w.yaw), math.sin(w.yaw)
        d = pts - np.asarray(w.position, dtype=np.float64)
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
        free &= ~np.all(np.abs(local) <= np.asarray(w.size[:2], dtype=np.float64) / 2.0, axis=1)
    return bool(free.any())


def search_actions(region, start, walls, scale: float, lane_spacing: float, sides: tuple = SIDES) -> np.ndarray:
    """The search's path as normalised actions (N, 2): pokes into ``region`` from ``start`` (2,), metres, from each
    of ``sides`` (:data:`pipeline.scenes.coverage.SIDES`) where the hand keeps clear of ``walls`` (WallSpec),
    ``scale`` metres per unit action."""
    seq = coverage_passes(region, tuple(map(float, start)), scale_m=scale, lane_spacing_m=lane_spacing,
                          sides=tuple(sides), walls=[wall_outline(w) for w in walls])
    return np.asarray(seq, dtype=np.float64).reshape(-1, 2)


class ExplorePolicy:
    """No action list: the guarded search of the target region, then probes (:class:`ExploreParams`); see the
    module docstring. Driven by :func:`pipeline.collect.collect_run` like every policy: it makes no action of its
    own there (:meth:`plan` is 0) and acts in :meth:`after`; :attr:`probes_from` is then the number of rows before
    the first probe (the search's)."""

    discards = False
    goal = None

    def __init__(self, scene, policy_rng: np.random.Generator, noise_rng: np.random.Generator,
                 max_actions: int | None = None, params: ExploreParams | None = None) -> None:
        self.scene, self.noise_rng = scene, noise_rng
        self.params = params if params is not None else ExploreParams()
        self.region = declared_region(scene)
        if self.region is None:
            raise SceneError(f"{scene.path}: key 'target_region': the explore policy needs the rectangle where the "
                             "target lies; the scene declares none")
        self.budget = self.params.action_budget if max_actions is None else min(self.params.action_budget,
                                                                                int(max_actions))
        self.gripper_start = scene.gripper_start
        #: The run's wall times, kept out of the run file: ``decision_s`` (s, a list), ``prior_s`` (s).
        self.times: dict | None = None
        self.probes_from = 0

    def start(self, world) -> None:
        pass

    def plan(self) -> int:
        return 0

    def action(self, world, k: int, last_contact: bool) -> np.ndarray | None:
        return None

    def after(self, world, rows: list, summarize: Callable, table: Callable, seed: int, root_seed: int
              ) -> dict[str, Any]:
        """Search, then probe, in ``world`` (appending every action to ``rows``); what the run's metadata records
        under ``probe`` (no wall time: the same command writes the same file)."""
        scene, params, scale = self.scene, self.params, self.scene.action_scale
        start = np.asarray(world.gripper_pose()[0][:2], dtype=np.float64)
        reachable = region_reachable(self.region, scene.walls)
        search = {"region_m": [list(self.region[0]), list(self.region[1])], "planned_actions": 0, "actions": 0,
                  "legs": 0, "legs_given_up": [], "completed": False}
        if reachable:
            path = search_actions(self.region, start, scene.walls, scale, params.lane_spacing, params.search_sides)
            touch = params.search_stop == "touch"
            replay = GuardedReplay(path, start, scale, self.noise_rng, scene.effects.noise_mm,
                                   **({"stall_actions": 1, "stall_share": math.inf} if touch else
                                      {"stall_actions": params.stall_actions}))
            act = recorder(world, scale, rows, summarize)
            last = False
            while len(rows) < min(self.budget, replay.limit):
                u = replay.next(world.gripper_pose()[0][:2], last)
                if u is None:
                    break
                last = bool(act(float(u[0] * scale), float(u[1] * scale))["in_contact"])
            search.update(planned_actions=len(path), actions=len(rows), legs=len(replay.waypoints),
                          legs_given_up=list(replay.given_up), completed=replay.leg >= len(replay.waypoints))
        self.probes_from = len(rows)
        if not reachable or not rows:
            # Nothing to probe from: the region is walled off, or the budget allows no action.
            meta = run_record(params, ProbeLog(flagged=BUDGET_SPENT if reachable else REGION_UNREACHABLE))
            self.times = {"decision_s": [], "prior_s": 0.0}
        else:
            meta, self.times = run_policy(world, scene, seed, root_seed, rows, summarize, table, params,
                                          action_limit=self.budget - len(rows))
        meta["search"] = search
        return meta
