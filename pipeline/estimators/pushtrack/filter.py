"""Tracking the target's planar pose through the gripper's pushes: a particle filter over SE(2) (docs/estimators.md,
"The pushtrack estimator").

The target's COM pose x_t = (x, y, yaw) changes only during the actions in which the gripper touches the target's
segment. Such an action pushes the target by the gripper's in-contact displacement d: by default the gripper's slice
sweeps over d and a box pushed on a long face turns about its leading edge
(:mod:`pipeline.estimators.pushtrack.slice_pusher`, ``motion`` "tip"); the point pusher at the contact drives the
quasi-static model of planar pushing with an ellipsoidal limit surface
(:mod:`pipeline.estimators.pushtrack.quasistatic`, "push"). Walls and other objects are not modelled: a noise term
growing with the push length lets the contacts correct the prediction.

Observations weigh the particles at their own times: the contact point of a touching action lies on the target's
surface at the pose after that action (robust Geman-McClure term), and the gripper's slice at the end of every
action and along every action that did not touch the target lies outside the target at that time's pose (squared
depth beyond a tolerance, the plausible estimator's free-space term). Weights are kept in log space; the particles
are resampled (systematic) before a push when the effective sample size is low. Every array holds all particles:
no Python loop over particles or points (the free-space sums run in a compiled loop,
:mod:`pipeline.estimators.pushtrack.kernel`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.estimators.pushtrack.kernel import free_depth_sums, reweigh
from pipeline.estimators.pushtrack.params import MAX_PARTICLES, MOTIONS, SELECT_RULES, SLICE_MOTIONS, PushTrackParams
from pipeline.estimators.pushtrack.quasistatic import limit_surface_length, push_step
from pipeline.estimators.pushtrack.slice_pusher import GripperSlice, sweep_push, target_outline
from pipeline.geometry import Primitive, outline_point, primitive_sdf, rotate, wrap_angle
from pipeline.portable import atan2
from pipeline.track.resampling import systematic
from pipeline.track.weights import logsumexp

# (the parameters live in pipeline.estimators.pushtrack.params; re-exported here, where the filter's callers look)
__all__ = ["PushTrackParams", "MOTIONS", "SLICE_MOTIONS", "SELECT_RULES", "Actions", "FilterResult", "push",
           "model_length", "model_push", "contact_loglik", "particle_frames", "free_loglik", "initial_particles",
           "run_filter", "MAX_PARTICLES"]


@dataclass(frozen=True)
class Actions:
    """One run's actions as the filter reads them (K actions).

    Attributes
    ----------
    ee_start, ee_end : ndarray, shape (K, 2), metres
        Gripper position at the start and end of each action.
    touch : ndarray, shape (K,), bool
        The action touched the target's segment (a contact step of the chosen segment).
    contact : ndarray, shape (K, 2), metres
        Isolated contact point at the end of the action (NaN where none).
    push : ndarray, shape (K, 2), metres
        The gripper's displacement while in contact during the action (0 where none).
    gripper : GripperSlice or None
        The gripper's slice (:func:`pipeline.estimators.pushtrack.slice_pusher.gripper_slice`): the pusher of
        ``motion`` "sweep" and "tip".
    """

    ee_start: np.ndarray
    ee_end: np.ndarray
    touch: np.ndarray
    contact: np.ndarray
    push: np.ndarray
    gripper: GripperSlice | None = None

    def slice_poses(self, rows: np.ndarray, spacing: float) -> np.ndarray:
        """The gripper's positions (P, 2), metres, in the actions ``rows`` (R,): the end of a touching one, and
        along one that did not touch, straight from its start to its end, one every ``spacing`` (m) or closer."""
        a, b = self.ee_start[rows], self.ee_end[rows]
        n = np.where(self.touch[rows], 0, np.ceil(np.hypot(*(b - a).T) / spacing)).astype(np.int64)
        seg = np.repeat(np.arange(len(rows)), n + 1)
        k = np.arange(len(seg)) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
        frac = np.where(n[seg] > 0, k / np.maximum(n[seg], 1), 1.0)  # a touching action: its end pose only
        return a[seg] + frac[:, None] * (b - a)[seg]


def push(prim: Primitive, pose: np.ndarray, start: np.ndarray, d: np.ndarray, c: float,
         params: PushTrackParams) -> np.ndarray:
    """Poses (N, 3) after a push of d (2,) m from the pusher point ``start`` (2,), in ``params.substeps`` steps."""
    k = params.substeps
    for i in range(k):
        pose = push_step(prim, pose, start + d * (i / k), d / k, c, params.friction, params.motion)
    return pose


def _local(prim: Primitive, pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World points (P, 2) in the primitive frame of every COM pose (N, 3): (N, P, 2)."""
    centre = prim.centre_world(pose)
    return rotate(pts[None, :, :] - centre[:, None, :], (pose[:, 2] + prim.yaw)[:, None], inverse=True)


def contact_loglik(prim: Primitive, pose: np.ndarray, point: np.ndarray, params: PushTrackParams) -> np.ndarray:
    """Log-likelihood (N,) of a contact point (2,) on the surface of the target at COM poses (N, 3)."""
    sd, _ = primitive_sdf(prim, _local(prim, pose, point[None, :])[:, 0, :])
    u2 = (sd / params.contact_sigma) ** 2
    c2 = params.outlier_sigmas ** 2
    return -0.5 * c2 * u2 / (c2 + u2)


def particle_frames(prim: Primitive, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The primitive's centre (N, 2), metres, and the cosines and sines (N,) of its axes' yaw at COM poses
    (N, 3): what :func:`free_loglik` reads of the poses, made once while the particles stay put."""
    centre = np.ascontiguousarray(prim.centre_world(pose))
    yaw = (pose[:, 2] + prim.yaw)[:, None]  # the array rotate() takes its cosines from in _local
    return centre, np.cos(yaw)[:, 0].copy(), np.sin(yaw)[:, 0].copy()


def free_loglik(prim: Primitive, pose: np.ndarray, free: np.ndarray, params: PushTrackParams,
                frames: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Log-likelihood (N,) of gripper points (F, 2) lying outside the target at COM poses (N, 3): -1/2 the sum of
    the squared depths beyond ``free_tolerance`` over ``free_sigma``, through the compiled loop
    (:func:`pipeline.estimators.pushtrack.kernel.free_depth_sums`: the same bits as the numpy form it replaced,
    tests/test_pushtrack_kernel.py). ``frames``: :func:`particle_frames` of ``pose``, when already made."""
    if len(free) == 0:
        return np.zeros(len(pose))
    centre, cos_t, sin_t = particle_frames(prim, pose) if frames is None else frames
    hx, hy = float(prim.half[0]), float(prim.half[1]) if len(prim.half) > 1 else 0.0
    # outside the circumscribed circle a point is outside the target: its term is exactly 0
    reach = math.hypot(hx, hy) + 1e-6
    out = np.empty(len(pose))
    free_depth_sums(prim.kind == "cylinder", hx, hy, centre, cos_t, sin_t,
                    np.ascontiguousarray(free, dtype=np.float64), float(params.free_tolerance),
                    float(params.free_sigma), reach, out, np.empty(len(free)))
    return -0.5 * out


def initial_particles(prim: Primitive, point: np.ndarray, normal_hint: np.ndarray, n: int,
                      rng: np.random.Generator) -> np.ndarray:
    """n COM poses (n, 3) whose surface passes through ``point`` (2,): stratified yaw from a random offset, a random
    point of the outline on ``point``; with a nonzero ``normal_hint`` (2,) (the push direction) the outline point
    is drawn on a side whose outward normal opposes it (the pusher pushes into the target)."""
    theta = (rng.uniform() + np.arange(n)) * (2.0 * np.pi / n)
    if prim.kind == "cylinder":
        ang = rng.uniform(0.0, 2.0 * np.pi, n)
        if np.any(normal_hint != 0.0):
            hint = float(atan2(-normal_hint[1], -normal_hint[0]))
            ang = hint + rng.uniform(-0.5 * np.pi, 0.5 * np.pi, n) - theta - prim.yaw
        u = prim.half[0] * np.column_stack([np.cos(ang), np.sin(ang)])
    else:
        hx, hy = prim.half
        u = outline_point(rng.uniform(0.0, 4.0 * (hx + hy), n), hx, hy)
    yaw = theta + prim.yaw
    centre = point - rotate(u, yaw)
    com = centre - rotate(np.broadcast_to(prim.centre, centre.shape), theta)
    return np.column_stack([com, wrap_angle(theta)])


@dataclass
class FilterResult:
    """The particles after the run's last action.

    Attributes
    ----------
    poses : ndarray, shape (N, 3)
        COM poses.
    log_w : ndarray, shape (N,)
        Normalised log-weights (finite).
    local : ndarray, shape (N, T, 2)
        Each touching action's contact point in the particle's COM frame at that action (T touching actions):
        the contacts carried with each particle's own trajectory are ``apply_pose(poses, local)``.
    choice : ndarray, shape (N,)
        Log prior of each particle's pushed-or-left choices at other segments' contacts (``other_push``): a pushed
        particle log(other_push), a left one log(1 - other_push), summed over its trajectory (0 without any).
    pushed : ndarray, shape (T,)
        Length (m) of the pushes after each touching action's contact (the target's and other segments' near it).
    n_pushes : int
        Actions that touched the target.
    n_resampled : int
        Resampling steps.
    log_evidence : float
        Log-likelihood of the observations given to the filter (its contacts and free space, from the first touch
        on; the free space before it at the first touch), summed over the actions: log of the weights' total after
        each update, before normalising. Compares filters over the same run (``starts``).
    """

    poses: np.ndarray
    log_w: np.ndarray
    local: np.ndarray
    choice: np.ndarray
    pushed: np.ndarray
    n_pushes: int
    n_resampled: int
    log_evidence: float = 0.0


def model_length(prim: Primitive, params: PushTrackParams) -> float:
    """The limit surface's characteristic length (m) of the pushing model ``params.motion``."""
    scale = params.sweep_limit_scale if params.motion in SLICE_MOTIONS else params.limit_scale
    return limit_surface_length(prim) * scale


def model_push(prim: Primitive, pose: np.ndarray, params: PushTrackParams, contact: np.ndarray, d: np.ndarray,
               c: float, sweep: tuple | None = None) -> np.ndarray:
    """COM poses (N, 3) after one push by the pushing model ``params.motion``, without its noise: with ``sweep``
    (the gripper's slice, the target's outline, the gripper's end position (2,)) the slice swept over the
    in-contact displacement d (2,) m to that end position ("sweep", "tip"; before it the gripper did not touch the
    target), else the point pusher moved by d to the contact (2,) ("push", "translate", "static"); c the limit
    surface's length (:func:`model_length`)."""
    if sweep is not None:
        return sweep_push(prim, pose, sweep[0], sweep[1], sweep[2] - d, sweep[2], params.sweep_substeps, c,
                          params.friction, (params.tip_spread, params.tip_reach) if params.motion == "tip" else None)
    return push(prim, pose, contact - d, d, c, params)


def _move(prim: Primitive, pose: np.ndarray, sel: np.ndarray, contact: np.ndarray, d: np.ndarray, c: float,
          params: PushTrackParams, rng: np.random.Generator, seen: np.ndarray, j: int, noisy: np.ndarray,
          share: np.ndarray | None = None, sweep: tuple | None = None) -> np.ndarray:
    """Poses (N, 3) after the pusher at ``contact`` (2,) (its end point) moved by d (2,) m against the particles
    ``sel`` (N,) bool: the pushing model plus the push noise (:func:`model_push`, :class:`PushTrackParams`). The
    particles' earlier contacts ``seen[:, :j]`` (N, T, 2) move with the model's rigid displacement, in place: not
    with the noise floors; with the push noise too where ``noisy`` (N,) bool (``carry``). ``share`` (N,): the part
    of the model's displacement each particle gets (default all)."""
    if sel.all():
        sel = slice(None)  # every particle (a push of the target): views, not copies; the same values
    out = pose.copy()
    a = pose[sel]
    b = model_push(prim, a, params, contact, d, c, sweep)
    length = math.hypot(d[0], d[1])
    if share is not None:
        b = a + (b - a) * share[sel, None]
        length = length * share[sel, None]
    z = rng.normal(0.0, 1.0, size=b.shape)
    moved = b + z * (np.array([params.trans_noise, params.trans_noise, params.yaw_noise]) * length)
    b = np.where(noisy[sel, None], moved, b)
    if j:
        seen[sel, :j] = rotate(seen[sel, :j] - a[:, None, :2], (b[:, 2] - a[:, 2])[:, None]) + b[:, None, :2]
    out[sel] = moved + z * np.array([params.noise_floor] * 2 + [params.yaw_floor])
    return out


def run_filter(prim: Primitive, actions: Actions, free_points, params: PushTrackParams,
               rng: np.random.Generator, give_up_below: float = -math.inf) -> FilterResult | None:
    """The particle filter over one run's actions; None when no action touched the target, or as soon as the
    evidence falls below ``give_up_below`` (it never rises: every likelihood term is at most 1).

    ``free_points(rows, centre)`` returns the world points (F, 2) the gripper's slice covered during the actions
    ``rows`` (an index array; only the end pose for a touching action) near ``centre`` (2,).
    """
    touched = np.flatnonzero(actions.touch)
    if len(touched) == 0:
        return None
    c = model_length(prim, params)
    first = int(touched[0])
    start = actions.contact[first] - actions.push[first]
    pose = initial_particles(prim, start, actions.push[first], params.n_particles, rng)
    # uniform weights times the free space before the first touch (log N: the weights' total before)
    log_w = np.empty(len(pose))
    total, before = reweigh(np.zeros(len(pose)), free_loglik(prim, pose, free_points(np.arange(first), start), params),
                            log_w)
    evidence = total - before
    if evidence < give_up_below:
        return None
    resampled = 0
    seen = np.zeros((len(pose), len(touched), 2))  # the contacts in world coordinates, carried by the model
    choice = np.zeros(len(pose))
    noisy = np.full(len(pose), params.carry == "model+noise")
    if params.carry == "mixed":
        noisy = np.arange(len(pose)) % 2 == 1
    pushed = np.zeros(len(touched))
    outline = target_outline(prim) if params.motion in SLICE_MOTIONS else None
    if outline is not None and actions.gripper is None:
        raise ValueError(f"PushTrackParams.motion {params.motion!r} needs the gripper's slice (Actions.gripper)")
    j = 0
    # (the poses array, its mean position, its particle_frames): most actions push nothing and leave the particles
    # where they were (every move makes a new array; the injection writes into the one a move has just made)
    kept: list = [None, None, None]
    K = len(actions.touch)
    # the first touching action at or after each action (K after the last): a stretch of actions that push
    # nothing ends there (free_stretches)
    next_touch = np.searchsorted(touched, np.arange(K + 1))
    next_touch = np.where(next_touch < len(touched), touched[np.minimum(next_touch, len(touched) - 1)], K)
    t = first
    while t < K:
        if kept[0] is not pose:
            kept = [pose, np.mean(pose[:, :2], axis=0), None]
        centre = kept[1]
        d = actions.push[t]
        sweep = None if outline is None else (actions.gripper, outline, actions.ee_end[t])
        if actions.touch[t]:
            if math.exp(-logsumexp(2.0 * log_w)) < params.ess_threshold * len(pose):
                ancestors = systematic(log_w, rng)
                pose, seen, noisy, choice = pose[ancestors], seen[ancestors], noisy[ancestors], choice[ancestors]
                log_w = np.full(len(pose), -math.log(len(pose)))
                resampled += 1
            pose = _move(prim, pose, np.ones(len(pose), dtype=bool), actions.contact[t], d, c, params, rng, seen, j,
                         noisy, sweep=sweep)
            pushed[:j] += math.hypot(d[0], d[1])
            n_new = int(params.inject * len(pose))
            if n_new and j:
                worst = np.lexsort((np.arange(len(pose)), log_w))[:n_new]
                pose[worst] = initial_particles(prim, actions.contact[t], d, n_new, rng)
                # their earlier contacts where they were observed, as if the target had not moved since
                seen[worst, :j] = actions.contact[touched[:j]][None, :, :]
                # weighted as the best particle times the likelihood of those contacts, each one's sigma grown
                # per later push (they were observed before the target moved)
                sd, _ = primitive_sdf(prim, _local(prim, pose[worst], actions.contact[touched[:j]]))
                u2 = (sd / (params.contact_sigma * params.inject_growth ** (j - np.arange(j))[None, :])) ** 2
                c2 = params.outlier_sigmas ** 2
                log_w[worst] = np.max(log_w) - 0.5 * np.sum(c2 * u2 / (c2 + u2), axis=1)
            ll = contact_loglik(prim, pose, actions.contact[t], params)
            ll = ll + free_loglik(prim, pose, free_points(np.array([t]), centre), params)
            seen[:, j] = actions.contact[t]
            j += 1
        else:
            # (only before the target's last touch: after it no contact can tell a pushed particle from one left)
            if params.other_push and t < touched[-1] and np.all(np.isfinite(actions.contact[t])) and np.any(d != 0.0):
                sd, _ = primitive_sdf(prim, _local(prim, pose, actions.contact[t][None, :])[:, 0, :])
                near = np.abs(sd) <= params.other_reach
                moved = near & (rng.uniform(size=len(pose)) < params.other_push)
                lp = (math.log(params.other_push), math.log1p(-params.other_push) if params.other_push < 1.0 else 0.0)
                choice += np.where(moved, lp[0], np.where(near, lp[1], 0.0))
                if moved.any():
                    pushed[:j] += math.hypot(d[0], d[1])
                    # the pusher first closes the gap to the particle's surface: the rest of d pushes it
                    gap = np.maximum(sd, 0.0) / max(math.hypot(d[0], d[1]), 1e-12)
                    pose = _move(prim, pose, moved, actions.contact[t], d, c, params, rng, seen, j, noisy,
                                 None if sweep is not None else np.clip(1.0 - gap, 0.0, 1.0), sweep=sweep)
            rows = np.array([t])
            if params.free_stretches and not params.other_push:
                rows = np.arange(t, next_touch[t])  # one observation: the particles stay where they are
                t = int(rows[-1])
            free = free_points(rows, centre)
            if len(free) and kept[0] is pose and kept[2] is None:
                kept[2] = particle_frames(prim, pose)
            ll = free_loglik(prim, pose, free, params, kept[2] if kept[0] is pose else None)
        # (log_w need not sum to one here: the particles injected at a push were weighted apart)
        updated = np.empty(len(pose))
        total, before = reweigh(np.ascontiguousarray(log_w, dtype=np.float64),
                                np.ascontiguousarray(ll, dtype=np.float64), updated)
        evidence += total - before
        if evidence < give_up_below:
            return None
        log_w = updated
        t += 1
    pose[:, 2] = wrap_angle(pose[:, 2])
    local = rotate(seen - pose[:, None, :2], pose[:, 2, None], inverse=True)
    return FilterResult(poses=pose, log_w=log_w, local=local, choice=choice, pushed=pushed, n_pushes=len(touched),
                        n_resampled=resampled, log_evidence=evidence)
