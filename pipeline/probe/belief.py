"""What the robot knows during a run, computed by the pipeline itself on what has been sensed so far.

:class:`Sensing` feeds the scripted actions through the stages the run file will later go through, in the same
order and with the same random streams: isolation (:func:`pipeline.isolate.isolate_run`, the action's own row),
the tracker (:func:`pipeline.track.stage.make_tracker`, stream :func:`pipeline.seeds.run_rng`) updated once per
action as ``stucco track`` replays the contacts table, and the segmentation of ``stucco segment`` (Alg. 3 for
STUCCO, the tracker's own labels for the baselines); the probes' contacts are kept as isolated.
:func:`choose_target` is the paper's segment choice on the scripted part and :func:`pose_set` the plausible
estimator's fit (docs/estimators.md, "The plausible estimator") on that segment plus the probes' contacts,
returning the whole set with each pose's likelihood. The belief depends only on the run's data and the probe
contacts' attribution (in the run's metadata): the grasp recomputes the policy's last belief exactly (docs/active.md).

Nothing here reads the simulation's ground truth: only the contact wrench (through isolation), the gripper's
positions and the target's known shape.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.detection import DetectionParams, scene_detection
from pipeline.estimators.estimate import Segment
from pipeline.estimators.paper.choice import estimate_run
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.plausible.evidence import (
    cached_gripper_lattice,
    free_space_points,
    recency_sigma,
    target_reach,
)
from pipeline.estimators.plausible.fit import PlausibleParams, fit_segment
from pipeline.estimators.segment_choice import resisting_choice, segment_fits
from pipeline.geometry import Primitive, primitive_pose, primitive_sdf, rotate
from pipeline.isolate import IsolationParams, contact_forces, isolate_run, isolation_surface
from pipeline.labels import canonical_labels
from pipeline.portable import exp
from pipeline.probe.carry import Pushes, commands
from pipeline.robot import load_robot
from pipeline.scenes import declared_region
from pipeline.schema import step_bounds
from pipeline.seeds import run_rng
from pipeline.track.stage import TrackConfig, make_tracker, warm_up

__all__ = ["Sensing", "PoseSet", "TargetChoice", "NO_TARGET", "choose_target", "pose_set",
           "explaining", "surface_distance", "prior_set"]


class Sensing:
    """The tracker's view of one run's scripted actions, and the raw contacts of the probes after them.

    The scripted actions (the first ``n_scripted``) go through isolation and the tracker as ``stucco track``
    replays them. The probes' contacts are kept as isolated, at their own positions: they are the freshest data
    and nothing has moved since but by the probes' few millimetres, whereas the tracker's resampling would
    replace a fresh point that contradicts its drifted old ones by a copy of one of them (Alg. 2).

    Parameters
    ----------
    run : str; root_seed : int
        Run name (``<scene>/<seed>``) and the track stage's root seed: they key the tracker's random stream as
        ``stucco track`` does.
    start : ndarray, shape (2,), metres
        Gripper position before the first action.
    n_scripted : int
        Actions of the scripted part.
    method : str
        Tracking method (``stucco`` or a baseline of :mod:`pipeline.methods`).
    scene : pipeline.scenes.Scene, optional
        Its robot's detector and tracker parameters (else the defaults), and :attr:`region`.

    Attributes
    ----------
    region : ((x_min, y_min), (x_max, y_max)), metres, or None
        The target region the scene declares (:func:`pipeline.scenes.declared_region`; None: none), where the
        no-segment prior's hypotheses lie (:func:`prior_set`).
    prior : pipeline.probe.history.HistoryPrior or None
        The prior the scripted part's pushes put on the target's pose once the scripted part is observed (its
        ``segment``, the one it tracked, and ``cost(target, poses)``), added to the sets fitted to that segment
        (:func:`pipeline.probe.attribution.set_from_steps`). None: no prior.
    """

    def __init__(self, run: str, root_seed: int, start: np.ndarray, n_scripted: int, method: str = "stucco",
                 robot: str = "panda", scene=None) -> None:
        self.sdf = load_robot(robot)
        self.region = declared_region(scene)
        # the scene's robot as tuned (its [detection] and [methods.<method>]), as evaluate isolates and tracks it
        self.detection = DetectionParams() if scene is None else scene_detection(scene)
        params = {} if scene is None else scene.hardware.method_params(method)
        config = TrackConfig(method=method, robot=robot, params=params)
        warm_up(config, self.sdf)
        self.method, self.n_scripted = method, int(n_scripted)
        self.tracker = make_tracker(config, self.sdf, run_rng(root_seed, run))
        self.surface = isolation_surface(self.sdf, IsolationParams(robot=robot))
        self.ee = [np.asarray(start, dtype=np.float64)[:2].copy()]
        self.touching = [False]  # per visited position: reached in contact by a probe
        self.blocked = [False]  # per visited position: near where a transit met an object (block_near)
        self.steps: list[int] = []
        self.forces: list[float] = []  # contact force (N) each action met, NaN without
        self.point_steps, self.probe_steps, self.probe_points = [], [], []  # steps (int) and points (2,) arrays
        self.probe_forces: list[np.ndarray] = []  # the contact force (N) on the gripper, NaN without a wrench
        self.probe_force_n: list[float] = []  # the force (N) each probe contact's action met, NaN without
        self.light_n = 0.0  # probe contacts under this force (N) are the clutter's (attribution.light_limit)
        self.pushes = Pushes()  # probes pushing light clutter aside (ProbeParams.push_through)
        self.probe_pinned: list[bool] = []  # per probe contact: a carried object's, pinned (pipeline.probe.carry)
        self.prior: Any = None

    def observe(self, table: pa.Table) -> None:
        """Feed new actions (rows of a ``sim_run`` table, in order). An action with several contacts (fingertip
        sensors) gives the tracker all of them in one update, as ``stucco track`` does."""
        cols, _, _ = isolate_run(table, *self.surface, self.detection)
        first, self.forces = len(self.forces), self.forces + contact_forces(table, self.detection).tolist()
        force = np.column_stack([table.column("force_rep_x_n").to_numpy(zero_copy_only=False),
                                 table.column("force_rep_y_n").to_numpy(zero_copy_only=False)]).astype(np.float64)
        cmd = commands(table)
        step = np.asarray(cols["step"], dtype=np.int64)
        for a, (i, j) in enumerate(zip(*step_bounds(step))):
            x = np.array([cols["ee_x_m"][i], cols["ee_y_m"][i]])
            scripted = len(self.steps) < self.n_scripted
            self.ee.append(x)
            self.steps.append(int(step[i]))
            inc = bool(cols["in_contact"][i])
            p = np.array([cols["contact_x_m"][i:j], cols["contact_y_m"][i:j]], dtype=np.float64).T  # (K, 2)
            carried, pinned = self.pushes.judge(inc and not scripted, self.is_light(self.forces[first + a]),
                                                cmd[a], p - x)
            # Only a probe's contact leaves its object where it was: the scripted part's pushes and a carry moved
            # theirs on (the scripted positions are the transit's only links).
            self.touching.append(inc and not scripted and not carried)
            self.blocked.append(False)
            if carried:
                continue
            if not inc:
                if scripted:
                    self.tracker.update(x, None, None)
                continue
            if scripted:
                self.tracker.update(x, np.array([cols["dx_m"][i:j], cols["dy_m"][i:j]], dtype=np.float64).T, p)
                self.point_steps += [int(step[i])] * (j - i)
                continue
            self.probe_points += list(p)
            self.probe_steps += [int(step[i])] * (j - i)
            self.probe_forces += [force[a].copy() for _ in range(j - i)]
            self.probe_force_n += [float(self.forces[first + a])] * (j - i)
            self.probe_pinned += [pinned] * (j - i)

    @property
    def visited(self) -> np.ndarray:
        """Gripper positions (K + 1, 2), metres: the start, then the end of every action."""
        return np.array(self.ee)

    def is_light(self, force_n: float) -> bool:
        """Whether a probe contact whose action met ``force_n`` (N; NaN, not measured: never) was under ``light_n``."""
        return bool(force_n < self.light_n)

    def block_near(self, point: np.ndarray, radius: float) -> None:
        """Mark the visited positions within ``radius`` (m) of ``point`` (2,) ``blocked``: a transit met an object
        there, so the space once passed may not be free. Transit leaves them out as positions reached in contact,
        except in the last resort of :func:`pipeline.probe.policy.next_probe` and at the current position."""
        near = np.linalg.norm(self.visited - np.asarray(point, dtype=np.float64).reshape(1, 2), axis=1) < radius
        self.blocked = [t or bool(b) for t, b in zip(self.blocked, near)]

    @property
    def avoided(self) -> np.ndarray:
        """Visited positions transit leaves out (K,) bool: reached in contact by a probe, or ``blocked``."""
        return np.asarray(self.touching, dtype=bool) | np.asarray(self.blocked, dtype=bool)

    def segments(self) -> list[Segment]:
        """The segmentation ``stucco segment`` makes of the tracker's points (segment -1 left out)."""
        if not self.point_steps:
            return []
        pts = np.asarray(self.tracker.points_, dtype=np.float64)
        labels = canonical_labels(np.asarray(self.tracker.labels()))
        steps = np.asarray(self.point_steps, dtype=np.int64)
        return [Segment(int(s), pts[labels == s], steps[labels == s]) for s in np.unique(labels) if s >= 0]


@dataclass
class PoseSet:
    """The plausible set of target poses.

    Attributes
    ----------
    poses : ndarray, shape (H, 3)
        COM poses (x, y, yaw) of the plausible hypotheses.
    weights : ndarray, shape (H,)
        Likelihood of each relative to the best, exp(-(cost - best)), normalised to sum 1.
    best : int
        Index of the estimator's pose (the one ``stucco retrieve`` reports).
    segment : int
        Segment the set was fitted to (-1: none; the set is then :func:`prior_set`).
    notes : list of str
        Why the set is not a fit to the target's own segment (``no_segment``).
    cost : float, squared sigmas
        The fit's lowest cost (:func:`pipeline.estimators.plausible.fit.fit_segment`; 0 for :func:`prior_set`).
    """

    poses: np.ndarray
    weights: np.ndarray
    best: int
    segment: int
    notes: list[str] = field(default_factory=list)
    cost: float = 0.0


@dataclass
class TargetChoice:
    """The target's segment of the scripted part, chosen once (the paper's choice, §V-C, as ``stucco retrieve``).

    Attributes
    ----------
    segment : int
        Chosen segment (-1: none).
    points : ndarray, shape (M, 2); steps : ndarray, shape (M,)
        Its tracked points and their observation steps.
    others : ndarray, shape (Q, 2)
        The other segments' points.
    seeds : ndarray, shape (S, 3)
        The paper's valid ICP poses on the segment (COM), extra starts of the fit.
    resisted : bool
        The segment was chosen because its contacts resisted the pushes most, the target being heavy
        (:mod:`pipeline.estimators.segment_choice`).
    """

    segment: int
    points: np.ndarray
    steps: np.ndarray
    others: np.ndarray
    seeds: np.ndarray
    resisted: bool = False


def choose_target(segments: Sequence[Segment], target: Primitive, ee: np.ndarray, sdf,
                  rngs: Sequence[np.random.Generator], params: RetrievalParams = RetrievalParams(),
                  steps: np.ndarray | None = None, force: np.ndarray | None = None, mass: float = float("nan")
                  ) -> list[TargetChoice]:
    """The scripted part's segments ranked as the target's: the estimators' choice first (the paper's, §V-C, or
    for a heavy target the segment that resisted the pushes most: ``steps``, ``force`` (N) per action and the
    target's ``mass`` (kg), :func:`~pipeline.estimators.segment_choice.resisting_choice`), then the paper's if it
    differs, then the other segments whose best ICP error passes the fit gate by position variance, then the
    rest by the same. Empty without segments."""
    paper = estimate_run([(s.id, s.points) for s in segments], target, np.asarray(ee).reshape(-1, 2), sdf, params,
                         rngs[0], rngs[1])
    none = np.zeros((0, 2))
    if paper.segment < 0:
        return []
    icp = paper.candidates
    steps = np.zeros(0, np.int64) if steps is None else np.asarray(steps, dtype=np.int64)
    first, resisted = resisting_choice(segments, paper.segment, icp, steps, force, mass, params)
    fits = segment_fits(icp, [s.id for s in segments], params.segment_fit_gate)
    ranked = []
    for seg, fit in zip(segments, fits):
        m = icp["segment"] == seg.id
        if not m.any():
            continue
        var = np.nan_to_num(np.nanmin(np.r_[icp["position_var_m2"][m], np.inf]), nan=np.inf)
        ranked.append((seg.id != first, seg.id != paper.segment, not fit, float(var), seg.id, seg,
                       m & icp["valid"]))
    ranked.sort(key=lambda r: r[:5])
    return [TargetChoice(seg.id, np.asarray(seg.points, dtype=np.float64).reshape(-1, 2), np.asarray(seg.steps),
                         np.vstack([s.points for s in segments if s.id != seg.id] or [none]),
                         np.column_stack([icp["x_m"][mine], icp["y_m"][mine], icp["yaw_rad"][mine]]),
                         resisted and seg.id == first)
            for *_, seg, mine in ranked]


NO_TARGET = TargetChoice(-1, np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)))


def pose_set(choice: TargetChoice, target: Primitive, ee: np.ndarray, steps: np.ndarray, sdf,
             rng: np.random.Generator, probe_points: np.ndarray, probe_steps: np.ndarray, probe_others: np.ndarray,
             plausible: PlausibleParams = PlausibleParams(n_hypotheses=16, iterations=20), probe_growth: float = 1.25,
             max_seeds: int = 8, prior: Callable[[np.ndarray], np.ndarray] | None = None, region=None) -> PoseSet:
    """The plausible set from the scripted part's target segment plus the probes' contacts on the target.

    The plausible estimator's fit (:func:`pipeline.estimators.plausible.fit.fit_segment`): the segment's tracked points
    with their recency sigma (every probe contact is a later contact, so they fade), the probes' contacts with
    ``contact_sigma`` x ``probe_growth`` per later probe contact (a probe pushes by millimetres, not centimetres),
    the gripper's free space from the segment's last scripted contact on (every probe's sweep included), and the
    other segments' points and the probes' contacts on something else outside the target.

    Parameters
    ----------
    ee : ndarray, shape (K + 1, 2); steps : ndarray, shape (K,)
        Gripper positions (start, then every action's end) and action indices.
    probe_points : ndarray, shape (P, 2); probe_steps : ndarray, shape (P,); probe_others : ndarray, shape (R, 2)
        Probe contacts attributed to the target, their actions, and the probe contacts attributed to other objects.
    prior : callable, optional
        COM poses (B, 3) -> a prior cost (B,) added to each hypothesis's fit cost before the set is drawn
        (:func:`pipeline.estimators.plausible.fit.fit_segment`; the pushes' prior, :mod:`pipeline.probe.history`).
    region : ((x_min, y_min), (x_max, y_max)), metres, optional
        The scene's target region: where :func:`prior_set` puts its hypotheses when there is nothing to fit.
    """
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    probe_points = np.asarray(probe_points, dtype=np.float64).reshape(-1, 2)
    probe_steps = np.asarray(probe_steps, dtype=np.int64).reshape(-1)
    others = np.vstack([choice.others, np.asarray(probe_others, dtype=np.float64).reshape(-1, 2)])
    if choice.segment < 0 and len(probe_points) == 0:
        return prior_set(target, ee, steps, sdf, plausible, rng, region=region, others=others)
    all_steps = np.concatenate([choice.steps, probe_steps]).astype(np.int64)
    sigma_old = recency_sigma(all_steps, plausible)[:len(choice.steps)]
    later = len(probe_steps) - 1 - np.arange(len(probe_steps))
    sigma = np.concatenate([sigma_old, plausible.contact_sigma * probe_growth ** later])
    pts = np.vstack([choice.points, probe_points])
    centre, radius = target_reach(target, pts)
    after = int(np.max(choice.steps)) if len(choice.steps) else int(np.min(probe_steps)) - 1
    lattice = cached_gripper_lattice(sdf, plausible.free_resolution)
    free = free_space_points(lattice, ee[:-1], ee[1:], steps, after, plausible, centre, radius)
    others = others[np.linalg.norm(others - centre, axis=1) <= radius]
    # At most max_seeds ICP starts besides the random ones: a decision must take well under half a second.
    seeds = choice.seeds[:max_seeds] if len(choice.seeds) else None
    fit = fit_segment(target, pts, sigma, free, others, plausible, rng, seeds, prior)
    cost = fit.terms.total + fit.prior
    keep = np.flatnonzero(fit.plausible)
    w = exp(-(cost[keep] - cost[keep].min()))
    return PoseSet(poses=fit.poses[keep], weights=w / w.sum(), best=int(np.searchsorted(keep, fit.chosen)),
                   segment=choice.segment, notes=[] if choice.segment >= 0 else ["no_segment"],
                   cost=float(cost[keep].min()))


def explaining(target: Primitive, poses: np.ndarray, point: np.ndarray, tolerance: float,
               force: np.ndarray | None = None, max_angle_deg: float = 180.0, corner: float = 0.0) -> np.ndarray:
    """Which hypotheses (COM poses (H, 3)) put their surface within ``tolerance`` (m) of ``point`` (2,): (H,) bool.

    With the contact's ``force`` (2,), N, on the gripper (it pushes the gripper out of the object, along the
    object's outward normal within the friction cone), the hypothesis must also turn its surface there to face
    it: its outward normal within ``max_angle_deg`` of the force, or, where the point lies within ``corner`` (m)
    of one of a box's corners, the corner's normal cone (the quarter turn between its two faces' normals) within
    ``max_angle_deg`` of the force (docs/active.md, "Whose contact (attribution)", "A corner
    faces a quarter turn, not every way")."""
    pp, local, sd, grad = _surface_at(target, poses, point)
    near = np.abs(sd[:, 0]) <= tolerance
    f = None if force is None else np.asarray(force, dtype=np.float64).reshape(2)
    if f is None or not np.all(np.isfinite(f)) or math.hypot(f[0], f[1]) == 0.0 or max_angle_deg >= 180.0:
        return near
    normal = rotate(grad[:, 0, :], pp[:, 2])
    cos = (normal[:, 0] * f[0] + normal[:, 1] * f[1]) / (np.hypot(normal[:, 0], normal[:, 1]) * math.hypot(*f))
    facing = cos >= math.cos(math.radians(max_angle_deg))
    if target.kind == "box" and corner > 0.0:
        hx, hy = target.half[:2]
        d_corner = np.hypot(np.abs(local[:, 0, 0]) - hx, np.abs(local[:, 0, 1]) - hy)
        # the force in each hypothesis's frame, projected on the two outward normals of the nearest corner: inside
        # the cone both projections are >= 0; outside, the nearer normal is the cone's nearest direction
        fl = rotate(f[None, None, :], pp[:, None, 2], inverse=True)[:, 0, :]
        along_x = fl[:, 0] * np.sign(local[:, 0, 0])
        along_y = fl[:, 1] * np.sign(local[:, 0, 1])
        cone_cos = np.where((along_x >= 0.0) & (along_y >= 0.0), 1.0,
                            np.maximum(along_x, along_y) / math.hypot(f[0], f[1]))
        facing |= (d_corner <= corner) & (cone_cos >= math.cos(math.radians(max_angle_deg)))
    return near & facing


def surface_distance(target: Primitive, poses: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Distance (m) from ``point`` (2,) to the surface of the target at each COM pose (H, 3) or (3,): (H,)."""
    return np.abs(_surface_at(target, poses, point)[2][:, 0])


def _surface_at(target: Primitive, poses: np.ndarray, point: np.ndarray):
    """(primitive poses (H, 3), the point in each one's frame (H, 1, 2), signed distance (H, 1), its gradient
    (H, 1, 2)) of ``point`` (2,) against the target at the COM poses (H, 3)."""
    pp = primitive_pose(target, np.asarray(poses, dtype=np.float64).reshape(-1, 3))
    local = rotate(np.asarray(point, dtype=np.float64)[None, None, :] - pp[:, None, :2], pp[:, None, 2],
                   inverse=True)
    sd, grad = primitive_sdf(target, local)
    return pp, local, sd, grad


def prior_set(target: Primitive, ee: np.ndarray, steps: np.ndarray, sdf, plausible: PlausibleParams,
              rng: np.random.Generator, n: int = 48, reach: float = 0.25, region=None, others=None) -> PoseSet:
    """A set when no segment fits the target (no contact yet, or none accepted): poses uniform, any yaw, equally
    likely, kept clear of the space the gripper swept and of the contacts on other objects ``others`` (M, 2) (all
    kept when fewer than four are; ``notes`` = ``no_segment``), within ``reach`` of the visited positions' centroid,
    or in ``region`` ((x_min, y_min), (x_max, y_max), m: the scene's target region), where four times as many are
    drawn, for the rummage swept much of it."""
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    if region is None:
        centre = ee.mean(axis=0)
        cand = np.column_stack([centre + rng.uniform(-reach, reach, (4 * n, 2)), rng.uniform(-np.pi, np.pi, 4 * n)])
        radius = reach + 0.2
    else:
        low, high = np.asarray(region[0], dtype=np.float64), np.asarray(region[1], dtype=np.float64)
        centre = (low + high) / 2.0
        cand = np.column_stack([rng.uniform(low, high, (16 * n, 2)), rng.uniform(-np.pi, np.pi, 16 * n)])
        radius = math.hypot(*(high - low)) / 2.0 + 0.2
    lattice = cached_gripper_lattice(sdf, 2 * plausible.free_resolution)
    # the target is not where the gripper swept, nor where another object was touched (the heavy target stays)
    taken = np.vstack([free_space_points(lattice, ee[:-1], ee[1:], np.asarray(steps), -1, plausible, centre, radius),
                       np.zeros((0, 2)) if others is None else np.asarray(others, dtype=np.float64).reshape(-1, 2)])
    if len(taken):
        local = rotate(taken[None, :, :] - target.centre_world(cand)[:, None, :], (cand[:, 2] + target.yaw)[:, None],
                       inverse=True)
        sd, _ = primitive_sdf(target, local)
        clear = sd.min(axis=1) > -plausible.free_tolerance
        if clear.sum() >= 4:
            cand = cand[clear]
    cand = cand[:n]
    return PoseSet(poses=cand, weights=np.full(len(cand), 1.0 / len(cand)), best=0, segment=-1,
                   notes=["no_segment"])
