"""Scene files -> typed, frozen scene objects (no pybullet here).

A scene is one TOML file under ``data/scenes/`` (REFERENCE_SPEC §1.4-1.5, §2.2, §2.4): the plane, the walls,
the objects as primitive boxes and cylinders, where the gripper starts, how it moves (a hand-made action
sequence for the retrieval tasks, a greedy random walk for the training scenes) and which simulation effects
the world builds (``[effects]``). :func:`load_scene` parses and validates one; every problem is a
:class:`SceneError` whose one-line message names the file and the offending key.

Coordinates are world metres on the plane (z up), angles radians. An object's ``position``/``yaw`` place its
*link frame* (the authors' URDF frame); ``shape_offset`` places the primitive's centre in that frame and
``com_offset``/``com_yaw`` the centre of mass, whose pose pybullet reports and every recorded pose uses
(REFERENCE_SPEC §1.3).
"""
from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

__all__ = [
    "SCENE_DIR",
    "SceneError",
    "Plane",
    "ObjectSpec",
    "WallSpec",
    "Effects",
    "WalkSpec",
    "Scene",
    "scene_names",
    "scene_path",
    "load_scene",
    "load_all",
    "scene_hash",
]

#: Directory of the shipped scene files.
SCENE_DIR = Path(__file__).resolve().parents[1] / "data" / "scenes"

#: Normalised actions are multiplied by this (m) to give a displacement (MAX_PUSH_DIST, REFERENCE_SPEC §2.1).
DEFAULT_ACTION_SCALE = 0.03


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
        +-0.5 mm; the authors' code used +-0.075 mm (REFERENCE_SPEC §2.3).
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
class WalkSpec:
    """Greedy controller with a random walk on contact (training scenes, REFERENCE_SPEC §2.4)."""

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
    actions : tuple of (float, float) or None
        The hand-made sequence in normalised units, each axis in [-1, 1].
    action_scale : float, metres
        Displacement per unit action.
    walk : WalkSpec or None
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
    action_scale: float = DEFAULT_ACTION_SCALE
    walk: WalkSpec | None = None
    notes: str = field(default="", compare=False)

    @property
    def body_names(self) -> tuple[str, ...]:
        """Names of every body that can be touched, objects then walls: position = ground-truth object id."""
        return tuple(o.name for o in self.objects) + tuple(w.name for w in self.walls)

    @property
    def target(self) -> ObjectSpec | None:
        """The object to retrieve, if any."""
        return next((o for o in self.objects if o.target), None)

    def with_effects(self, **changes: Any) -> "Scene":
        """A copy with some effects changed, e.g. ``scene.with_effects(noise_mm=0.0, walls=False)``."""
        try:
            return replace(self, effects=replace(self.effects, **changes))
        except TypeError as exc:
            raise SceneError(f"{self.path}: [effects]: {exc}") from None


# ---------------------------------------------------------------------------------------------------------------
# Finding files
# ---------------------------------------------------------------------------------------------------------------


def scene_names(directory: Path = SCENE_DIR) -> list[str]:
    """Names of the scene files in ``directory``, sorted."""
    return sorted(p.stem for p in Path(directory).glob("*.toml"))


def scene_path(name_or_path: str | Path, directory: Path = SCENE_DIR) -> Path:
    """The file of a scene given by name (``"FB"``) or by path to a ``.toml`` file."""
    text = str(name_or_path)
    if text.endswith(".toml") or "/" in text or "\\" in text:
        path = Path(text)
        if not path.is_file():
            raise SceneError(f"{path}: scene file does not exist")
        return path
    path = Path(directory) / f"{text}.toml"
    if not path.is_file():
        known = ", ".join(scene_names(directory)) or "none"
        raise SceneError(f"{path}: unknown scene {text!r} (known: {known})")
    return path


def scene_hash(name: str) -> int:
    """A stable 32-bit integer for a scene name, the middle entry of every job's SeedSequence."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def load_all(directory: Path = SCENE_DIR) -> list[Scene]:
    """Every scene in ``directory``, sorted by name."""
    return [load_scene(n, directory) for n in scene_names(directory)]


# ---------------------------------------------------------------------------------------------------------------
# Parsing
# ---------------------------------------------------------------------------------------------------------------


class _Reader:
    """Typed access to a TOML table that reports the file and the dotted key on every error."""

    def __init__(self, path: Path, table: dict[str, Any], prefix: str = "") -> None:
        self.path = path
        self.table = table
        self.prefix = prefix

    def key(self, k: str) -> str:
        return f"{self.prefix}{k}"

    def fail(self, k: str, msg: str) -> SceneError:
        return SceneError(f"{self.path}: key '{self.key(k)}': {msg}")

    def check_keys(self, allowed: set[str]) -> None:
        for k in self.table:
            if k not in allowed:
                raise self.fail(k, f"unknown key (allowed: {', '.join(sorted(allowed))})")

    def get(self, k: str, default: Any = ..., *, required: bool = False) -> Any:
        if k not in self.table:
            if required or default is ...:
                raise self.fail(k, "missing")
            return default
        return self.table[k]

    def number(self, k: str, default: Any = ..., *, positive: bool = False, nonneg: bool = False) -> Any:
        if k not in self.table and default is not ...:
            return default
        v = self.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(k, f"expected a finite number, got {v!r}")
        if positive and v <= 0:
            raise self.fail(k, f"expected a positive number, got {v!r}")
        if nonneg and v < 0:
            raise self.fail(k, f"expected a non-negative number, got {v!r}")
        return float(v)

    def integer(self, k: str, default: Any = ..., *, minimum: int = 0) -> int:
        v = self.get(k, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            raise self.fail(k, f"expected an integer >= {minimum}, got {v!r}")
        return int(v)

    def boolean(self, k: str, default: Any = ...) -> bool:
        v = self.get(k, default)
        if not isinstance(v, bool):
            raise self.fail(k, f"expected true or false, got {v!r}")
        return v

    def string(self, k: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        v = self.get(k, default)
        if not isinstance(v, str):
            raise self.fail(k, f"expected a string, got {v!r}")
        if choices is not None and v not in choices:
            raise self.fail(k, f"expected one of {', '.join(choices)}, got {v!r}")
        return v

    def vector(self, k: str, n: int, default: Any = ..., *, positive: bool = False) -> Any:
        if k not in self.table and default is not ...:
            return default
        v = self.get(k)
        ok = isinstance(v, list) and len(v) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        if not ok:
            raise self.fail(k, f"expected a list of {n} finite numbers, got {v!r}")
        if positive and any(x <= 0 for x in v):
            raise self.fail(k, f"expected positive numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def sub(self, k: str, *, required: bool = False) -> "_Reader | None":
        v = self.get(k, None, required=required)
        if v is None:
            return None
        if not isinstance(v, dict):
            raise self.fail(k, f"expected a table, got {type(v).__name__}")
        return _Reader(self.path, v, f"{self.key(k)}.")

    def subs(self, k: str) -> list["_Reader"]:
        v = self.get(k, [])
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise self.fail(k, "expected an array of tables ([[" + k + "]])")
        return [_Reader(self.path, t, f"{self.key(k)}[{i}].") for i, t in enumerate(v)]


_TOP_KEYS = {"name", "description", "kind", "notes", "gripper", "plane", "effects", "objects", "walls", "actions",
             "walk"}
_OBJECT_KEYS = {"name", "shape", "size", "position", "yaw", "rp", "z", "mass", "lateral_friction",
                "spinning_friction", "rolling_friction", "shape_offset", "shape_yaw", "com_offset", "com_yaw",
                "model", "target"}


def _parse_object(r: _Reader) -> ObjectSpec:
    r.check_keys(_OBJECT_KEYS)
    shape = r.string("shape", choices=("box", "cylinder"))
    size = r.vector("size", 3 if shape == "box" else 2, positive=True)
    return ObjectSpec(
        name=r.string("name"),
        shape=shape,
        size=size,
        position=r.vector("position", 2),
        yaw=r.number("yaw", 0.0),
        rp=r.vector("rp", 2, (0.0, 0.0)),
        z=r.number("z", None, positive=True),
        mass=r.number("mass", positive=True),
        lateral_friction=r.number("lateral_friction", None, nonneg=True),
        spinning_friction=r.number("spinning_friction", None, nonneg=True),
        rolling_friction=r.number("rolling_friction", None, nonneg=True),
        shape_offset=r.vector("shape_offset", 2, (0.0, 0.0)),
        shape_yaw=r.number("shape_yaw", 0.0),
        com_offset=r.vector("com_offset", 3, (0.0, 0.0, 0.0)),
        com_yaw=r.number("com_yaw", 0.0),
        model=r.string("model", ""),
        target=r.boolean("target", False),
    )


def _parse_wall(r: _Reader, i: int) -> WallSpec:
    r.check_keys({"name", "size", "position", "yaw", "z", "lateral_friction"})
    return WallSpec(
        name=r.string("name", f"wall{i}"),
        size=r.vector("size", 3, positive=True),
        position=r.vector("position", 2),
        yaw=r.number("yaw", 0.0),
        z=r.number("z", 0.1),
        lateral_friction=r.number("lateral_friction", 0.7, nonneg=True),
    )


def _parse_effects(r: _Reader | None, object_names: list[str]) -> Effects:
    if r is None:
        return Effects()
    r.check_keys({"noise_mm", "movable", "friction", "settle_steps", "wrench", "contact_truth", "walls"})
    mov = r.get("movable", "all")
    if mov == "all":
        movable = None
    elif isinstance(mov, list) and all(isinstance(m, str) for m in mov):
        for m in mov:
            if m not in object_names:
                raise r.fail("movable", f"no object named {m!r} (objects: {', '.join(object_names)})")
        movable = tuple(mov)
    else:
        raise r.fail("movable", f"expected \"all\" or a list of object names, got {mov!r}")
    return Effects(
        noise_mm=r.number("noise_mm", 0.5, nonneg=True),
        movable=movable,
        friction=r.boolean("friction", True),
        settle_steps=r.integer("settle_steps", 1000),
        wrench=r.boolean("wrench", True),
        contact_truth=r.boolean("contact_truth", True),
        walls=r.boolean("walls", True),
    )


def _parse_actions(r: _Reader | None) -> tuple[tuple[tuple[float, float], ...] | None, float]:
    if r is None:
        return None, DEFAULT_ACTION_SCALE
    r.check_keys({"scale", "sequence"})
    scale = r.number("scale", DEFAULT_ACTION_SCALE, positive=True)
    seq = r.get("sequence")
    if not isinstance(seq, list) or not seq:
        raise r.fail("sequence", "expected a non-empty list of [u_x, u_y] pairs")
    out = []
    for i, a in enumerate(seq):
        ok = isinstance(a, list) and len(a) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and -1.0 <= x <= 1.0 for x in a)
        if not ok:
            raise r.fail(f"sequence[{i}]", f"expected [u_x, u_y] with each in [-1, 1], got {a!r}")
        out.append((float(a[0]), float(a[1])))
    return tuple(out), scale


def _parse_walk(r: _Reader | None) -> WalkSpec | None:
    if r is None:
        return None
    r.check_keys({"bounds", "min_start_goal_distance", "max_actions", "goal_tolerance", "walk_length",
                  "n_candidates"})
    d = WalkSpec()
    bounds = r.vector("bounds", 2, d.bounds)
    if bounds[0] >= bounds[1]:
        raise r.fail("bounds", f"expected [low, high] with low < high, got {list(bounds)}")
    return WalkSpec(
        bounds=bounds,
        min_start_goal_distance=r.number("min_start_goal_distance", d.min_start_goal_distance, nonneg=True),
        max_actions=r.integer("max_actions", d.max_actions, minimum=1),
        goal_tolerance=r.number("goal_tolerance", d.goal_tolerance, positive=True),
        walk_length=r.integer("walk_length", d.walk_length),
        n_candidates=r.integer("n_candidates", d.n_candidates, minimum=1),
    )


def parse_scene(data: dict[str, Any], path: Path) -> Scene:
    """Validate a decoded TOML document into a :class:`Scene` (``path`` only names the file in errors)."""
    r = _Reader(path, data)
    r.check_keys(_TOP_KEYS)
    name = r.string("name", path.stem)
    kind = r.string("kind", choices=("retrieval", "training"))
    g = r.sub("gripper")
    start = None
    if g is not None:
        g.check_keys({"start"})
        start = g.vector("start", 2, None)
    p = r.sub("plane")
    plane = Plane()
    if p is not None:
        p.check_keys({"lateral_friction", "spinning_friction"})
        plane = Plane(p.number("lateral_friction", None, nonneg=True), p.number("spinning_friction", None,
                                                                                 nonneg=True))
    objects = tuple(_parse_object(o) for o in r.subs("objects"))
    if not objects:
        raise r.fail("objects", "a scene needs at least one [[objects]] entry")
    walls = tuple(_parse_wall(w, i) for i, w in enumerate(r.subs("walls")))
    names = [o.name for o in objects] + [w.name for w in walls]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise r.fail("objects", f"duplicate object/wall names: {', '.join(dup)}")
    effects = _parse_effects(r.sub("effects"), [o.name for o in objects])
    actions, scale = _parse_actions(r.sub("actions"))
    walk = _parse_walk(r.sub("walk"))
    if kind == "retrieval":
        if actions is None:
            raise r.fail("actions", "a retrieval scene needs [actions] with a sequence")
        if start is None:
            raise r.fail("gripper.start", "a retrieval scene needs the gripper start [x, y]")
        if sum(o.target for o in objects) != 1:
            raise r.fail("objects", "a retrieval scene needs exactly one object with target = true")
    if kind == "training" and walk is None:
        raise r.fail("walk", "a training scene needs a [walk] table (greedy random walk)")
    desc = r.string("description", "")
    if "\n" in desc.strip():
        raise r.fail("description", "expected one line")
    return Scene(name=name, description=desc.strip(), kind=kind, path=path, gripper_start=start, plane=plane,
                 objects=objects, walls=walls, effects=effects, actions=actions, action_scale=scale, walk=walk,
                 notes=r.string("notes", ""))


def load_scene(name_or_path: str | Path, directory: Path = SCENE_DIR) -> Scene:
    """Read and validate a scene by name (``"FB"``) or path.

    Raises
    ------
    SceneError
        Unknown scene, unreadable or invalid TOML, or a missing/ill-typed key; one line naming file and key.
    """
    path = scene_path(name_or_path, directory)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_scene(data, path)
