"""The probing policy's parameters and its record of one run (docs/active.md): what
:mod:`pipeline.probe.policy` is asked to do and what it did, both serialised into the run file's metadata."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar

from pipeline.constraints import Constraint, Params, integer, number, rule
from pipeline.probe.planning import PlanParams

__all__ = ["ProbeParams", "ProbeLog"]


@dataclass(frozen=True)
class ProbeParams(Params):
    """Parameters of the probing policy; serialised into the run file's metadata.

    Attributes
    ----------
    budget : int
        Most probes per run (12; 8 before: a set still wide after 8 probes is usually settled by the next few,
        docs/experiments/probe-budget.md).
    min_probes : int
        Probes made even if the set agrees from the start (0): a confident set can be confidently wrong.
    coarse_step, fine_step : float, metres
        Step of the guarded move far from and near the predicted contacts (0.02, 0.004).
    slow_zone : float, metres
        Fine steps from this far before the earliest predicted contact (0.03).
    overshoot : float, metres
        Give up this far past the latest predicted contact (0.04).
    backoff : float, metres
        Retreat after a contact (0.015).
    transit_step : float, metres
        Longest action of a transit (0.03, the scripted actions' scale).
    attribute_tolerance : float, metres
        A probe contact is the target's if some hypothesis's surface passes this close (0.025).
    attribute_angle_deg : float, degrees
        ... and turns its outward normal there within this angle of the contact force (60; 180: position only),
    attribute_corner : float, metres
        ... or puts one of a box's corners within this distance of it with the corner's normal cone (the quarter
        turn between its faces' normals) within that angle of the force (0.015).
    misfit_tolerance : float, metres
        When the probe contacts attributed to the target lie farther than this (median) from the set's estimate,
        the segment is not the target's: the next-ranked one is taken (0.006).
    stall : int
        Probes after which a segment whose set still does not agree gives way to the next-ranked one (99: never;
        4 switched right segments away on the training seeds, docs/experiments/active-segment-choice.md).
    unsupported : int
        Probes after which a segment's set that no probe contact has been attributed to gives way to the
        next-ranked segment, or to the no-segment prior after the last (0: never; 6 gained three generated
        training runs of 40 and lost a paper task's, docs/experiments/generated-scenes.md, section 25).
    min_span : float
        For a box, the set is trusted only once the target's probe contacts span this share of its long side
        (0.6); until then the next probe goes where the estimate predicts contact farthest from them.
    min_target_contacts : int
        The set agrees only once this many probe contacts are the target's (3 for a box, one fewer for a can):
        the scripted part's points have drifted, so a set resting on them alone is not trusted.
    light_contact_n : float, N
        For a heavy target (its known mass at least ``RetrievalParams.heavy_target_kg``), a probe contact that met
        less force than this (the sensed wrench, :func:`pipeline.detection.contact_forces`) is another object's
        whatever the set says: the heavy target does not give way at a few newtons, the household clutter does
        (5.0; 0: off; docs/active.md, "Whose contact (attribution)").
    light_refutations : int
        After this many probe actions with such a light contact that the set explained (it put the target there),
        the segment is not the target's: the next-ranked one is taken (2; 0: never).
    push_through : float, metres
        How far a probe's guarded move, and its transit to the probe's start, go on pushing what they met while
        the contact stays light (``light_contact_n``): the clutter round a hidden target moves at a few newtons,
        and a probe that stops at the first can spends itself on the clutter. The push's first contact is a probe
        contact (light, so another object's); the contacts of the object carried after it are not (it moves on);
        the contact that stops the push is one, and is another object's when it lies where the carried object
        touched the hand (``pinned_within``): the carried object pinned against something heavy (0: off, every
        probe stops at its first contact; docs/active.md, "Pushing light clutter aside").
    pinned_within : float, metres
        A contact that stops a push is the carried object's when it lies within this distance of the carried
        object's last contact, in the gripper's frame (0.015).
    light_scripted_n : float, N
        The same rule on the scripted part: its tracked points whose action met less than this are the clutter's,
        left out of the segments the target is chosen from and fitted to, kept as obstacles
        (:func:`pipeline.probe.attribution.heavy_choices`; 5.0; 0: off), the probes' limit too.
    prior_clear_of_others : bool
        Under the no-segment prior, no hypothesis holds a point of a segment set aside, and the planned grasp takes
        them as obstacles (:func:`pipeline.probe.attribution.no_target`; True; runs probed before: False).
    switch_probes : int
        Probes of its own for a segment taken when the budget is spent (:func:`give_way_at_budget`), beyond
        the budget: its set rests on the scripted part's drifted points otherwise.
    clutter_cost : float, squared sigmas
        A probe contact that some hypotheses of the set explain and others do not is the target's only if the set
        fitted with it as the target's costs less than this more than with it as another object's (0.3;
        docs/active.md, "Whose contact (attribution)").
    reattribute : str
        Whether a probe contact once attributed to another object is tried again at later decisions against the
        set then (``fit``: by the rule above, or by its cost alone where no hypothesis explains it; ``explained``:
        only where some hypothesis does; ``off``: never). One fit more per decision at most; docs/active.md,
        "Whose contact (attribution)".
    method : str
        Tracking method of the policy's belief (``stucco``).
    history : str
        The prior the scripted part's pushes put on every set (:mod:`pipeline.probe.history`): ``pushtrack`` (the
        pushtrack estimator's refined set after the scripted part) or ``off`` (docs/active.md, "What the pushes said: a
        prior from pushtrack").
    history_yaw_band : float, radians
        The prior costs nothing within this yaw of one of its poses, modulo the shape's symmetry (0.8: a box
        turned a quarter turn, 1.57 rad, is what it rules out; nearby yaws are the probes' to decide).
    history_yaw_sigma : float, radians
        Beyond the band, the cost grows as a Gaussian of this sigma (0.2).
    history_reach : float, metres
        ... and within this distance of one of its poses' centres (0.10: a prior pose farther off lies on
        another object);
    history_reach_sigma : float, metres
        ... beyond it, a Gaussian of this sigma (0.05).
    history_floor : float
        Share of a uniform prior mixed in: the prior never costs more than -log(floor) (0.05: 3.0, less than a
        contact left unexplained costs, so contacts that contradict the prior win).
    plan : PlanParams
    """

    budget: int = 12
    min_probes: int = 0
    coarse_step: float = 0.02
    fine_step: float = 0.004
    slow_zone: float = 0.03
    overshoot: float = 0.04
    backoff: float = 0.015
    transit_step: float = 0.03
    attribute_tolerance: float = 0.025
    attribute_angle_deg: float = 60.0
    attribute_corner: float = 0.015
    misfit_tolerance: float = 0.006
    stall: int = 99
    unsupported: int = 0
    min_span: float = 0.6
    min_target_contacts: int = 3
    switch_probes: int = 3
    light_contact_n: float = 5.0
    light_refutations: int = 2
    light_scripted_n: float = 5.0
    push_through: float = 0.0
    pinned_within: float = 0.015
    prior_clear_of_others: bool = True
    clutter_cost: float = 0.3
    reattribute: str = "fit"
    method: str = "stucco"
    history: str = "pushtrack"
    history_yaw_band: float = 0.8
    history_yaw_sigma: float = 0.2
    history_reach: float = 0.10
    history_reach_sigma: float = 0.05
    history_floor: float = 0.05
    plan: PlanParams = field(default_factory=PlanParams)

    constraints: ClassVar[dict[str, Constraint]] = {
        "budget": integer(0, 64), "min_probes": integer(0, 64),
        **{name: number(0, 0.03, lo_open=True) for name in ("coarse_step", "fine_step", "backoff", "transit_step")},
        **{name: number(0) for name in ("slow_zone", "overshoot")},
        **{name: number(0, lo_open=True) for name in ("attribute_tolerance", "misfit_tolerance")},
        "attribute_angle_deg": number(0, 180), "attribute_corner": number(0),
        "stall": integer(0), "unsupported": integer(0, 64), "switch_probes": integer(0, 64), "min_span": number(0, 1),
        "clutter_cost": number(0), "light_contact_n": number(0), "light_scripted_n": number(0),
        "light_refutations": integer(0), "push_through": number(0, 1), "pinned_within": number(0),
        "prior_clear_of_others": rule("true or false", lambda v: isinstance(v, bool)),
        "reattribute": rule("off, explained or fit", lambda v: v in ("off", "explained", "fit")),
        "min_target_contacts": integer(0),
        "history": rule("pushtrack or off", lambda v: v in ("pushtrack", "off")),
        **{name: number(0) for name in ("history_yaw_band", "history_reach")},
        **{name: number(0, lo_open=True) for name in ("history_yaw_sigma", "history_reach_sigma")},
        "history_floor": number(0, 1, lo_open=True),
        "method": rule("a tracking method's name", lambda m: isinstance(m, str) and bool(m)),
        "plan": rule("a PlanParams", lambda v: isinstance(v, PlanParams))}


@dataclass
class ProbeLog:
    """What the policy did in one run (recorded in the run file's metadata under ``probe``).

    Attributes
    ----------
    probes : int
        Guarded moves made.
    actions : int
        Actions recorded by the policy (transits, steps, back-offs).
    decision_s : list of float, seconds
        Wall time of each decision (belief update + planning), the last one deciding to stop.
    prior_s : float, seconds
        Wall time of the pushes' prior, once per run before the first decision (0 without one).
    contacts : list of bool
        Whether each probe ended in a detected contact.
    share : float
        Likelihood share of the final set agreeing with its estimate (:func:`planning.agreement`).
    agreed : bool
        The set agrees (share >= ``agree_share``).
    flagged : str
        Why the grasp goes ahead without the policy's stop verdict (``budget_spent``, ``no_reachable_probe``), or
        "".
    segment : int
        Segment of the final set (-1: none fitted).
    target_steps, other_steps : list of int
        Actions whose isolated contact the policy attributed to the target / to something else.
    history : list of dict
        At each decision: the rows sensed (``rows``), the target's segment, the set's agreement (``share``), the
        probe contacts attributed to it, the share of the set its grasp holds (``held``) and whether the policy
        stops there (``stop``), so the set of any decision
        can be recomputed and the decision a smaller budget stops at found (the budget curve of ``stucco bench
        probe``).
    switches : int
        Times the probes showed the chosen segment was not the target's and the next one was taken.
    refuted : int
        Probe actions with a light contact (``light_contact_n``) the current segment's set explained since it was
        taken (the contacts of one action count once).
    lines : list of list
        Each probe's start (x, y), direction (x, y), the weighted 10, 50 and 90 % quantiles of the travel its
        set predicted (metres; None: no contact predicted), and whether it was a spread probe.
    """

    probes: int = 0
    actions: int = 0
    decision_s: list = field(default_factory=list)
    prior_s: float = 0.0
    contacts: list = field(default_factory=list)
    share: float = 0.0
    agreed: bool = False
    flagged: str = ""
    segment: int = -1
    lines: list = field(default_factory=list)
    target_steps: list = field(default_factory=list)
    other_steps: list = field(default_factory=list)
    switches: int = 0
    refuted: int = 0
    history: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)
