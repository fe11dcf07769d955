"""Probe planning: which guarded move separates the hypotheses of the plausible set best (docs/active.md).

A candidate probe is a straight line: it starts at a position the gripper has already occupied (known free space,
reached by retracing visited positions) and heads in one direction. Every hypothesis predicts where the guarded
move along it would stop: the travel after which the gripper's outline first meets the posed primitive (a ray
cast from each point of the outline, :func:`ray_travel`). The probe chosen is the one whose predicted outcomes
are most uncertain under the hypotheses' likelihoods (the entropy of the binned outcome, which is the expected
information gain of a noiseless outcome), less a small charge per metre of travel.

Everything is vectorised over (lines, hypotheses, outline points); nothing here reads the simulation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.constraints import Params
from pipeline.estimators.plausible.evidence import gripper_lattice
from pipeline.geometry import Primitive, com_pose, primitive_pose, rotate, wrap_symmetric
from pipeline.portable import log
from pipeline.probe.transit import Keepout, path_to, transit_graph

__all__ = ["PlanParams", "ProbePlan", "gripper_outline", "ray_travel", "agreement", "outcome_entropy",
           "obstacle_travel", "hit_points", "choose_probe"]


@dataclass(frozen=True)
class PlanParams(Params):
    """Parameters of probe planning; serialised into the run's metadata.

    Attributes
    ----------
    yaw_tolerance : float, radians
        Hypotheses agree on yaw within this (0.05: the box grasp's tolerance, docs/retrieval.md).
    position_tolerance : float, metres
        ... and on the primitive centre within this (0.01).
    agree_share : float
        The set agrees when this likelihood share of it is within both tolerances of the estimate (0.95).
    max_travel : float, metres
        Longest guarded move (0.25).
    outcome_bin : float, metres
        Outcomes closer than this are not told apart (0.008: two fine steps of the guarded move).
    n_directions : int
        Directions tried from each start, evenly spaced (16), of which those within ``aim_cone`` of the set's
        centre are kept.
    aim_cone : float, radians
        Half-angle of that cone (0.8).
    max_starts : int
        At most this many start positions, the visited positions nearest the set's centre (40).
    start_reach : float, metres
        Starts farther than this from the set's centre are not tried (0.35).
    path_cost : float, bits per metre
        Charge on the transit to the start plus the expected travel (1.0).
    perturb_weight : float
        Likelihood share given to copies of the estimate turned by +-``perturb_yaw`` and shifted by
        +-``perturb_shift`` (0.3): a set that already agrees still has a probe that would catch its being wrong.
    perturb_yaw : float, radians
    perturb_shift : float, metres
    outline_resolution : float, metres
        Spacing of the gripper outline points (0.01).
    link_radius : float, metres
        Visited positions closer than this are linked for transit (0.02), besides consecutive ones.
    transit_clearance : float, metres
        Transit keeps the gripper this far from the target at the set's estimate (0.015: the estimate's error
        and the gripper's lag behind its command; :class:`pipeline.probe.transit.Keepout`).
    obstacle_radius : float, metres
        A known point of another object blocks the outline within this distance (0.01).
    """

    yaw_tolerance: float = 0.05
    position_tolerance: float = 0.01
    agree_share: float = 0.95
    max_travel: float = 0.25
    outcome_bin: float = 0.008
    n_directions: int = 16
    aim_cone: float = 0.8
    max_starts: int = 40
    start_reach: float = 0.35
    path_cost: float = 1.0
    perturb_weight: float = 0.3
    perturb_yaw: float = 0.08
    perturb_shift: float = 0.015
    outline_resolution: float = 0.01
    link_radius: float = 0.02
    transit_clearance: float = 0.015
    obstacle_radius: float = 0.01


@dataclass
class ProbePlan:
    """The chosen guarded move.

    Attributes
    ----------
    path : ndarray, shape (P, 2), metres
        Visited positions to retrace from the current position to the start (the start last; P >= 1).
    start : ndarray, shape (2,)
    direction : ndarray, shape (2,), unit
    predicted : ndarray, shape (H,), metres
        Travel at which each hypothesis of the set predicts contact (inf: none within ``max_travel``).
    gain : float, bits
        Entropy of the predicted outcome (perturbed copies included).
    mode : str
        ``gain`` (the most informative line) or ``spread`` (the contact farthest from the given points).
    """

    path: np.ndarray
    start: np.ndarray
    direction: np.ndarray
    predicted: np.ndarray
    gain: float
    mode: str = "gain"


def gripper_outline(sdf, resolution: float = 0.01) -> np.ndarray:
    """Points (G, 2), metres, robot frame, of the gripper's slice within one ``resolution`` of its boundary."""
    lattice = gripper_lattice(sdf, resolution)
    return lattice[sdf.query(lattice) > -resolution]


def ray_travel(prim: Primitive, poses: np.ndarray, origins: np.ndarray, directions: np.ndarray,
               max_travel: float) -> np.ndarray:
    """Travel (L, H), metres, along each line until the outline meets each posed primitive.

    Parameters
    ----------
    prim : Primitive
    poses : ndarray, shape (H, 3)
        COM poses of the hypotheses.
    origins : ndarray, shape (L, G, 2)
        Outline points of the gripper at each line's start (world).
    directions : ndarray, shape (L, 2), unit
    max_travel : float
        Beyond this a line misses (inf).

    Returns
    -------
    ndarray, shape (L, H)
        0 where the outline already overlaps the hypothesis at the start.
    """
    t = _ray_all(prim, poses, origins, directions).min(axis=-1)
    return np.where(t <= max_travel, t, np.inf)


def _ray_all(prim: Primitive, poses: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Travel (L, H, G) of every outline point of every line to every posed primitive (inf: a miss)."""
    pp = primitive_pose(prim, np.asarray(poses, dtype=np.float64).reshape(-1, 3))  # (H, 3) centre, axes yaw
    o = rotate(origins[:, None, :, :] - pp[None, :, None, :2], pp[None, :, None, 2], inverse=True)  # (L, H, G, 2)
    d = rotate(directions[:, None, :], pp[None, :, 2], inverse=True)[:, :, None, :]  # (L, H, 1, 2)
    if prim.kind == "cylinder":
        r = prim.half[0]
        b = np.sum(o * d, axis=-1)
        c = np.sum(o * o, axis=-1) - r * r
        disc = b * b - c
        root = np.sqrt(np.maximum(disc, 0.0))
        near, far = -b - root, -b + root
        hit = (disc >= 0.0) & (far >= 0.0)
        t = np.where(hit, np.maximum(near, 0.0), np.inf)
    else:
        h = np.asarray(prim.half[:2], dtype=np.float64)
        dd = np.where(np.abs(d) < 1e-12, 1e-12, d)
        t1 = (-h - o) / dd
        t2 = (h - o) / dd
        near = np.max(np.minimum(t1, t2), axis=-1)
        far = np.min(np.maximum(t1, t2), axis=-1)
        hit = (near <= far) & (far >= 0.0)
        t = np.where(hit, np.maximum(near, 0.0), np.inf)
    return t


def hit_points(prim: Primitive, pose: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Where each line's outline first meets one posed primitive (COM pose (3,)): points (L, 2), NaN on a miss."""
    t = _ray_all(prim, np.asarray(pose, dtype=np.float64).reshape(1, 3), origins, directions)[:, 0, :]  # (L, G)
    g = np.argmin(t, axis=1)
    tl = t[np.arange(len(t)), g]
    hit = origins[np.arange(len(t)), g] + np.where(np.isfinite(tl), tl, np.nan)[:, None] * directions
    return hit


def obstacle_travel(obstacles: np.ndarray, origins: np.ndarray, directions: np.ndarray, radius: float,
                    max_travel: float) -> np.ndarray:
    """Travel (L,), metres, along each line until the outline comes within ``radius`` of a known point of
    another object (obstacles (Q, 2): other segments' points, probe contacts on something else); inf if none.

    ``origins`` (L, G, 2) and ``directions`` (L, 2) as :func:`ray_travel`."""
    obstacles = np.asarray(obstacles, dtype=np.float64).reshape(-1, 2)
    if len(obstacles) == 0:
        return np.full(len(directions), np.inf)
    rel = obstacles[None, None, :, :] - origins[:, :, None, :]  # (L, G, Q, 2)
    b = np.sum(rel * directions[:, None, None, :], axis=-1)
    c = np.sum(rel * rel, axis=-1) - radius * radius
    disc = b * b - c
    near = b - np.sqrt(np.maximum(disc, 0.0))
    t = np.where((disc >= 0.0) & (b + np.sqrt(np.maximum(disc, 0.0)) >= 0.0), np.maximum(near, 0.0), np.inf)
    t = t.min(axis=(1, 2))
    return np.where(t <= max_travel, t, np.inf)


def agreement(prim: Primitive, poses: np.ndarray, weights: np.ndarray, best: int, yaw_tolerance: float,
              position_tolerance: float) -> float:
    """Likelihood share (0-1) of the hypotheses within both tolerances of hypothesis ``best`` (primitive centres;
    yaw modulo the shape's symmetry, ignored for a cylinder)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    c = prim.centre_world(poses)
    near = np.linalg.norm(c - c[best], axis=1) <= position_tolerance
    if prim.symmetry > 0.0:
        near &= np.abs(wrap_symmetric(poses[:, 2] - poses[best, 2], prim.symmetry)) <= yaw_tolerance
    return float(np.sum(np.asarray(weights)[near]) / max(np.sum(weights), 1e-300))


def outcome_entropy(travel: np.ndarray, weights: np.ndarray, bin_width: float) -> np.ndarray:
    """Entropy (L,), bits, of the binned outcome of each line: travel (L, H) binned by ``bin_width``, a miss
    (inf) its own outcome, each hypothesis voting with its weight (H,)."""
    w = np.asarray(weights, dtype=np.float64) / np.sum(weights)
    key = np.where(np.isfinite(travel), np.floor(travel / bin_width), -1.0)
    L, H = key.shape
    # Sort each line's keys: equal keys are adjacent, their weights summed by a segmented cumulative sum.
    order = np.argsort(key, axis=1, kind="stable")
    ks = np.take_along_axis(key, order, axis=1)
    ws = w[order]
    new = np.ones((L, H), dtype=bool)
    new[:, 1:] = ks[:, 1:] != ks[:, :-1]
    group = np.cumsum(new, axis=1) - 1 + (np.arange(L) * H)[:, None]
    mass = np.bincount(group.ravel(), weights=ws.ravel(), minlength=L * H).reshape(L, H)
    with np.errstate(divide="ignore", invalid="ignore"):
        ent = -np.where(mass > 0, mass * log(np.where(mass > 0, mass, 1.0)) / math.log(2.0), 0.0)
    return ent.sum(axis=1)


def _perturbed(prim: Primitive, pose: np.ndarray, params: PlanParams) -> np.ndarray:
    """Copies (6, 3) of a COM pose turned about the primitive centre by +-perturb_yaw and shifted by
    +-perturb_shift along the primitive's two axes."""
    pp = primitive_pose(prim, pose)
    ax = np.array([[np.cos(pp[2]), np.sin(pp[2])], [-np.sin(pp[2]), np.cos(pp[2])]])
    out = [pp + [0, 0, s * params.perturb_yaw] for s in (-1, 1)]
    out += [np.r_[pp[:2] + s * params.perturb_shift * ax[k], pp[2]] for k in (0, 1) for s in (-1, 1)]
    return com_pose(prim, np.array(out))


def choose_probe(prim: Primitive, poses: np.ndarray, weights: np.ndarray, best: int, visited: np.ndarray,
                 outline: np.ndarray, params: PlanParams = PlanParams(), obstacles: np.ndarray | None = None,
                 done: np.ndarray | None = None, spread_from: np.ndarray | None = None,
                 touching: np.ndarray | None = None, keepout: Keepout | None = None,
                 graph: tuple[np.ndarray, np.ndarray] | None = None) -> ProbePlan | None:
    """The guarded move that best separates the hypotheses, or None if no start can be reached.

    Parameters
    ----------
    poses : ndarray, shape (H, 3)
        COM poses of the plausible set; ``weights`` (H,) their likelihoods; ``best`` the estimate's index.
    visited : ndarray, shape (K, 2)
        Gripper positions so far, the current one last.
    outline : ndarray, shape (G, 2)
        :func:`gripper_outline`.
    obstacles : ndarray, shape (Q, 2), optional
        Known points of other objects: a line stops at the first (:func:`obstacle_travel`), so every
        hypothesis whose contact lies beyond predicts that stop instead.
    done : ndarray, shape (D, 4), optional
        Lines already probed (start x, y, direction x, y): not repeated (within 2 cm and 0.3 rad).
    touching : ndarray, shape (K,), bool, optional
        Visited positions transit must avoid (reached in contact by a probe).
    keepout : Keepout, optional
        The region around the target's estimate transit stays out of (positions and the moves between them).
    graph : (ndarray (K,), ndarray (K,)), optional
        :func:`pipeline.probe.transit.transit_graph` of ``visited`` under ``touching`` and ``keepout``, when the
        caller has built it already (:func:`pipeline.probe.moves.reaching`).
    spread_from : ndarray, shape (P, 2), optional
        Instead of the most informative line, the one whose contact the estimate predicts farthest from these
        points (the target's probe contacts): a set that agrees on a few close contacts may rest on another,
        smaller object, and a contact across the target's length tells.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    extra = _perturbed(prim, poses[best], params)
    all_poses = np.vstack([poses, extra])
    all_w = np.r_[w * (1.0 - params.perturb_weight), np.full(len(extra), params.perturb_weight / len(extra))]
    centre = np.sum(prim.centre_world(poses) * w[:, None], axis=0)
    visited = np.asarray(visited, dtype=np.float64).reshape(-1, 2)
    dist, pred = graph if graph is not None else transit_graph(visited, params.link_radius, touching, keepout)
    reach = np.linalg.norm(visited - centre, axis=1)
    ok = np.flatnonzero(np.isfinite(dist) & (reach <= params.start_reach))
    if len(ok) == 0:
        return None
    # Distinct starts (2 cm cells), nearest the set first.
    _, first = np.unique(np.rint(visited[ok] / 0.02).astype(np.int64), axis=0, return_index=True)
    ok = ok[first]
    ok = ok[np.argsort(reach[ok], kind="stable")[:params.max_starts]]
    ang = np.arange(params.n_directions) * (2 * np.pi / params.n_directions)
    dirs = np.column_stack([np.cos(ang), np.sin(ang)])
    to_c = centre - visited[ok]
    to_c /= np.maximum(np.linalg.norm(to_c, axis=1, keepdims=True), 1e-9)
    s_idx, d_idx = np.nonzero(np.sum(to_c[:, None, :] * dirs[None, :, :], axis=-1) >= np.cos(params.aim_cone))
    if len(s_idx) == 0:
        return None
    starts = visited[ok[s_idx]]
    directions = dirs[d_idx]
    origins = starts[:, None, :] + outline[None, :, :]
    travel = ray_travel(prim, all_poses, origins, directions, params.max_travel)
    near = np.linalg.norm(np.asarray(obstacles if obstacles is not None else np.zeros((0, 2))).reshape(-1, 2)
                          - centre, axis=1) if obstacles is not None else np.zeros(0)
    if len(near):
        obs = obstacle_travel(np.asarray(obstacles).reshape(-1, 2)[near <= params.start_reach + 0.2], origins,
                              directions, params.obstacle_radius, params.max_travel)
        travel = np.minimum(travel, obs[:, None])
    gain = outcome_entropy(travel, all_w, params.outcome_bin)
    # A start already inside much of the set is not free any more (the target may have been pushed there).
    blocked = np.sum((travel[:, :len(poses)] < 0.005) * w[None, :], axis=1) > 0.2
    fin = np.isfinite(travel)
    expect = np.sum(np.where(fin, travel, params.max_travel) * all_w[None, :], axis=1)
    score = gain - params.path_cost * (dist[ok[s_idx]] + expect)
    score[blocked | ~fin.any(axis=1)] = -np.inf
    if done is not None and len(done):
        done = np.asarray(done, dtype=np.float64).reshape(-1, 4)
        same = (np.linalg.norm(starts[:, None, :] - done[None, :, :2], axis=-1) < 0.02) & \
            (np.sum(directions[:, None, :] * done[None, :, 2:], axis=-1) > np.cos(0.3))
        score[same.any(axis=1)] = -np.inf
    if spread_from is not None and len(spread_from):
        hits = hit_points(prim, poses[best], origins, directions)
        far = np.min(np.linalg.norm(hits[:, None, :] - np.asarray(spread_from).reshape(1, -1, 2), axis=-1), axis=1)
        far = np.where(np.isfinite(far) & np.isfinite(score), far, -np.inf)
        score = np.where(np.isfinite(score), far - params.path_cost * 0.01 * dist[ok[s_idx]], -np.inf)
    j = int(np.argmax(score))
    if not np.isfinite(score[j]):
        return None
    return ProbePlan(path=path_to(pred, visited, int(ok[s_idx[j]])), start=starts[j], direction=directions[j],
                     predicted=travel[j, :len(poses)], gain=float(gain[j]),
                     mode="spread" if spread_from is not None and len(spread_from) else "gain")
