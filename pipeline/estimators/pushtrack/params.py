"""The parameters of the pushtrack estimator (:mod:`pipeline.estimators.pushtrack.filter` is its filter;
docs/estimators.md, "The pushtrack estimator")."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.constraints import Constraint, Params, integer, number, one_of

__all__ = ["PushTrackParams", "MOTIONS", "SLICE_MOTIONS", "SELECT_RULES", "MAX_PARTICLES"]

#: Most particles: the filter holds (particles, free-space points) arrays per action.
MAX_PARTICLES = 16384
#: The pushing models (``PushTrackParams.motion``).
MOTIONS = ("push", "sweep", "tip", "translate", "static")
#: The pushing models driven by the gripper's slice (:mod:`pipeline.estimators.pushtrack.slice_pusher`).
SLICE_MOTIONS = ("sweep", "tip")
#: The rules by which the estimate is chosen among the refined particles (``PushTrackParams.select``).
SELECT_RULES = ("cost", "posterior", "grasp", "mode", "held_mean")


@dataclass(frozen=True)
class PushTrackParams(Params):
    """Parameters of the pose-tracking estimator; serialised into the retrieval metadata.

    Attributes
    ----------
    n_particles : int
        Particles (512).
    substeps : int
        Integration steps of one push (4): the contact point and normal are re-found on the moved target at each.
    sweep_substeps : int
        Steps of the gripper's sweep over one action's in-contact displacement (``motion`` "sweep" or "tip"; 15).
    sweep_limit_scale : float
        ``limit_scale`` of ``motion`` "sweep" and "tip" (1.5: the scale that fits the simulated pushes best, a box
        resting on its corners; docs/estimators.md, "Pushing models").
    tip_spread, tip_reach : float
        Where a box pushed on a long face turns (``motion`` "tip"): about a point of its leading long edge's line,
        hy * min(1 + tip_spread * hy / |e|, tip_reach) from the edge's middle on the far side from the contact's
        offset e (0.08, 1.27: chosen push by push on training seeds; docs/experiments/tipped-box-centre.md).
    motion : {"push", "sweep", "tip", "translate", "static"}
        "push": the quasi-static pushing model from a point pusher at the contact minus the in-contact displacement;
        "sweep": the same model driven by the gripper's slice swept over the action's in-contact displacement (to
        its end position), the contact found where the slice meets each particle
        (:mod:`pipeline.estimators.pushtrack.slice_pusher`;
        needs ``Actions.gripper``); "tip" (default): the slice, and a box pushed on a long face turns about a point
        of its leading long edge, as a box tipped onto that edge does (docs/estimators.md, "Pushing models");
        "translate": the target moves by the pusher's displacement projected on the contact normal, never
        turns (the tracker's assumption, §VI-A); "static": never moves
        (only the noise). The last two isolate what the pushing model adds (``stucco bench retrieval``).
    friction : float
        Pusher-target friction coefficient of the pushing model (0.5).
    limit_scale : float
        Factor on the limit surface's characteristic length of ``motion`` "push" (1.0: uniform pressure over the
        footprint; larger: the support pressure nearer the footprint's edge, as a rigid box resting on its
        corners).
    trans_noise : float
        Standard deviation of the position noise per metre pushed (0.15), plus ``noise_floor``.
    yaw_noise : float, rad per metre pushed
        Standard deviation of the yaw noise per metre pushed (1.5), plus ``yaw_floor``. Half of what the point
        pusher needs (0.3 and 3.0), since the tipped box is closer per push (docs/estimators.md, "Pushing models").
    noise_floor : float, metres
        Position noise of every push (0.001).
    yaw_floor : float, radians
        Yaw noise of every push (0.01).
    contact_sigma : float, metres
        Standard deviation of a contact point's distance to the surface (0.004: isolation error, tilt).
    outlier_sigmas : float
        Geman-McClure scale of the contact term in sigmas (2.5).
    free_sigma : float, metres
        Scale of the free-space depth (0.003).
    free_tolerance : float, metres
        Depth of the gripper's slice inside the target that costs nothing (0.004).
    free_resolution : float, metres
        Lattice spacing of the gripper's slice (0.01).
    sweep_spacing : float, metres
        Spacing of the gripper poses sampled along an action (0.01).
    free_in_contact : bool
        The sweeps of actions in contact with other segments are free space too; False (default): only the actions
        without contact and the end poses of the target's (a contact of another segment may be the target's).
    free_stretches : bool
        The free space of consecutive actions that do not touch the target, which leave the particles where they
        were, is one observation: each cell of it counted once (True), as the free space before the first touch
        is; False (default): once per action that covered it (docs/estimators.md, "The pushtrack estimator").
    ess_threshold : float
        Resample before a push when the effective sample size falls below this share of the particles (0.5).
    inject : float
        Share of the particles (0.03) replaced at every push, the lowest weights first, by fresh particles on the
        push's contact (the contact manifold: a random outline point on the contact, stratified yaw), weighted
        as the best particle times the likelihood of the earlier contacts where they were observed (sigma grown
        by ``inject_growth`` per later push): a segment's first contacts may be another object's, and walls or
        other objects may move the target in ways the model does not predict.
    other_push : float
        Share of the particles (0: off; 0.5 tried) pushed by an action whose contact is not the target's but lies within
        ``other_reach`` of their surface: the pushing model from that contact (another object pushed into the target,
        or a contact of the target given to another segment); the others stay (docs/experiments/pushtrack-carrying.md).
    other_reach : float, metres
        Distance of another segment's contact from a particle's surface within which it may push it (0.03).
    inject_growth : float
        Factor on an earlier contact's sigma per later push when weighting a fresh particle (1.0: every earlier
        contact counts in full, so a fresh particle wins only where the target stayed put, as against a wall).
    n_refine : int
        Highest-weight particles refined at the end (128; 0: none, the best particle is the estimate): each one's
        contacts, carried along its own trajectory to its final pose, and the gripper's free space after the last
        push, by the plausible estimator's Levenberg-Marquardt
        (:func:`pipeline.estimators.pushtrack.estimator.final_pose`).
    refine_growth : float
        The refinement's factor on a carried contact's sigma per later touching action (1.0: none; the plausible
        estimator's recency growth; it discounted contacts followed only by touches that do not push).
    carry : {"model", "model+noise", "mixed"}
        How a particle's earlier contacts move with it: by the pushing model's displacement ("model"), or by that
        plus the push-length noise ("model+noise": a particle that turned differently from the model carries its
        contacts its own way, as against a wall), or ("mixed", default) half the particles each way, set at the
        start and inherited; never by the noise floors, which only keep the particles diverse.
    refine_spread : float
        The refinement's growth of a carried contact's sigma with the length the target was pushed after it (3.0;
        sigma = hypot(grown sigma, refine_spread x metres pushed since): 1 cm pushed, 3 cm): a contact followed only
        by touches that do not push stays at full weight.
    starts : int
        The filter runs from each of the first ``starts`` contacts of the segment (6; 1: from its first only), the
        segment's contacts before that start taken as another object's, and the run whose evidence
        (``FilterResult.log_evidence``) is highest is kept, each skipped contact charged the contact term's outlier
        level (``outlier_sigmas``² / 2 nats) and any later start ``start_margin``: a segment often begins with
        another object's contacts, and a filter started there loses the target (docs/estimators.md, "Where the filter
        starts").
    start_margin : float, nats
        What a start after the segment's first contact must win by, beyond the skipped contacts' charge (10): more
        than the filter's own evidence varies between random seeds, so that a later start wins on the contacts,
        not on the particles' luck.
    islands : int
        Independent filters run over the same actions from the kept start (4; 1: one filter), pooled before the
        refinement, each island's particles weighted by its share of the islands' summed evidence
        (:func:`pipeline.estimators.pushtrack.estimator.pool_islands`): one filter's resampling often keeps only one
        of the
        modes the contacts allow, and which one is a coin toss of its draws (docs/estimators.md, "Islands").
    select : {"cost", "posterior", "grasp", "mode", "held_mean"}
        Which refined particle is the estimate: the lowest refinement cost ("cost"); the lowest refinement cost
        minus the particle's log-weight ("posterior": the trajectory's evidence counts too); ("grasp")
        the lowest posterior among the particles held by the paper grasp, of those aimed at each refined
        particle, that holds the largest share of the refined set weighted by exp(-posterior) (the Bayes
        decision for the grasp script; docs/estimators.md, "The estimate: the posterior mean of what the grasp holds");
        ("mode")
        the particle whose own paper grasp holds that largest share (measured and not the default, ibid.); or
        (default, "held_mean") the posterior mean of the particles "grasp" chooses among: those that grasp holds
        whose yaw is within ``mean_yaw`` of the "grasp" particle's, weighted by exp(-posterior) (docs/estimators.md,
        "The estimate: the posterior mean of what the grasp holds").
    mean_yaw : float, radians
        Yaw window of "held_mean" around the chosen particle (0.05: the box grasp's tolerance).
    """

    n_particles: int = 512
    substeps: int = 4
    sweep_substeps: int = 15
    sweep_limit_scale: float = 1.5
    tip_spread: float = 0.08
    tip_reach: float = 1.27
    motion: str = "tip"
    friction: float = 0.5
    limit_scale: float = 1.0
    trans_noise: float = 0.15
    yaw_noise: float = 1.5
    noise_floor: float = 0.001
    yaw_floor: float = 0.01
    contact_sigma: float = 0.004
    outlier_sigmas: float = 2.5
    free_sigma: float = 0.003
    free_tolerance: float = 0.004
    free_resolution: float = 0.01
    sweep_spacing: float = 0.01
    free_in_contact: bool = False
    free_stretches: bool = False
    ess_threshold: float = 0.5
    inject: float = 0.03
    other_push: float = 0.0
    other_reach: float = 0.03
    inject_growth: float = 1.0
    n_refine: int = 128
    refine_growth: float = 1.0
    carry: str = "mixed"
    refine_spread: float = 3.0
    starts: int = 6
    start_margin: float = 10.0
    islands: int = 4
    select: str = "held_mean"
    mean_yaw: float = 0.05
    constraints: ClassVar[dict[str, Constraint]] = {
        "n_particles": integer(8, MAX_PARTICLES), "substeps": integer(1, 64), "starts": integer(1, 64),
        "sweep_substeps": integer(1, 256),
        "islands": integer(1, 64),
        "motion": one_of(*MOTIONS), "carry": one_of("model", "model+noise", "mixed"),
        "select": one_of(*SELECT_RULES),
        **{name: number(0, lo_open=True) for name in ("contact_sigma", "outlier_sigmas", "free_sigma",
                                                      "free_resolution", "sweep_spacing", "limit_scale",
                                                      "sweep_limit_scale")},
        "other_push": number(0, 1), "other_reach": number(0), "refine_spread": number(0), "start_margin": number(0),
        "tip_reach": number(1),
        **{name: number(0) for name in ("friction", "tip_spread", "trans_noise", "yaw_noise", "noise_floor",
                                        "yaw_floor", "free_tolerance", "mean_yaw")},
        "ess_threshold": number(0, 1), "inject": number(0, 1), "inject_growth": number(1),
        "n_refine": integer(0, 256), "refine_growth": number(1)}
