"""Scene types: the typed, frozen dataclasses a scene file becomes, and :class:`SceneError` (no pybullet here).

A scene (docs/simulation.md, "Scenes are data") is the plane, the walls, the objects as primitive boxes and
cylinders, where the gripper starts, how it moves (a hand-made action sequence for the retrieval tasks, a greedy
random walk for the training scenes) and which simulation effects the world builds (:class:`Effects`).

Coordinates are world metres on the plane (z up), angles radians. An object's ``position``/``yaw`` place its
*link frame* (the authors' URDF frame); ``shape_offset`` places the primitive's centre in that frame and
``com_offset``/``com_yaw`` the centre of mass, whose pose pybullet reports and every recorded pose uses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_ACTION_SCALE", "WORKSPACE_M", "SceneError", "Plane", "ObjectSpec", "WallSpec", "Effects",
           "Sensors", "Hardware", "WalkSpec", "Scene", "declared_region"]

#: Normalised actions are multiplied by this (m) to give a displacement (the authors' MAX_PUSH_DIST; docs/simulation.md,
#: "Scenes are data").
DEFAULT_ACTION_SCALE = 0.03
#: How a scripted sequence may be replayed (``[actions] replay``; :class:`Scene`).
REPLAYS = ("open", "guarded")
#: The table top, ((x_min, y_min), (x_max, y_max)) in metres: every shipped scene's objects, walls and walk bounds
#: lie in it. A scene's ``[target_region]`` must lie in it, and is it when the file declares none
#: (docs/simulation.md, "Scenes are data").
WORKSPACE_M = ((-1.0, -1.0), (1.0, 1.0))


class SceneError(ValueError):
    """A scene that does not exist or whose file is malformed; the message is one line naming file and key."""


@dataclass(frozen=True)
class Plane:
    """Ground plane friction overrides; None keeps pybullet's default (lateral 1.0, spinning 0, rolling 0)."""

    lateral_friction: float | None = None
    spinning_friction: float | None = None


@dataclass(frozen=True)
class ObjectSpec:
    """One object: a primitive box or cylinder.

    Attributes
    ----------
    name : str
        Unique within the scene; ground-truth object ids follow the order of ``Scene.bodies``.
    shape : {"box", "cylinder"}
    size : tuple of float, metres
        Box: full extents (x, y, z) in the shape frame. Cylinder: (radius, height), axis along the shape z.
    position : (float, float), metres
        Link-frame origin (x, y) at spawn.
    yaw : float, radians
        Link-frame yaw at spawn.
    rp : (float, float), radians
        Roll and pitch of the link frame at spawn (a cylinder lying on its side); (0, 0) for upright objects.
    z : float or None, metres
        Link-frame height at spawn; None rests the primitive on the plane (z = half its vertical extent).
    mass : float, kg
    lateral_friction, spinning_friction, rolling_friction : float or None
        Friction overrides (None: pybullet default, lateral 0.5 for a created body).
    shape_offset : (float, float), metres
        Primitive centre in the link frame (the YCB collision hulls are not centred on their link frame).
    shape_yaw : float, radians
        Primitive yaw in the link frame.
    com_offset : (float, float, float), metres
        Centre of mass in the link frame (the URDF ``<inertial>`` origin times the global scaling).
    com_yaw : float, radians
        Yaw of the inertial frame in the link frame. Poses are reported in the inertial (COM) frame.
    model : str
        What the primitive stands for (e.g. "YcbCrackerBox x1.0"), informational.
    target : bool
        The object to retrieve (one per retrieval task).
    """

    name: str
    shape: str
    size: tuple[float, ...]
    position: tuple[float, float]
    yaw: float = 0.0
    rp: tuple[float, float] = (0.0, 0.0)
    z: float | None = None
    mass: float = 1.0
    lateral_friction: float | None = None
    spinning_friction: float | None = None
    rolling_friction: float | None = None
    shape_offset: tuple[float, float] = (0.0, 0.0)
    shape_yaw: float = 0.0
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    com_yaw: float = 0.0
    model: str = ""
    target: bool = False

    @property
    def half_height(self) -> float:
        """float, metres: half the primitive's vertical extent when upright (or its radius lying down)."""
        if self.rp != (0.0, 0.0):
            return self.size[0] if self.shape == "cylinder" else max(self.size) / 2.0
        return (self.size[1] if self.shape == "cylinder" else self.size[2]) / 2.0

    @property
    def spawn_z(self) -> float:
        """float, metres: link-frame height at spawn."""
        return self.half_height if self.z is None else self.z

    @property
    def centre_xy(self) -> tuple[float, float]:
        """(float, float), metres: the primitive's centre in the plane at spawn (link frame + ``shape_offset``)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        ox, oy = self.shape_offset
        return self.position[0] + c * ox - s * oy, self.position[1] + s * ox + c * oy

    @property
    def footprint_sides_m(self) -> tuple[float, float]:
        """(short, long), metres: sides of the smallest rectangle the object's outline on the plane can fit in
        upright (box: its x, y extents; cylinder: its diameter twice); lying down, a lower bound (the two
        smallest extents; a cylinder's diameter and height)."""
        if self.shape == "cylinder":
            sides = (2.0 * self.size[0], 2.0 * self.size[0]) if self.rp == (0.0, 0.0) else \
                (2.0 * self.size[0], self.size[1])
        else:
            sides = tuple(self.size[:2]) if self.rp == (0.0, 0.0) else tuple(sorted(self.size)[:2])
        return min(sides), max(sides)


@dataclass(frozen=True)
class WallSpec:
    """A static box (mass 0) with full extents ``size`` centred at (``position``, ``z``) with ``yaw``."""

    name: str
    size: tuple[float, float, float]
    position: tuple[float, float]
    yaw: float = 0.0
    z: float = 0.1
    lateral_friction: float | None = 0.7


@dataclass(frozen=True)
class Effects:
    """What the simulator builds for a scene; each can be switched off.

    Attributes
    ----------
    noise_mm : float, millimetres
        Half-width of the uniform replay noise added to each axis of each action (0 = off). The paper states
        +-0.5 mm; the authors' code used +-0.075 mm (docs/simulation.md, "Effects: only what a scene calls for").
    movable : tuple of str or None
        Names of the objects that are dynamic; None = all objects. Others get mass 0 (static).
    friction : bool
        Apply the friction overrides (plane, objects, walls, finger lateral friction 2); off = pybullet defaults.
    settle_steps : int
        Sim steps at rest after building the world, before the first action.
    wrench : bool
        Compute the contact wrench on the gripper every sim step (needed for detection and isolation).
    contact_truth : bool
        Record the true contact point and touched object every sim step (labels, isolation error).
    walls : bool
        Build the scene's walls.
    """

    noise_mm: float = 0.5
    movable: tuple[str, ...] | None = None
    friction: bool = True
    settle_steps: int = 1000
    wrench: bool = True
    contact_truth: bool = True
    walls: bool = True

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly form for output metadata."""
        return {
            "noise_mm": self.noise_mm,
            "movable": "all" if self.movable is None else list(self.movable),
            "friction": self.friction,
            "settle_steps": self.settle_steps,
            "wrench": self.wrench,
            "contact_truth": self.contact_truth,
            "walls": self.walls,
        }


@dataclass(frozen=True)
class Sensors:
    """The robot's contact sensors beyond the wrist wrench (``[sensors]``; docs/simulation.md, "Tactile fingertips
    and a noisy wrench"). All off by default: a scene that asks for none pays for none.

    Attributes
    ----------
    fingertips : bool
        A contact sensor on each finger pad (the paper's soft bubbles, §V-E): each reports one contact point per
        action, where its pad was pressed.
    pad_threshold_n : float, N
        A pad fires only while the normal force on it exceeds this (the bubbles' 4 mm of deformation): its dead
        band.
    pad_noise_mm : float, millimetres
        Standard deviation of the reported point, per axis (the bubbles' averaged deformed pixels).
    wrench_noise : tuple of 6 float
        Standard deviation of Gaussian noise added to each component of the wrist wrench at every sim step
        (f_x, f_y, f_z in N, tau_x, tau_y, tau_z in N m): a wrench estimated from joint torques. Zeros: exact.
    """

    fingertips: bool = False
    pad_threshold_n: float = 1.0
    pad_noise_mm: float = 0.0
    wrench_noise: tuple[float, ...] = (0.0,) * 6

    @property
    def any(self) -> bool:
        """Whether the simulator has anything to add to the plain wrist wrench."""
        return self.fingertips or any(s > 0.0 for s in self.wrench_noise)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly form for output metadata."""
        return {"fingertips": self.fingertips, "pad_threshold_n": self.pad_threshold_n,
                "pad_noise_mm": self.pad_noise_mm, "wrench_noise": list(self.wrench_noise)}


@dataclass(frozen=True)
class Hardware:
    """Settings the scene's robot was tuned with (``[detection]`` and ``[methods.<tracker>]``; docs/simulation.md,
    "Tactile fingertips and a noisy wrench"): the paper's Table I has one column for the simulator and one for
    its real robot.

    Attributes
    ----------
    detection : dict
        Overrides of the contact detector's parameters (``threshold``, ``sigma_inv``, ``min_force_n``); empty: the
        defaults.
    methods : dict of str -> dict
        Per tracking method, overrides of its parameters (e.g. ``{"stucco": {"length": 0.006}}``); a method not
        named keeps its defaults.
    """

    detection: dict[str, Any] = field(default_factory=dict)
    methods: dict[str, dict[str, Any]] = field(default_factory=dict)

    def method_params(self, method: str) -> dict[str, Any]:
        """The overrides for ``method`` (a copy; empty if none)."""
        return dict(self.methods.get(method, {}))


@dataclass(frozen=True)
class WalkSpec:
    """Greedy controller with a random walk on contact (training scenes; docs/simulation.md, "`stucco collect`")."""

    bounds: tuple[float, float] = (-0.7, 0.7)
    min_start_goal_distance: float = 0.7
    max_actions: int = 299
    goal_tolerance: float = 0.04
    walk_length: int = 6
    n_candidates: int = 100


@dataclass(frozen=True)
class Scene:
    """A parsed scene file.

    Attributes
    ----------
    name : str
        Scene name (the file stem), e.g. "FB".
    description : str
        One line.
    kind : {"retrieval", "training"}
    path : Path
        The file it was read from.
    gripper_start : (float, float) or None, metres
        Gripper base (x, y) at the start (z is fixed at 0.1); None for sampled starts (greedy walk).
    plane : Plane
    objects : tuple of ObjectSpec
    walls : tuple of WallSpec
    effects : Effects
    sensors : Sensors
    hardware : Hardware
    actions : tuple of (float, float) or None
        The hand-made sequence in normalised units, each axis in [-1, 1].
    action_scale : float, metres
        Displacement per unit action.
    replay : {"open", "guarded"}
        How the scripted policy replays ``actions``: ``open`` adds each action to wherever the gripper is (the
        paper's tasks); ``guarded`` follows the sequence's waypoints in closed loop and gives up a leg an object
        stops (:mod:`pipeline.guarded_replay`; the generated scenes).
    stop_force_n : float or None, N
        With the guarded replay, a leg is also given up after an action in contact that met this force (a heavy
        object pushed on tips over before it slides); None: never (``[actions] stop_force_n``).
    walk : WalkSpec or None
    target_region : ((float, float), (float, float)), metres
        ((x_min, y_min), (x_max, y_max)): the rectangle of the plane the user knows the target lies in (prior
        knowledge for retrieval); :data:`WORKSPACE_M` when the file declares no ``[target_region]``.
    source : str
        The TOML text the scene was parsed from ('' if built in code); collect stores it in every run file so the
        later stages use this scene, not whatever file has its name then (docs/simulation.md).
    """

    name: str
    description: str
    kind: str
    path: Path
    gripper_start: tuple[float, float] | None
    plane: Plane
    objects: tuple[ObjectSpec, ...]
    walls: tuple[WallSpec, ...]
    effects: Effects
    actions: tuple[tuple[float, float], ...] | None = None
    sensors: Sensors = Sensors()
    hardware: Hardware = field(default_factory=Hardware, compare=False)
    action_scale: float = DEFAULT_ACTION_SCALE
    replay: str = "open"
    stop_force_n: float | None = None
    walk: WalkSpec | None = None
    target_region: tuple[tuple[float, float], tuple[float, float]] = WORKSPACE_M
    notes: str = field(default="", compare=False)
    source: str = field(default="", compare=False, repr=False)

    @property
    def body_names(self) -> tuple[str, ...]:
        """Names of every body that can be touched, objects then walls: position = ground-truth object id."""
        return tuple(o.name for o in self.objects) + tuple(w.name for w in self.walls)

    @property
    def target(self) -> ObjectSpec | None:
        """The object to retrieve, if any."""
        return next((o for o in self.objects if o.target), None)

    def with_effects(self, **changes: Any) -> Scene:
        """A copy with some effects changed, e.g. ``scene.with_effects(noise_mm=0.0, walls=False)``."""
        try:
            return replace(self, effects=replace(self.effects, **changes))
        except TypeError as exc:
            raise SceneError(f"{self.path}: [effects]: {exc}") from None


def declared_region(scene) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """The target region a scene declares (``[target_region]``, :attr:`Scene.target_region`), or None when it
    declares none (its region is then the whole workspace, which says nothing) or there is no scene."""
    region = getattr(scene, "target_region", None)
    if region is None or tuple(map(tuple, region)) == tuple(map(tuple, WORKSPACE_M)):
        return None
    return (tuple(map(float, region[0])), tuple(map(float, region[1])))
