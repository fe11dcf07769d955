"""Parameters of the paper's pose estimation (paper §V-C): ICP, model points, the choice and its tolerances.

docs/estimators.md gives the measurements behind the defaults.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.constraints import Constraint, Params, integer, number, one_of

__all__ = ["RetrievalParams", "MAX_COUNT"]

#: Largest restart, model point, iteration or point count accepted.
MAX_COUNT = 1000


@dataclass(frozen=True)
class RetrievalParams(Params):
    """Parameters of pose estimation (paper §V-C, docs/estimators.md); serialised into the metadata.

    Attributes
    ----------
    n_restarts : int
        ICP restarts per segment (30).
    estimation : {"point_to_plane", "point_to_point"}
        ICP estimator. The authors' ICP was point-to-point; with 50 model points ~9 mm apart it locks
        every tracked point to a model point and stops one spacing away from the truth, while point-to-plane
        onto the same points with their analytic normals slides along the faces (measured in docs/retrieval.md,
        "Deviations from the paper and the authors' code"). "point_to_plane" (default) runs
        point-to-point, then point-to-plane from its result, keeping the point-to-point result when the
        refinement slides off the model.
    n_box_points, n_can_points : int
        Model points on a box outline (50) and around a can (49: 50 evenly spaced angles on [0, 2 pi], the
        duplicate end dropped, as the authors' ``sample_in_order``).
    box_sampling : {"perimeter", "tester"}
        "perimeter": evenly spaced along the outline from a random start (every face gets its share).
        "tester": the authors' rule (testers ~ N(0, tester_sigma^2) projected onto the outline, rejected within
        min_separation of an accepted point), which crowds the long faces and the corners and leaves the short
        faces nearly empty (docs/retrieval.md).
    tester_sigma : float, metres
        "tester" sampling spread (0.1).
    min_separation : float, metres
        "tester" sampling separation (0.002).
    max_iteration : int
        ICP iterations per restart (Open3D's default 30; the authors stopped at 20).
    max_correspondence_distance : float, metres
        ICP correspondence radius; large, so every tracked point gets its nearest model point like the
        authors' all-pairs matching.
    max_point_distance : float, metres
        An ICP result whose points are farther than this (median) from the model points is not used (0.05):
        with few points, point-to-plane ICP can slide them along tangent planes off the model.
    penetration_tolerance : float, metres
        Penetration of the gripper's visited poses up to this depth counts as none when choosing (ties then
        go to the lowest ICP error), and a chosen pose penetrating deeper is flagged "penetrating" (0.01).
        Not the tracker's 2 mm: objects move and tilt after the gripper has been somewhere, the run files keep
        only (x, y, yaw), so a true pose can read inside gripper poses visited while the object was tilted
        (docs/retrieval.md, "Deviations from the paper": penetration ties).
    agreement_tolerance : float or None, metres
        The position variance that picks the segment is over the restarts whose ICP error is within this of
        the segment's best (0.002); None: over all 30, as the paper. Restarts that stopped in another local
        minimum say nothing about where the object is, yet dominate the variance of all 30
        (docs/retrieval.md, "Deviations from the paper": position variance over agreeing restarts).
    segment_fit_gate : float, metres
        A segment whose best restart has an ICP error above this cannot be the target while another segment
        fits (0.02). Not in the paper: a straight run of points (a wall, a segment far from the target) fits
        one side of a box the same way from every restart, so its position variance is the lowest.
    heavy_target_kg : float or None, kg
        The estimators that refine the paper's choice (``plausible``, ``pushtrack``, the probing policy) take the
        segment whose contacts met the largest median force when the target's known mass is at least this (1.0;
        None: the paper's choice always; :mod:`pipeline.estimators.segment_choice`). The ``paper`` estimator ignores it.
    robot : str
        Gripper grid for pxpen (:func:`pipeline.robot.load_robot`).
    min_points : int
        Fewer points in the chosen segment -> low confidence ("few_points").
    collinear_tolerance : float, metres
        Chosen segment whose smallest principal standard deviation is below this -> "collinear" (a pose
        from points on one line can slide along it).
    max_rmse : float, metres
        Chosen pose with a larger ICP RMSE -> "poor_fit" (points that are not on the target's shape).
    """

    n_restarts: int = 30
    estimation: str = "point_to_plane"
    n_box_points: int = 50
    n_can_points: int = 49
    box_sampling: str = "perimeter"
    tester_sigma: float = 0.1
    min_separation: float = 0.002
    max_iteration: int = 30
    max_correspondence_distance: float = 1.0
    max_point_distance: float = 0.05
    penetration_tolerance: float = 0.01
    agreement_tolerance: float | None = 0.002
    segment_fit_gate: float = 0.02
    heavy_target_kg: float | None = 1.0
    robot: str = "panda"
    min_points: int = 3
    collinear_tolerance: float = 0.002
    max_rmse: float = 0.005
    constraints: ClassVar[dict[str, Constraint]] = {
        # MAX_COUNT: every one is an ICP run or model point per segment, a bound on time and memory.
        **{name: integer(1, MAX_COUNT) for name in ("n_restarts", "n_box_points", "n_can_points", "max_iteration",
                                                    "min_points")},
        "estimation": one_of("point_to_plane", "point_to_point"), "box_sampling": one_of("perimeter", "tester"),
        **{name: number(0, lo_open=True) for name in ("tester_sigma", "max_correspondence_distance", "max_rmse",
                                                      "segment_fit_gate", "max_point_distance")},
        "agreement_tolerance": number(0, nullable=True), "heavy_target_kg": number(0, nullable=True),
        **{name: number(0) for name in ("min_separation", "penetration_tolerance", "collinear_tolerance")}}
