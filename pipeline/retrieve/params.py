"""Parameters of the paper's pose estimation (paper §V-C): ICP, model points, the choice and its tolerances.

docs/retrieval.md gives the measurements behind the defaults.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["RetrievalParams", "MAX_COUNT"]

#: Largest restart, model point, iteration or point count accepted.
MAX_COUNT = 1000


@dataclass(frozen=True)
class RetrievalParams:
    """Parameters of pose estimation (paper §V-C, docs/retrieval.md); serialised into the metadata.

    Attributes
    ----------
    n_restarts : int
        ICP restarts per segment (30).
    estimation : {"point_to_plane", "point_to_point"}
        Open3D estimator. The authors' ICP was point-to-point; with 50 model points ~9 mm apart it locks
        every tracked point to a model point and stops one spacing away from the truth (on FB seed 0's box,
        1 of 30 restarts within 5 mm and 0.05 rad), while point-to-plane onto the same points with their
        analytic normals slides along the faces (19 of 30, 0.2 mm). "point_to_plane" (default) runs
        point-to-point, then point-to-plane from its result, keeping the point-to-point result when the
        refinement slides off the model.
    n_box_points, n_can_points : int
        Model points on a box outline (50) and around a can (49: 50 evenly spaced angles on [0, 2 pi], the
        duplicate end dropped, as the authors' ``sample_in_order``).
    box_sampling : {"perimeter", "tester"}
        "perimeter": evenly spaced along the outline from a random start (every face gets its share).
        "tester": the authors' rule (testers ~ N(0, tester_sigma^2) projected onto the outline, rejected within
        min_separation of an accepted point), which puts about 40 of 50 points on the long faces and most of
        the rest at the corners, leaving the short faces nearly empty.
    tester_sigma : float, metres
        "tester" sampling spread (0.1).
    min_separation : float, metres
        "tester" sampling separation (0.002).
    max_iteration : int
        ICP iterations per restart (Open3D's default 30; the authors stopped at 20).
    max_correspondence_distance : float, metres
        Open3D's correspondence radius; large, so every tracked point gets its nearest model point like the
        authors' all-pairs matching.
    max_point_distance : float, metres
        An ICP result whose points are farther than this (median) from the model points is not used (0.05):
        with few points, point-to-plane ICP can slide them along tangent planes off the model.
    penetration_tolerance : float, metres
        Penetration of the gripper's visited poses up to this depth counts as none when choosing (ties then
        go to the lowest ICP error), and a chosen pose penetrating deeper is flagged "penetrating" (0.01).
        Not the tracker's 2 mm: objects move and tilt after the gripper has been somewhere, and the planar
        pose cannot show it. The 10 kg cracker box tilts when pushed at the gripper's height (tipping moment
        3.0 N m against 3.1 N m restoring), the run files keep only (x, y, yaw), and the true final pose of
        FB seed 0 reads 8-9 mm inside gripper poses visited while it was tilted; with 2 mm, poses that fit
        the contacts badly but touch no visited pose (12 mm RMSE, 5 cm off) beat the true pose.
    agreement_tolerance : float or None, metres
        The position variance that picks the segment is over the restarts whose ICP error is within this of
        the segment's best (0.002); None: over all 30, as the paper. Restarts that stopped in another local
        minimum say nothing about where the object is, yet dominate the variance of all 30: on FB seeds
        0-9 with ideal contact points (docs/retrieval.md) the pose came within 2 cm and 0.2 rad in 6 of 10
        runs with 0.002 and in 3 of 10 with None (the can's segment chosen instead); on STUCCO's segments
        5 of 10 either way.
    segment_fit_gate : float, metres
        A segment whose best restart has an ICP error above this cannot be the target while another segment
        fits (0.02). Not in the paper: a straight run of points (a wall, a segment far from the target) fits
        one side of a box the same way from every restart, so its position variance is the lowest.
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
    robot: str = "panda"
    min_points: int = 3
    collinear_tolerance: float = 0.002
    max_rmse: float = 0.005

    def __post_init__(self) -> None:
        for name in ("n_restarts", "n_box_points", "n_can_points", "max_iteration", "min_points"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
            if v > MAX_COUNT:  # every one is an ICP run or model point per segment: a bound on time and memory
                raise ValueError(f"{name} must be at most {MAX_COUNT}, got {v!r}")
        if self.estimation not in ("point_to_plane", "point_to_point"):
            raise ValueError(f"estimation must be 'point_to_plane' or 'point_to_point', got {self.estimation!r}")
        if self.box_sampling not in ("perimeter", "tester"):
            raise ValueError(f"box_sampling must be 'perimeter' or 'tester', got {self.box_sampling!r}")
        for name in ("tester_sigma", "max_correspondence_distance", "max_rmse", "segment_fit_gate",
                     "max_point_distance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number (metres), got {v!r}")
        if self.agreement_tolerance is not None and not (math.isfinite(self.agreement_tolerance)
                                                         and self.agreement_tolerance >= 0):
            raise ValueError(f"agreement_tolerance must be None or a non-negative number (metres), "
                             f"got {self.agreement_tolerance!r}")
        for name in ("min_separation", "penetration_tolerance", "collinear_tolerance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a non-negative number (metres), got {v!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
