"""Guarded replay of a scene's action sequence: the sequence read as a path of waypoints, followed in closed loop
on the gripper's own position, each leg given up when an object stops it (docs/scene_generator.md, "Guarded
replay").

The open-loop replay of the paper's tasks (:class:`pipeline.policies.ScriptedPolicy`) adds each action to wherever
the gripper is: a poke stopped by a heavy object still retreats its full commanded length, so a long rummage
creeps back by every blocked centimetre and its later pokes never reach the clutter's far side. A robot under
position control does not drift: it is sent to positions. Here the sequence is cut into legs (runs of equal
consecutive actions); each leg's planned end, from the start plus the sum of the actions before it, is a waypoint
the gripper is driven to, at most one action's length per step. A leg is given up when two consecutive actions
in contact advance less than ``stall_share`` of their commanded length (the gripper is pressing on something it
cannot move), or, where the scene sets a force limit, after an action in contact that met it (what the hand pushes
resists: a heavy object pushed on tips over before it slides), and the next leg is driven to its own planned end, so
a stopped poke's retreat ends on the approach line it started from.

Only the gripper's own position and each action's contact verdict and force are read (what a robot knows); never
an object.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.sim import action_noise

__all__ = ["legs", "GuardedReplay", "STALL_SHARE", "STALL_ACTIONS", "ARRIVED_M"]

#: An action in contact that advances the gripper less than this share of its commanded length is stalled.
STALL_SHARE = 0.5
#: Consecutive stalled actions that give up a leg.
STALL_ACTIONS = 2
#: A waypoint is reached within this distance, metres (the replay noise is 0.5 mm per axis).
ARRIVED_M = 0.002
#: The guarded replay makes at most this many times the sequence's length in actions (a leg pushed back by an
#: object it moves can take longer than planned).
MAX_ACTIONS_FACTOR = 2


def legs(actions: np.ndarray, start: np.ndarray, scale: float) -> np.ndarray:
    """Planned ends (L, 2), metres, of the runs of equal consecutive ``actions`` (N, 2) (normalised) from ``start``
    (2,), metres, with ``scale`` metres per unit action."""
    actions = np.asarray(actions, dtype=np.float64).reshape(-1, 2)
    if len(actions) == 0:
        return np.zeros((0, 2))
    change = np.r_[np.any(actions[1:] != actions[:-1], axis=1), True]
    ends = np.cumsum(actions, axis=0)[change] * scale
    return ends + np.asarray(start, dtype=np.float64)


class GuardedReplay:
    """Drives the gripper through a sequence's waypoints (:func:`legs`); one normalised action per call.

    Parameters
    ----------
    actions : ndarray, shape (N, 2)
        The sequence, normalised.
    start : ndarray, shape (2,), metres
        The gripper base where the sequence starts.
    scale : float, metres per unit action
    noise_rng : numpy.random.Generator
        Replay noise (``noise_mm`` half-width per axis, as the open-loop replay's) of each action, drawn as it is
        made.
    noise_mm : float
    stall_actions : int
        Consecutive stalled actions that give up a leg (:data:`STALL_ACTIONS`).
    stall_share : float
        An action in contact that advances less than this share of its commanded length is stalled
        (:data:`STALL_SHARE`; infinite: every action in contact, so a leg with ``stall_actions`` 1 ends at its
        first contact).
    stop_force_n : float, N
        A leg is also given up after an action in contact that met at least this force: what the hand pushes
        resists, and is pushed no further (infinite: never; the scene's ``[actions] stop_force_n``).
    """

    def __init__(self, actions: np.ndarray, start: np.ndarray, scale: float, noise_rng: np.random.Generator,
                 noise_mm: float, stall_actions: int = STALL_ACTIONS, stall_share: float = STALL_SHARE,
                 stop_force_n: float = math.inf) -> None:
        self.waypoints = legs(actions, start, scale)
        self.scale, self.noise_rng, self.noise_mm = scale, noise_rng, noise_mm
        self.limit = MAX_ACTIONS_FACTOR * len(np.asarray(actions).reshape(-1, 2))
        self.leg = 0
        self.stalls = 0
        self.stall_actions, self.stall_share = int(stall_actions), float(stall_share)
        self.stop_force_n = float(stop_force_n)
        self.given_up: list[int] = []  # legs given up, in order
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # (position before, displacement commanded)

    def next(self, here: np.ndarray, last_contact: bool, last_force_n: float = math.nan) -> np.ndarray | None:
        """The next normalised action (2,) from the gripper's position ``here`` (2,), metres, whether the last
        action ended in contact and the force it met (N; NaN: not measured); None when the path is done."""
        here = np.asarray(here, dtype=np.float64)
        if self._last is not None:
            before, cmd = self._last
            length = math.hypot(cmd[0], cmd[1])
            moved = here - before
            advance = (moved[0] * cmd[0] + moved[1] * cmd[1]) / length if length > 0.0 else 0.0
            self.stalls = self.stalls + 1 if last_contact and advance < self.stall_share * length else 0
            if self.stalls >= self.stall_actions or (last_contact and last_force_n >= self.stop_force_n):
                self.given_up.append(self.leg)
                self.leg += 1
                self.stalls = 0
        while self.leg < len(self.waypoints) and \
                math.hypot(*(self.waypoints[self.leg] - here)) <= ARRIVED_M:
            self.leg += 1
            self.stalls = 0
        if self.leg >= len(self.waypoints):
            return None
        u = (self.waypoints[self.leg] - here) / self.scale
        u = u / max(1.0, float(np.max(np.abs(u))))
        u = np.clip(u + action_noise(self.noise_rng, 1, self.noise_mm, self.scale)[0], -1.0, 1.0)
        self._last = (here, u * self.scale)
        return u
