"""The plausible estimator's parameters (docs/estimators.md, "The plausible estimator"; the fit:
:mod:`pipeline.estimators.plausible.fit`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.constraints import Constraint, Params, integer, number, one_of

__all__ = ["PlausibleParams", "MAX_HYPOTHESES"]

#: Most hypotheses (or iterations) per segment of the plausible estimator.
MAX_HYPOTHESES = 4096


@dataclass(frozen=True)
class PlausibleParams(Params):
    """Parameters of the plausible-set estimator; serialised into the retrieval metadata.

    Attributes
    ----------
    n_hypotheses : int
        SE(2) starts per segment (32): stratified yaw, the points' centroid on a random point of the outline.
    iterations : int
        Levenberg-Marquardt iterations per start (30).
    contact_sigma : float, metres
        Standard deviation of a contact point observed at the segment's last contact (0.003).
    recency_growth : float
        Factor on sigma per later contact of the same segment (2.0; 1.0 = every point alike).
    max_sigma : float, metres
        Cap on a point's sigma (1.0: none).
    outlier_sigmas : float
        Geman-McClure scale in sigmas: a point farther than this from the surface costs at most c^2 / 2 (3.0).
    free_resolution : float, metres
        Lattice spacing of the gripper points of the free-space term (0.005).
    free_tolerance : float, metres
        Penetration of the gripper's free space up to this depth costs nothing (0.003): objects tilt, the
        recorded poses are planar.
    free_weight : float
        Weight of the free-space and other-segment terms (1.0).
    sweep_spacing : float, metres
        Spacing of the gripper poses sampled along each free action (0.01).
    other_tolerance : float, metres
        Depth of another segment's point inside the target that costs nothing (0.005).
    margin : float
        Plausible set: hypotheses whose cost is within this of the best (2.0, in squared sigmas).
    yaw_agreement : float, radians
        Hypotheses agree on a grasp when their yaws differ by less than this (0.05, the grasp's tolerance).
    min_share : float
        Below this share of the plausible set agreeing on the grasp yaw -> ``ambiguous_yaw`` (0.5).
    max_spread : float, metres
        Above this spread (RMS distance from their mean) of the agreeing poses' positions -> ``wide_set`` (0.02).
    pose_rule : {"uniform", "best", "vote"}
        "best" (default): the set's lowest-cost pose. "uniform": the plausible pose whose cost with one sigma for
        every point (``uniform_sigma``) is lowest: recency decides what is plausible, every contact picks within
        it. "vote": the yaw most of the set agrees on (each pose voting with its likelihood relative to the
        best), then that group's lowest-cost pose. Measured on the training seeds in
        docs/experiments/plausible-defaults.md.
    uniform_sigma : float, metres
        The one sigma of the "uniform" rule (0.005).
    icp_seeds : bool
        Also start from the paper's ICP results on the segment (True): ICP's local minima are starts the random
        ones can miss.
    """

    n_hypotheses: int = 32
    iterations: int = 30
    contact_sigma: float = 0.003
    recency_growth: float = 2.0
    max_sigma: float = 1.0
    outlier_sigmas: float = 3.0
    free_resolution: float = 0.005
    free_tolerance: float = 0.003
    free_weight: float = 1.0
    sweep_spacing: float = 0.01
    other_tolerance: float = 0.005
    margin: float = 2.0
    yaw_agreement: float = 0.05
    min_share: float = 0.5
    max_spread: float = 0.02
    pose_rule: str = "best"
    uniform_sigma: float = 0.005
    icp_seeds: bool = True
    constraints: ClassVar[dict[str, Constraint]] = {
        # MAX_HYPOTHESES: (hypotheses, points) residual arrays per start and segment.
        **{name: integer(1, MAX_HYPOTHESES) for name in ("n_hypotheses", "iterations")},
        **{name: number(0, lo_open=True) for name in ("contact_sigma", "max_sigma", "outlier_sigmas",
                                                      "free_resolution", "sweep_spacing", "yaw_agreement",
                                                      "max_spread", "uniform_sigma")},
        **{name: number(0) for name in ("free_tolerance", "free_weight", "other_tolerance", "margin")},
        "recency_growth": number(1), "min_share": number(0, 1), "pose_rule": one_of("best", "vote", "uniform")}
