"""What the pushes said: a prior over the target's pose after the scripted part, for the probing policy's sets.

The policy's plausible set fits one pose to the points and probe contacts sensed so far (:mod:`.belief`); it has
no memory of how the target was pushed. The ``pushtrack`` estimator
(:mod:`pipeline.estimators.pushtrack.estimator`) tracks
the pose through the scripted part's pushes and rarely mistakes a box for one turned a quarter turn, the pose
the policy's set most often settles on wrongly (docs/active.md, "What the pushes said: a prior from pushtrack"). Run
once on the scripted part's rows, its refined set becomes a prior cost on every hypothesis of the
sets the policy fits to the segment it tracked: flat within ``history_yaw_band`` of the prior's poses' yaws (so the
probes alone decide between nearby yaws) and within ``history_reach`` of their centres, rising beyond, capped at
-log ``history_floor`` (so contacts that contradict the prior still win; :class:`~pipeline.probe.params.ProbeParams`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pipeline.estimators.estimate import Segment
from pipeline.estimators.params import RetrievalParams
from pipeline.estimators.pushtrack.estimator import pushtrack_set
from pipeline.estimators.pushtrack.filter import PushTrackParams
from pipeline.estimators.run_info import info_from_table, retrieval_rng
from pipeline.geometry import Primitive, primitive_pose, wrap_symmetric
from pipeline.portable import exp, log
from pipeline.probe.params import ProbeParams

__all__ = ["HistoryPrior", "history_prior", "PRIOR_PUSHTRACK"]

#: The filter behind the prior: the point pusher and its push noise, with which the prior was chosen and checked
#: (docs/active.md, "What the pushes said: a prior from pushtrack"), and the free space counted once per action
#: that covered it, as when the active protocol's figures were measured; pushtrack's own defaults moved on since.
PRIOR_PUSHTRACK = PushTrackParams(motion="push", trans_noise=0.3, yaw_noise=3.0, free_stretches=False)


@dataclass(frozen=True)
class HistoryPrior:
    """The pushtrack estimator's refined set after the scripted part, as a prior over the target's COM pose.

    Attributes
    ----------
    poses : ndarray, shape (H, 3)
        COM poses (x, y, yaw), metres and radians.
    weights : ndarray, shape (H,)
        Their posterior weights, summing to 1.
    segment : int
        The segment pushtrack tracked (the estimators' choice): the prior is about that segment's object, and only
        the sets fitted to it add it.
    params : ProbeParams
        The prior's shape: ``history_yaw_band``, ``history_yaw_sigma``, ``history_reach``, ``history_reach_sigma``,
        ``history_floor``.
    """

    poses: np.ndarray
    weights: np.ndarray
    segment: int
    params: ProbeParams = ProbeParams()

    def cost(self, target: Primitive, poses: np.ndarray) -> np.ndarray:
        """Prior cost (B,) of COM poses (B, 3), in the plausible fit's units (squared sigmas / 2, nats):
        -log(floor + (1 - floor) * support), the support being the prior's weight near each pose: 0 within the band
        and the reach of the prior's poses, -log(floor) (3.0) far from all of them."""
        p = self.params
        pp = primitive_pose(target, np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        qq = primitive_pose(target, self.poses)
        dpos = np.hypot(pp[:, None, 0] - qq[None, :, 0], pp[:, None, 1] - qq[None, :, 1])
        # (each shoulder's distance in sigmas is clipped at 100, where exp(-z / 2) is 0 anyway: no overflow for poses
        # far off)
        z = np.minimum(np.maximum(dpos - p.history_reach, 0.0) / p.history_reach_sigma, 100.0) ** 2
        if target.symmetry:  # a can's yaw is nothing to go by
            dyaw = np.abs(wrap_symmetric(pp[:, None, 2] - qq[None, :, 2], target.symmetry))
            z = z + np.minimum(np.maximum(dyaw - p.history_yaw_band, 0.0) / p.history_yaw_sigma, 100.0) ** 2
        support = np.sum(exp(-0.5 * z) * self.weights[None, :], axis=1)
        return -log(p.history_floor + (1.0 - p.history_floor) * np.minimum(support, 1.0))


def history_prior(table: pa.Table, segments: Sequence[Segment], scene, run: str, root_seed: int, sdf,
                  params: ProbeParams = ProbeParams()) -> HistoryPrior | None:
    """The prior of the scripted part's rows ``table`` and the tracker's ``segments`` of them: the pushtrack
    estimator's refined set with its default parameters and the retrieve stage's random stream for ``run``
    (:func:`pipeline.estimators.run_info.retrieval_rng`), so it is the set ``stucco retrieve --estimator pushtrack``
    would refine on those rows. None when pushtrack does not filter (no segment, or no isolated contact on it)."""
    if table.num_rows == 0 or not segments:
        return None
    info = info_from_table(table, scene)  # the final poses NaN: no ground truth is read
    found = pushtrack_set(segments, info, sdf, retrieval_rng(root_seed, run), RetrievalParams(), PRIOR_PUSHTRACK,
                          table)
    if found is None:
        return None
    poses, weights = np.asarray(found[0], dtype=np.float64), np.asarray(found[1], dtype=np.float64)
    if len(poses) == 0 or not (np.all(np.isfinite(poses)) and np.all(np.isfinite(weights)) and weights.sum() > 0):
        return None  # (a refinement that failed is no evidence)
    return HistoryPrior(poses, weights / weights.sum(), int(found[2]), params)
