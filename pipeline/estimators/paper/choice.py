"""The paper's pose estimator (§V-C): ICP restarts on every segment, the lowest position variance picks the
segment, the least penetration of the gripper's visited poses then the lowest ICP error picks the pose."""
from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.estimators.paper.icp import IcpResult, icp_restarts, initial_transforms
from pipeline.estimators.paper.icp_kernel import clearance_kernel, warm_up
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.target_model import model_normals, model_points
from pipeline.geometry import Primitive, apply_pose
from pipeline.portable import tie_key
from pipeline.schema.retrieval import CANDIDATE_FIELDS, run_candidates

__all__ = ["min_clearance", "Choice", "choose_segment", "confidence_notes", "smallest_principal_std", "Estimate",
           "estimate_run", "nonempty", "icp_segment", "assemble"]


def min_clearance(sdf, model: np.ndarray, poses: np.ndarray, ee: np.ndarray) -> np.ndarray:
    """Smallest pxpen of the posed model points against every visited gripper position.

    Parameters
    ----------
    sdf : pipeline.robot.GridSDF
        The gripper grid; pxpen(x, p) = sdf.query(p - x).
    model : ndarray, shape (N, 2)
        Model points, COM frame.
    poses : ndarray, shape (B, 3)
        Candidate object poses.
    ee : ndarray, shape (K, 2)
        Gripper positions visited in the run.

    Returns
    -------
    ndarray, shape (B,), metres
        min over (k, n) of sdf(pose(model_n) - ee_k); negative = the pose penetrates the gripper somewhere it
        has been; ``sdf.outside_value`` when no model point comes near any gripper position.

    Only the (pose, gripper position) pairs whose boxes overlap the grid are queried: a pair whose posed model
    points all fall outside the grid around that gripper position gives ``outside_value`` anyway, so the result
    is exactly that of querying every pair (the online estimator calls this at every in-contact step).
    """
    world = apply_pose(np.asarray(poses, dtype=np.float64), np.asarray(model, dtype=np.float64))  # (B, N, 2)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    out = np.full(world.shape[0], float(sdf.outside_value))
    if len(ee) == 0 or world.shape[0] == 0 or world.shape[1] == 0:
        return out
    # The grid's cells span [origin - res/2, origin + (n - 1/2) res]; one more cell of margin on each side keeps
    # every pair the nearest-cell rounding could put inside (a superset, so the minimum is unchanged).
    lo = np.asarray(sdf.origin, dtype=np.float64) - 1.5 * sdf.resolution
    hi = lo + sdf.resolution * (np.asarray(sdf.values.shape, dtype=np.float64) + 2.0)
    # pose b can reach the grid around ee_k only if its box [wmin, wmax] overlaps [ee_k + lo, ee_k + hi]
    wmin, wmax = world.min(axis=1), world.max(axis=1)  # (B, 2)
    near = np.all((wmax[:, None, :] >= ee[None] + lo) & (wmin[:, None, :] <= ee[None] + hi), axis=2)  # (B, K)
    if near.any():
        # sdf.query over the near pairs, compiled (the same lookups and minimum: tests/test_online.py).
        values, shape, strides, origin, resolution = sdf.kernel_arrays()
        out = clearance_kernel(np.ascontiguousarray(world), ee, near, values, shape, strides, origin,
                               float(resolution), float(sdf.outside_value))
    return out


@dataclass(frozen=True)
class Choice:
    """Which segment and which restart the selection rule picked.

    Attributes
    ----------
    segment_index : int
        Index into the list of segments given to :func:`choose_segment` (-1 if none).
    restart : int
        Restart of that segment (-1 if none).
    position_var : ndarray, shape (S,), m^2
        Per segment: unbiased variance of the restarts' estimated positions (x plus y), over the valid
        restarts that agree (see :func:`choose_segment`); inf when fewer than 2 are valid.
    rank : list of ndarray
        Per segment, each restart's rank under (excess penetration, ICP RMSE) (0 = best; invalid last).
    """

    segment_index: int
    restart: int
    position_var: np.ndarray
    rank: list[np.ndarray]


def choose_segment(centres: Sequence[np.ndarray], penetration: Sequence[np.ndarray], rmse: Sequence[np.ndarray],
           valid: Sequence[np.ndarray], tolerance: float, fit_gate: float | None = None,
           agreement: float | None = None) -> Choice:
    """The paper's selection rule over S segments of B restarts each.

    1. The segment with the lowest variance of the estimated positions (``centres``) wins; ties go to the
       segment listed first. The variance is over the valid restarts, or with ``agreement`` over those whose
       ICP error is within ``agreement`` of the segment's best (all valid ones if fewer than two are). With
       ``fit_gate``, only segments whose best valid restart has an ICP error <= fit_gate compete, unless none
       has.
    2. Within it, the restart that penetrates the visited gripper poses least: excess penetration
       max(0, penetration - tolerance), then on ties the lowest ICP error, then the lowest restart index.

    Parameters
    ----------
    centres : sequence of ndarray, shape (B, 2)
        Estimated positions (of the primitive centre, so a symmetric shape's arbitrary yaw adds no variance).
    penetration : sequence of ndarray, shape (B,), metres
        max(0, -min_clearance).
    rmse : sequence of ndarray, shape (B,)
        ICP error of each restart.
    valid : sequence of ndarray, shape (B,), bool
    tolerance : float, metres
    fit_gate : float or None, metres
    agreement : float or None, metres
    """
    var = np.full(len(centres), np.inf)
    best_err = np.full(len(centres), np.inf)
    ranks = []
    for s, (c, pen, err, ok) in enumerate(zip(centres, penetration, rmse, valid)):
        ok = np.asarray(ok, dtype=bool)
        if ok.any():
            best_err[s] = float(np.min(np.asarray(err)[ok]))
        use = ok
        if agreement is not None and ok.any():
            near = ok & (np.asarray(err) <= best_err[s] + agreement)
            use = near if near.sum() >= 2 else ok
        if use.sum() >= 2:
            var[s] = float(np.var(np.asarray(c)[use], axis=0, ddof=1).sum())
        excess = np.maximum(np.asarray(pen) - tolerance, 0.0)
        key0 = np.where(ok, excess, np.inf)
        # Restarts that converged to one minimum differ in the last bits: ties within 1e-9 m go to the index.
        order = np.lexsort((np.arange(len(ok)), tie_key(np.where(ok, err, np.inf), 1e-9), tie_key(key0, 1e-9)))
        rank = np.empty(len(ok), dtype=np.int64)
        rank[order] = np.arange(len(ok))
        ranks.append(rank)
    if not len(centres):
        return Choice(-1, -1, var, ranks)
    eligible = np.isfinite(best_err)
    if fit_gate is not None and np.any(best_err <= fit_gate):
        eligible &= best_err <= fit_gate
    pool = np.where(eligible, var, np.inf)
    if np.isfinite(pool).any():
        s_best = int(np.flatnonzero(pool == pool[np.isfinite(pool)].min())[0])
    elif eligible.any():
        # No eligible segment has two valid restarts: the first with any valid one.
        s_best = int(np.flatnonzero(eligible)[0])
    else:
        s_best = 0
    return Choice(s_best, int(np.argmin(ranks[s_best])), var, ranks)


def smallest_principal_std(points: np.ndarray) -> float:
    """Smallest principal standard deviation (metres) of points (M, 2), M >= 1: the square root of the smaller
    eigenvalue of their scatter matrix over M (closed form, no LAPACK: docs/evaluation.md)."""
    d = points - points.mean(axis=0)
    a, b, c = (float(np.sum(d[:, 0] * d[:, 0])), float(np.sum(d[:, 0] * d[:, 1])),
               float(np.sum(d[:, 1] * d[:, 1])))
    low = 0.5 * (a + c) - math.hypot(0.5 * (a - c), b)
    return math.sqrt(max(low, 0.0) / len(points))


def confidence_notes(points: np.ndarray | None, rmse: float, penetration: float, params: RetrievalParams) -> list[str]:
    """Why an estimate should not be trusted (empty list: confident).

    ``no_points`` (empty segmentation), ``few_points`` (fewer than ``min_points``), ``collinear`` (smallest
    principal standard deviation below ``collinear_tolerance``: the pose can slide along the line),
    ``poor_fit`` (ICP RMSE above ``max_rmse``: the points are not on the target's shape, e.g. a segment of
    another object), ``penetrating`` (the chosen pose penetrates a visited gripper pose deeper than
    ``penetration_tolerance``).
    """
    if points is None or len(points) == 0:
        return ["no_points"]
    notes: list[str] = []
    if len(points) < params.min_points:
        notes.append("few_points")
    if len(points) >= 2:
        if smallest_principal_std(points) < params.collinear_tolerance:
            notes.append("collinear")
    if not (rmse <= params.max_rmse):
        notes.append("poor_fit")
    if penetration > params.penetration_tolerance:
        notes.append("penetrating")
    return notes


@dataclass
class Estimate:
    """Pose estimate of one run and the candidates behind it.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Target COM pose (x, y, yaw), canonical under the target's symmetry; finite even without points (then
        the last gripper position, yaw 0, flagged ``no_points``).
    segment : int
        Chosen segment id (-1 if none).
    n_points, n_segments : int
    position_var : float, m^2
        Variance of the chosen segment's restart positions (inf if undefined).
    rmse, penetration : float, metres
    notes : list of str
        Low-confidence reasons (:func:`confidence_notes`).
    candidates : dict of ndarray
        Columns of the candidates table for this run, built from its spec by
        :func:`pipeline.schema.retrieval.run_candidates`.
    icp_s : float
        Wall time of model sampling, ICP, scoring and choice.
    """

    pose: np.ndarray
    segment: int
    n_points: int
    n_segments: int
    position_var: float
    rmse: float
    penetration: float
    notes: list[str]
    candidates: dict[str, np.ndarray]
    icp_s: float

    @property
    def low_confidence(self) -> bool:
        return bool(self.notes)


def estimate_run(segments: Sequence[tuple[int, np.ndarray]], target: Primitive, ee: np.ndarray, sdf,
                 params: RetrievalParams, rng_model: np.random.Generator, rng_restarts: np.random.Generator
                 ) -> Estimate:
    """Estimate the target pose from the segments of one run.

    Parameters
    ----------
    segments : sequence of (segment id, ndarray (M_s, 2))
        Final tracked points of each segment, world metres.
    target : Primitive
    ee : ndarray, shape (K, 2)
        Gripper positions visited in the run.
    sdf : GridSDF
        Gripper grid for pxpen.
    params : RetrievalParams
    rng_model, rng_restarts : numpy.random.Generator

    Returns
    -------
    Estimate
    """
    warm_up()  # compile or load the kernels before the clock starts (as the tracker does)
    t0 = time.perf_counter()
    model = model_points(target, params, rng_model)
    normals = model_normals(target, model)
    ee = np.asarray(ee, dtype=np.float64).reshape(-1, 2)
    segs = nonempty(segments)
    results = [icp_segment(pts, model, normals, params, rng_restarts) for _, pts in segs]
    pens = [np.maximum(-min_clearance(sdf, model, res.poses, ee), 0.0) for res in results]
    choice = choose_segment([target.centre_world(r.poses) for r in results], pens, [r.rmse for r in results],
                            [r.valid for r in results], params.penetration_tolerance, params.segment_fit_gate,
                            params.agreement_tolerance)
    return assemble(segs, results, pens, choice, target, ee, params, t0)


def nonempty(segments: Sequence[tuple[int, np.ndarray]]) -> list[tuple[int, np.ndarray]]:
    """(segment id, points (M, 2) float64) of the segments with at least one point, in the given order."""
    segs = [(int(s), np.asarray(p, dtype=np.float64).reshape(-1, 2)) for s, p in segments]
    return [(s, p) for s, p in segs if len(p) > 0]


def icp_segment(points: np.ndarray, model: np.ndarray, normals: np.ndarray, params: RetrievalParams,
                rng: np.random.Generator, warm: np.ndarray | None = None) -> IcpResult:
    """ICP of one segment's points (M, 2) from ``params.n_restarts`` random initial transforms drawn from
    ``rng`` (:func:`~pipeline.estimators.paper.icp.initial_transforms`); with ``warm`` (a world -> model transform (3,),
    the authors' ``best_tsf_guess``) restart 0 starts from it instead (all restarts are still drawn, so the
    stream does not depend on it)."""
    inits = initial_transforms(points, model, params.n_restarts, rng)
    if warm is not None:
        inits[0] = warm
    return icp_restarts(points, model, inits, params, normals)


def assemble(segs: Sequence[tuple[int, np.ndarray]], results: Sequence[IcpResult], pens: Sequence[np.ndarray],
             choice: Choice, target: Primitive, ee: np.ndarray, params: RetrievalParams, t0: float) -> Estimate:
    """The :class:`Estimate` of a choice among the ICP results of ``segs`` (one :class:`IcpResult` and one
    penetration array (B,) per segment): its candidates table, pose, notes; ``icp_s`` counted from ``t0``
    (``time.perf_counter``). Without a segment: the last gripper position, yaw 0, flagged ``no_points``."""
    B = params.n_restarts
    cand: dict[str, list] = {k: [] for k in CANDIDATE_FIELDS}
    for i, ((sid, pts), res) in enumerate(zip(segs, results)):
        cand["segment"].append(np.full(B, sid))
        cand["restart"].append(np.arange(B))
        cand["n_points"].append(np.full(B, len(pts)))
        cand["x_m"].append(res.poses[:, 0])
        cand["y_m"].append(res.poses[:, 1])
        cand["yaw_rad"].append(res.poses[:, 2])
        cand["icp_rmse_m"].append(res.rmse)
        cand["penetration_m"].append(pens[i])
        cand["valid"].append(res.valid)
        v = choice.position_var[i]
        cand["position_var_m2"].append(np.full(B, v if math.isfinite(v) else np.nan))
        cand["rank"].append(choice.rank[i])
        cand["segment_chosen"].append(np.full(B, i == choice.segment_index))
        cand["chosen"].append((np.arange(B) == choice.restart) & (i == choice.segment_index))
    candidates = run_candidates(**{k: (np.concatenate(v) if v else np.zeros(0)) for k, v in cand.items()})
    if choice.segment_index < 0:
        pose = np.array([ee[-1, 0], ee[-1, 1], 0.0]) if len(ee) else np.zeros(3)
        return Estimate(pose=pose, segment=-1, n_points=0, n_segments=0, position_var=math.inf, rmse=math.nan,
                        penetration=0.0, notes=["no_points"], candidates=candidates,
                        icp_s=time.perf_counter() - t0)
    i, b = choice.segment_index, choice.restart
    pts = segs[i][1]
    pose = target.canonical(results[i].poses[b])
    rmse = float(results[i].rmse[b])
    pen = float(pens[i][b])
    var = float(choice.position_var[i])
    notes = confidence_notes(pts, rmse, pen, params)
    if not results[i].valid[b]:
        notes.append("no_valid_icp")
    return Estimate(pose=pose, segment=segs[i][0], n_points=len(pts), n_segments=len(segs), position_var=var,
                    rmse=rmse, penetration=pen, notes=notes, candidates=candidates, icp_s=time.perf_counter() - t0)
