"""What a probe that pushes light clutter aside senses (``ProbeParams.push_through``; docs/active.md, "Pushing light
clutter aside"): which of its contacts are the carried object's, and whether the contact that stops the push is
that object pinned against something heavy. A pure rule on one action at a time, read from what the robot senses
(the action's commanded direction, its contact force and its isolated contacts), so the policy and the later
stages that recompute its belief from the run file agree."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pyarrow as pa

__all__ = ["Carried", "CarryVerdict", "carry_verdict", "Pushes", "commands"]

#: Two actions push the same way when their directions' cosine exceeds this.
SAME_WAY = 0.999


class Carried(NamedTuple):
    """The light contact of the last action: its unit direction (2,) and its contacts' offsets from the gripper
    (K, 2), metres."""

    direction: np.ndarray
    offsets: np.ndarray


class CarryVerdict(NamedTuple):
    """One probe action's contact: ``carried`` (a light contact after a light contact of the same push: the object
    moves on, its contact is no probe contact), ``pinned`` (a contact that is not light, stopping a push, where the
    carried object touched the gripper), and what the next action is judged against (None: no light contact)."""

    carried: bool
    pinned: bool
    last: Carried | None


def carry_verdict(last: Carried | None, light: bool, command: np.ndarray, offsets: np.ndarray,
                  pinned_within: float) -> CarryVerdict:
    """Judge one probe action in contact.

    Parameters
    ----------
    last : Carried or None
        The previous action's light contact (None: it had none, or was no probe action in contact).
    light : bool
        Whether this action's contact met less than the light limit.
    command : ndarray, shape (2,), metres
        The action's commanded move.
    offsets : ndarray, shape (K, 2), metres
        Its isolated contacts minus the gripper's position.
    pinned_within : float, metres
        A stopping contact within this distance of one of ``last``'s offsets is the carried object's.
    """
    norm = math.hypot(float(command[0]), float(command[1]))
    way = np.asarray(command, dtype=np.float64) / norm if norm > 0 else np.zeros(2)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
    pushed = last is not None and float(last.direction[0] * way[0] + last.direction[1] * way[1]) > SAME_WAY
    pinned = bool(pushed and not light and len(offsets) and len(last.offsets) and np.min(
        np.linalg.norm(offsets[:, None, :] - last.offsets[None, :, :], axis=-1)) < pinned_within)
    return CarryVerdict(pushed and light, pinned, Carried(way, offsets) if light else None)


class Pushes:
    """The probes' pushes as :class:`pipeline.probe.belief.Sensing` observes them, one action at a time: off (every
    probe contact a plain one) until ``on`` is set (``ProbeParams.push_through``), with ``within`` its
    ``pinned_within`` (metres)."""

    def __init__(self) -> None:
        self.on, self.within = False, 0.0
        self.last: Carried | None = None  # the previous action's light contact

    def judge(self, probe_contact: bool, light: bool, command: np.ndarray, offsets: np.ndarray) -> tuple[bool, bool]:
        """(carried, pinned) of the next action (:func:`carry_verdict`); ``probe_contact``: it is a probe action
        detected in contact (any other action ends a push)."""
        last, self.last = self.last, None
        if not (self.on and probe_contact):
            return False, False
        verdict = carry_verdict(last, light, command, offsets, self.within)
        self.last = verdict.last
        return verdict.carried, verdict.pinned


def commands(table: pa.Table) -> np.ndarray:
    """The commanded move (A, 2), metres, of every action of a ``sim_run`` table."""
    return np.column_stack([table.column("cmd_dx_m").to_numpy(zero_copy_only=False),
                            table.column("cmd_dy_m").to_numpy(zero_copy_only=False)]).astype(np.float64)
