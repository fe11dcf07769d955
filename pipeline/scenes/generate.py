"""Retrieval scenes drawn at random: the knobs (:class:`GeneratorSpec`) and one draw of a layout (no pybullet here).

A layout (:class:`Layout`) is a target from the tasks' YCB primitives (:mod:`pipeline.scenes.catalogue`) behind,
between or beside 2-6 distractors, optional task walls, a gripper start in front of the clutter (fingers along
+x, as in the tasks), the target region the user is told (the clutter's bounding box plus a drawn margin, never
the target's own pose) and a generic rummage of that region, pokes from the start's side
(:func:`pipeline.scenes.coverage.coverage_passes`).
Draw ``d`` of scene ``index`` depends only on (seed, index, d); the checks after settling and the redraws are in
:mod:`pipeline.sim.generate`, the TOML text in :mod:`pipeline.scenes.generated_toml` (docs/scene_generator.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pipeline.scenes.catalogue import (
    DISTRACTOR_MASS_KG,
    LATERAL_FRICTION,
    MODEL_BY_KEY,
    MODELS,
    TARGET_KEYS,
    TARGET_MASS_KG,
    TASK_WALLS,
    Model,
)
from pipeline.scenes.coverage import DEFAULT_LANE_SPACING_M
from pipeline.scenes.footprint import (
    GRIPPER_OUTLINE_M,
    bounding_box,
    gripper_outline,
    hidden_fraction,
    object_outline,
    separation,
    wall_outline,
)
from pipeline.scenes.types import WORKSPACE_M, ObjectSpec, WallSpec

__all__ = ["GeneratorSpec", "GeneratorSpecError", "Layout", "DrawRejected", "sample_layout", "draw_rng",
           "TARGET_CHOICES", "PLACEMENTS", "GAP_MIN_M", "GAP_LOOSE_M", "MAX_DISTRACTORS"]

TARGET_CHOICES = ("mix", "box", "can", "any")
PLACEMENTS = ("behind", "between", "beside")
#: Gaps between neighbouring outlines, metres: at clutter density 1 every gap is GAP_MIN_M (no contact at spawn,
#: so nothing is pushed while settling); at density 0 gaps are drawn up to GAP_LOOSE_M.
GAP_MIN_M = 0.005
GAP_LOOSE_M = 0.08
MAX_DISTRACTORS = 12
#: Clearance between the gripper's fingertips and the clutter at the start, metres (drawn in this range).
START_CLEARANCE_M = (0.03, 0.08)
#: Outlines may cover at most this share of the clutter area (a packing that sliding placement reaches).
MAX_FILL = 0.35
_SLIDE_STEP_M = 0.01
_SLIDE_STEPS = 80
_REST_TRIES = 30
_DECIMALS = 4  # metres, radians, kg and friction in the file: 0.1 mm is far below every gap


class GeneratorSpecError(ValueError):
    """A knob out of range; ``knob`` names it, ``value`` is what was given, the message is one line."""

    def __init__(self, knob: str, value: object, reason: str) -> None:
        super().__init__(f"{knob} {value!r}: {reason}")
        self.knob, self.value, self.reason = knob, value, reason


class DrawRejected(Exception):
    """One draw broke a rule (overlap, too little hidden, no room); the next draw of the scene is tried."""


@dataclass(frozen=True)
class GeneratorSpec:
    """The generator's knobs, checked on construction (:class:`GeneratorSpecError`).

    Attributes
    ----------
    min_distractors, max_distractors : int
        Distractors per scene, drawn uniformly in [min, max]; 0 <= min <= max <= MAX_DISTRACTORS.
    clutter_density : float in [0, 1]
        1: neighbours GAP_MIN_M apart; 0: gaps drawn in [GAP_MIN_M, GAP_LOOSE_M].
    hiddenness : float in [0, 1]
        Least share of the target's silhouette, seen from the gripper start, that distractors cover.
    wall_probability : float in [0, 1]
        Chance of each of the tasks' three walls.
    target : {"mix", "box", "can", "any"}
        box: the cracker box (FB, BC, IB); can: the small tomato can (TC); mix: box for even scene indices, can for
        odd ones (reports split evenly by target kind); any: any of the tasks' primitives, drawn.
    area_m : ((x_min, y_min), (x_max, y_max)), metres
        Where the objects are placed (whole outlines inside).
    region_margin_m : (low, high), metres
        The target region is the clutter's bounding box grown on each side by a margin drawn in [low, high] and
        rounded outward to the centimetre.
    lane_spacing_m : float, metres
        Largest lateral distance between the rummage's poke lanes (:func:`pipeline.scenes.coverage.lanes`).
    """

    min_distractors: int = 2
    max_distractors: int = 6
    clutter_density: float = 0.5
    hiddenness: float = 0.5
    wall_probability: float = 0.5
    target: str = "mix"
    area_m: tuple[tuple[float, float], tuple[float, float]] = ((0.1, -0.45), (0.8, 0.45))
    region_margin_m: tuple[float, float] = (0.03, 0.1)
    lane_spacing_m: float = DEFAULT_LANE_SPACING_M

    def __post_init__(self) -> None:
        for knob in ("min_distractors", "max_distractors"):
            v = getattr(self, knob)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 <= v <= MAX_DISTRACTORS:
                raise GeneratorSpecError(knob, v, f"expected a whole number in [0, {MAX_DISTRACTORS}]")
        if self.max_distractors < self.min_distractors:
            raise GeneratorSpecError("max_distractors", self.max_distractors,
                                     f"expected at least min_distractors ({self.min_distractors})")
        for knob in ("clutter_density", "hiddenness", "wall_probability"):
            v = getattr(self, knob)
            if not _real(v) or not 0.0 <= v <= 1.0:
                raise GeneratorSpecError(knob, v, "expected a number in [0, 1]")
        if self.hiddenness > 0.0 and self.max_distractors == 0:
            raise GeneratorSpecError("hiddenness", self.hiddenness, "needs distractors to hide the target")
        if self.target not in TARGET_CHOICES:
            raise GeneratorSpecError("target", self.target, f"expected one of {', '.join(TARGET_CHOICES)}")
        lo, hi = self.region_margin_m
        if not (_real(lo) and _real(hi) and 0.0 <= lo <= hi <= 0.5):
            raise GeneratorSpecError("region_margin_m", self.region_margin_m, "expected 0 <= low <= high <= 0.5 m")
        if not (_real(self.lane_spacing_m) and 0.01 <= self.lane_spacing_m <= 0.5):
            raise GeneratorSpecError("lane_spacing_m", self.lane_spacing_m, "expected metres in [0.01, 0.5]")
        self._check_area()

    def _check_area(self) -> None:
        (x0, y0), (x1, y1) = self.area_m
        (wx0, wy0), (wx1, wy1) = WORKSPACE_M
        if not all(_real(v) for v in (x0, y0, x1, y1)) or not (x0 < x1 and y0 < y1):
            raise GeneratorSpecError("area_m", self.area_m, "expected finite ((x_min, y_min), (x_max, y_max)) with "
                                                            "min < max")
        if not (wx0 <= x0 and wy0 <= y0 and x1 <= wx1 and y1 <= wy1):
            raise GeneratorSpecError("area_m", self.area_m, f"lies outside the workspace (x, y in [{wx0:g}, {wx1:g}] "
                                                            "m)")
        gripper_depth = GRIPPER_OUTLINE_M[1][0] - GRIPPER_OUTLINE_M[0][0]
        x_low = wx0 + gripper_depth + START_CLEARANCE_M[1]
        if x0 < x_low:
            raise GeneratorSpecError("area_m", self.area_m, f"leaves no room in the workspace for the gripper start "
                                                            f"before it (x_min >= {x_low:.3f} m)")
        width, height = sorted((x1 - x0, y1 - y0))
        for m in self.target_models():
            short, long = _sides(m)
            if short > width or long > height:
                raise GeneratorSpecError("area_m", self.area_m, f"is smaller than the target {m.key} ({short:.3f} x "
                                                                f"{long:.3f} m)")
        need = _padded_area(max(self.target_models(), key=_padded_area)) + self.max_distractors * max(
            _padded_area(m) for m in MODELS)
        if need > MAX_FILL * (x1 - x0) * (y1 - y0):
            raise GeneratorSpecError("max_distractors", self.max_distractors,
                                     f"{self.max_distractors + 1} objects need about {need:.3f} m^2 but the area "
                                     f"{x1 - x0:.2f} x {y1 - y0:.2f} m holds {MAX_FILL * (x1 - x0) * (y1 - y0):.3f}")

    def target_models(self) -> tuple[Model, ...]:
        """The models the target can be."""
        if self.target == "any":
            return MODELS
        keys = TARGET_KEYS.values() if self.target == "mix" else (TARGET_KEYS[self.target],)
        return tuple(MODEL_BY_KEY[k] for k in keys)

    def summary(self) -> str:
        """One line of ``knob=value`` pairs."""
        return " ".join(f"{k}={v}" for k, v in self.__dict__.items())


@dataclass(frozen=True)
class Layout:
    """One drawn scene, before its file is written.

    Attributes
    ----------
    seed, index, draw : int
        The draw's key: scene ``index`` of the batch of ``seed``, draw ``draw`` (0 unless earlier draws failed).
    objects : tuple of ObjectSpec
        Target first, then the distractors.
    walls : tuple of WallSpec
    start : (float, float), metres
        Gripper base at the start.
    region : ((x_min, y_min), (x_max, y_max)), metres
        The target region.
    placement : {"behind", "between", "beside"}
        How the target was placed among the distractors, seen from the start.
    hidden : float
        Share of the target's silhouette the distractors cover from the start.
    """

    seed: int
    index: int
    draw: int
    objects: tuple[ObjectSpec, ...]
    walls: tuple[WallSpec, ...]
    start: tuple[float, float]
    region: tuple[tuple[float, float], tuple[float, float]]
    placement: str
    hidden: float

    @property
    def name(self) -> str:
        """Scene name, ``GEN_<index:05d>`` (a scene name is an identifier: no '-')."""
        return f"GEN_{self.index:05d}"


def draw_rng(seed: int, index: int, draw: int) -> np.random.Generator:
    """The random stream of one draw: child ``draw`` of ``SeedSequence([seed, index])``, so scene ``index`` never
    depends on the batch it is generated in, nor on another scene's draws."""
    return np.random.default_rng(np.random.SeedSequence([seed, index], spawn_key=(draw,)))


def sample_layout(seed: int, index: int, draw: int, spec: GeneratorSpec) -> Layout:
    """Draw ``draw`` of scene ``index``; :class:`DrawRejected` if it breaks a rule (no overlap, target hidden by at
    least ``spec.hiddenness``, everything inside the area and the workspace, clear of the walls)."""
    rng = draw_rng(seed, index, draw)
    walls = tuple(w for w in TASK_WALLS if rng.random() < spec.wall_probability)
    target_model = _target_model(spec, index, rng)
    n_distractors = int(rng.integers(spec.min_distractors, spec.max_distractors + 1))
    pool = [m for m in MODELS if m.key != target_model.key]  # the target's shape stays unique, as in the tasks
    picks = [pool[int(i)] for i in rng.integers(0, len(pool), n_distractors)]
    gap_high = GAP_MIN_M + (1.0 - spec.clutter_density) * (GAP_LOOSE_M - GAP_MIN_M)
    placer = _Placer(spec.area_m, walls)

    (ax0, ay0), (ax1, ay1) = spec.area_m
    yaw = float(rng.uniform(-math.pi, math.pi))
    radius = _radius(target_model)
    # The target sits in the far two thirds of the area (in x), leaving room in front for what hides it.
    x_low = ax0 + radius + (ax1 - ax0 - 2 * radius) / 3.0
    centre = np.array([rng.uniform(x_low, ax1 - radius), rng.uniform(ay0 + radius, ay1 - radius)])
    mass = float(rng.uniform(*TARGET_MASS_KG))
    target = _object(target_model, target_model.key, centre, yaw, mass, float(rng.uniform(*LATERAL_FRICTION)), True)
    placer.add(target)
    (wx0, wy0), (wx1, wy1) = WORKSPACE_M
    start_y = float(np.clip(centre[1] + rng.uniform(-0.1, 0.1), wy0 - GRIPPER_OUTLINE_M[0][1] + GAP_MIN_M,
                            wy1 - GRIPPER_OUTLINE_M[1][1] - GAP_MIN_M))
    ahead = centre - np.array([ax0 - 0.2, start_y])  # from about where the gripper will start
    ahead /= math.hypot(*ahead)
    side = np.array([-ahead[1], ahead[0]])

    hide = spec.hiddenness > 0.0
    needs = {"behind": 1, "between": 2 + hide, "beside": 1 + hide}
    feasible = [p for p in PLACEMENTS if needs[p] <= n_distractors]
    if not feasible:
        raise DrawRejected(f"{n_distractors} distractors cannot hide the target")
    placement = feasible[int(rng.integers(len(feasible)))]
    names: dict[str, int] = {}
    queue = list(picks)

    def place_next(origin: np.ndarray, direction: np.ndarray) -> bool:
        """Slide the next distractor from ``origin`` along ``direction`` into place; False if it does not fit."""
        model = queue[0]
        count = names.get(model.key, 0) + 1
        name = model.key if count == 1 else f"{model.key}_{count}"
        obj = _object(model, name, origin, float(rng.uniform(-math.pi, math.pi)),
                      float(rng.uniform(*DISTRACTOR_MASS_KG)), float(rng.uniform(*LATERAL_FRICTION)), False)
        if not placer.slide(obj, direction, float(rng.uniform(GAP_MIN_M, gap_high))):
            return False
        names[model.key] = count
        queue.pop(0)
        return True

    placed = True
    if placement == "between":
        placed = place_next(centre, side) and place_next(centre, -side)
    elif placement == "beside":
        placed = place_next(centre, side if rng.random() < 0.5 else -side)
    if placed and (placement == "behind" or hide):
        # Off the line of sight by at most (1 - hiddenness) of the two half-widths: hidden more the higher it is.
        lateral = rng.uniform(-1.0, 1.0) * (1.0 - spec.hiddenness) * (radius + _radius(queue[0]))
        placed = place_next(centre + lateral * side, -ahead)
    if not placed:
        raise DrawRejected(f"no room to place the target {placement} its neighbours")
    while queue:
        # The rest go around anything placed, in a drawn direction.
        for _ in range(_REST_TRIES):
            anchor = np.array(placer.objects[int(rng.integers(len(placer.objects)))].centre_xy)
            angle = rng.uniform(0.0, 2.0 * math.pi)
            if place_next(anchor, np.array([math.cos(angle), math.sin(angle)])):
                break
        else:
            raise DrawRejected(f"no room for {queue[0].key}")

    (bx0, by0), (bx1, by1) = bounding_box(placer.outlines)
    start = (_round(bx0 - GRIPPER_OUTLINE_M[1][0] - rng.uniform(*START_CLEARANCE_M)), _round(start_y))
    hand = gripper_outline(start)
    if hand.min(axis=0)[0] < wx0 or any(separation(hand, wall_outline(w)) < GAP_MIN_M for w in walls):
        raise DrawRejected("no room for the gripper start")
    hidden = hidden_fraction(start, placer.outlines[0], placer.outlines[1:])
    if hidden < spec.hiddenness:
        raise DrawRejected(f"target {hidden:.0%} hidden, below {spec.hiddenness:.0%}")
    # Coarse knowledge only: the whole clutter's box, grown by drawn margins, rounded outward to the centimetre.
    margin = rng.uniform(*spec.region_margin_m, size=4)
    region = ((max(wx0, _cm_floor(bx0 - margin[0])), max(wy0, _cm_floor(by0 - margin[1]))),
              (min(wx1, _cm_ceil(bx1 + margin[2])), min(wy1, _cm_ceil(by1 + margin[3]))))
    return Layout(seed=seed, index=index, draw=draw, objects=tuple(placer.objects), walls=walls, start=start,
                  region=region, placement=placement, hidden=hidden)


class _Placer:
    """The objects placed so far, their outlines and gaps, and the rules a new one must keep."""

    def __init__(self, area_m, walls: tuple[WallSpec, ...]) -> None:
        self.area = np.asarray(area_m, dtype=np.float64)
        self.walls = [wall_outline(w) for w in walls]
        self.objects: list[ObjectSpec] = []
        self.outlines: list[np.ndarray] = []

    def add(self, obj: ObjectSpec) -> None:
        self.objects.append(obj)
        self.outlines.append(object_outline(obj))

    def clear(self, poly: np.ndarray, gap: float) -> bool:
        return all(separation(poly, o) >= gap for o in self.outlines)

    def fits(self, poly: np.ndarray) -> bool:
        return bool((poly >= self.area[0]).all() and (poly <= self.area[1]).all()) and all(
            separation(poly, w) >= GAP_MIN_M for w in self.walls)

    def slide(self, obj: ObjectSpec, direction: np.ndarray, gap: float) -> bool:
        """Move ``obj`` from where it is along ``direction`` until it is ``gap`` (m) from everything placed; add it
        if it then lies in the area, clear of the walls."""
        def moved(d: float) -> ObjectSpec:
            x, y = obj.position
            return replace(obj, position=(_round(x + d * direction[0]), _round(y + d * direction[1])))

        blocked = -1.0
        for k in range(_SLIDE_STEPS):
            d = k * _SLIDE_STEP_M
            if self.clear(object_outline(moved(d)), gap):
                break
            blocked = d
        else:
            return False
        low, high = blocked, d  # the first clear step; bisect back towards the last blocked one (to ~1 mm)
        for _ in range(3 if blocked >= 0.0 else 0):
            mid = (low + high) / 2.0
            low, high = (low, mid) if self.clear(object_outline(moved(mid)), gap) else (mid, high)
        placed = moved(high)
        poly = object_outline(placed)
        if not self.fits(poly):
            return False
        self.add(placed)
        return True


def _object(model: Model, name: str, centre: np.ndarray, yaw: float, mass: float, friction: float,
            target: bool) -> ObjectSpec:
    """An upright object of ``model`` whose primitive centre is at ``centre`` (m) with link yaw ``yaw`` (rad)."""
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy = model.shape_offset
    position = (_round(centre[0] - (c * ox - s * oy)), _round(centre[1] - (s * ox + c * oy)))
    return ObjectSpec(name=name, shape=model.shape, size=model.size, position=position, yaw=_round(yaw),
                      mass=_round(mass), lateral_friction=_round(friction), spinning_friction=model.spinning_friction,
                      rolling_friction=model.rolling_friction, shape_offset=model.shape_offset,
                      shape_yaw=model.shape_yaw, com_offset=model.com_offset, com_yaw=model.com_yaw,
                      model=model.model, target=target)


def _target_model(spec: GeneratorSpec, index: int, rng: np.random.Generator) -> Model:
    if spec.target == "mix":
        return MODEL_BY_KEY[TARGET_KEYS["box" if index % 2 == 0 else "can"]]
    models = spec.target_models()
    return models[int(rng.integers(len(models)))] if len(models) > 1 else models[0]


def _sides(m: Model) -> tuple[float, float]:
    """(short, long) sides of the model's outline, metres."""
    sides = (2 * m.size[0], 2 * m.size[0]) if m.shape == "cylinder" else (m.size[0], m.size[1])
    return min(sides), max(sides)


def _padded_area(m: Model) -> float:
    short, long = _sides(m)
    return (short + GAP_MIN_M) * (long + GAP_MIN_M)


def _radius(m: Model) -> float:
    """Half the diagonal of the model's outline, metres (its reach from the primitive centre)."""
    return math.hypot(*_sides(m)) / 2.0


def _real(v: object) -> bool:
    return isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool) and math.isfinite(v)


def _cm_floor(x: float) -> float:
    return math.floor(x * 100.0) / 100.0


def _cm_ceil(x: float) -> float:
    return math.ceil(x * 100.0) / 100.0


def _round(x: float) -> float:
    return round(float(x), _DECIMALS) + 0.0
