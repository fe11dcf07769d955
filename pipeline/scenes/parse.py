"""Scene parsing: a decoded TOML document -> a validated :class:`~pipeline.scenes.types.Scene`.

Every problem is a :class:`~pipeline.scenes.types.SceneError` whose one-line message names the file and the
offending dotted key; unknown keys are errors too, so typos do not pass silently (docs/simulation.md, "Scenes are
data", lists the keys).
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from pipeline.scenes.footprint import containment_problem
from pipeline.scenes.sensing import parse_hardware, parse_sensors
from pipeline.scenes.types import (
    DEFAULT_ACTION_SCALE,
    REPLAYS,
    WORKSPACE_M,
    Effects,
    ObjectSpec,
    Plane,
    Scene,
    SceneError,
    WalkSpec,
    WallSpec,
)

__all__ = ["parse_scene", "NAME_PATTERN", "MAX_EXTENT_M", "MAX_SIZE_M", "MAX_MASS_KG", "MAX_FRICTION",
           "MAX_ACTION_SCALE_M", "MAX_NOISE_MM", "MAX_SETTLE_STEPS", "MAX_ACTIONS", "MAX_STOP_FORCE_N"]

#: A scene name is a plain identifier: it becomes part of file names (``<out>/<scene>-<seed>.parquet``), so a
#: path separator or ``..`` could write outside ``--out``, and ``-`` would make those names ambiguous.
NAME_PATTERN = r"[A-Za-z][A-Za-z0-9_]{0,63}"
# Physical bounds of a table-top scene (docs/simulation.md, "Scenes are data"). Beyond them a value is a unit
# error or a typo, and some would make a run last for ever (settle steps, actions) or exhaust memory.
#: Positions (objects, walls, gripper start, walk bounds), metres from the origin per axis.
MAX_EXTENT_M = 10.0
#: Object and wall sizes, offsets of shapes and centres of mass, metres.
MAX_SIZE_M = 5.0
MAX_MASS_KG = 1000.0
#: Friction coefficients (lateral, spinning, rolling).
MAX_FRICTION = 10.0
#: Metres per unit action (the paper's 3 cm).
MAX_ACTION_SCALE_M = 0.5
#: Replay noise half-width, mm.
MAX_NOISE_MM = 50.0
#: The guarded replay's force limit, N (the gripper holds 30 N per finger; the wrench reaches a few hundred).
MAX_STOP_FORCE_N = 1000.0
#: Sim steps of settling before the first action (1000 by default; 100000 is 7 minutes of simulated time).
MAX_SETTLE_STEPS = 100_000
#: Actions of a scripted sequence or of a walk (a shipped scene has at most about 300; 100,000 actions would run
#: for half an hour). Also the largest ``--max-actions``.
MAX_ACTIONS = 5_000


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

    def number(self, k: str, default: Any = ..., *, positive: bool = False, nonneg: bool = False,
               maximum: float | None = None) -> Any:
        """A finite number; `maximum` bounds its magnitude (the physical bound of the key)."""
        if k not in self.table and default is not ...:
            return default
        v = self.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(k, f"expected a finite number, got {v!r}")
        if positive and v <= 0:
            raise self.fail(k, f"expected a positive number, got {v!r}")
        if nonneg and v < 0:
            raise self.fail(k, f"expected a non-negative number, got {v!r}")
        if maximum is not None and abs(v) > maximum:
            raise self.fail(k, f"expected at most {maximum:g} in magnitude, got {v!r}")
        return float(v)

    def integer(self, k: str, default: Any = ..., *, minimum: int = 0, maximum: int | None = None) -> int:
        v = self.get(k, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum or (maximum is not None and v > maximum):
            rule = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
            raise self.fail(k, f"expected an integer {rule}, got {v!r}")
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

    def vector(self, k: str, n: int, default: Any = ..., *, positive: bool = False,
               maximum: float | None = None) -> Any:
        """A list of `n` finite numbers; `maximum` bounds each one's magnitude."""
        if k not in self.table and default is not ...:
            return default
        v = self.get(k)
        ok = isinstance(v, list) and len(v) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        if not ok:
            raise self.fail(k, f"expected a list of {n} finite numbers, got {v!r}")
        if positive and any(x <= 0 for x in v):
            raise self.fail(k, f"expected positive numbers, got {v!r}")
        if maximum is not None and any(abs(x) > maximum for x in v):
            raise self.fail(k, f"expected numbers of at most {maximum:g} in magnitude, got {v!r}")
        return tuple(float(x) for x in v)

    def sub(self, k: str, *, required: bool = False) -> _Reader | None:
        v = self.get(k, None, required=required)
        if v is None:
            return None
        if not isinstance(v, dict):
            raise self.fail(k, f"expected a table, got {type(v).__name__}")
        return _Reader(self.path, v, f"{self.key(k)}.")

    def subs(self, k: str) -> list[_Reader]:
        v = self.get(k, [])
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise self.fail(k, "expected an array of tables ([[" + k + "]])")
        return [_Reader(self.path, t, f"{self.key(k)}[{i}].") for i, t in enumerate(v)]


_TOP_KEYS = {"name", "description", "kind", "notes", "gripper", "plane", "effects", "objects", "walls", "actions",
             "walk", "target_region", "sensors", "detection", "methods"}
_OBJECT_KEYS = {"name", "shape", "size", "position", "yaw", "rp", "z", "mass", "lateral_friction",
                "spinning_friction", "rolling_friction", "shape_offset", "shape_yaw", "com_offset", "com_yaw",
                "model", "target"}


def _parse_object(r: _Reader) -> ObjectSpec:
    r.check_keys(_OBJECT_KEYS)
    shape = r.string("shape", choices=("box", "cylinder"))
    size = r.vector("size", 3 if shape == "box" else 2, positive=True, maximum=MAX_SIZE_M)
    return ObjectSpec(
        name=r.string("name"),
        shape=shape,
        size=size,
        position=r.vector("position", 2, maximum=MAX_EXTENT_M),
        yaw=r.number("yaw", 0.0),
        rp=r.vector("rp", 2, (0.0, 0.0)),
        z=r.number("z", None, positive=True, maximum=MAX_EXTENT_M),
        mass=r.number("mass", positive=True, maximum=MAX_MASS_KG),
        lateral_friction=r.number("lateral_friction", None, nonneg=True, maximum=MAX_FRICTION),
        spinning_friction=r.number("spinning_friction", None, nonneg=True, maximum=MAX_FRICTION),
        rolling_friction=r.number("rolling_friction", None, nonneg=True, maximum=MAX_FRICTION),
        shape_offset=r.vector("shape_offset", 2, (0.0, 0.0), maximum=MAX_SIZE_M),
        shape_yaw=r.number("shape_yaw", 0.0),
        com_offset=r.vector("com_offset", 3, (0.0, 0.0, 0.0), maximum=MAX_SIZE_M),
        com_yaw=r.number("com_yaw", 0.0),
        model=r.string("model", ""),
        target=r.boolean("target", False),
    )


def _parse_wall(r: _Reader, i: int) -> WallSpec:
    r.check_keys({"name", "size", "position", "yaw", "z", "lateral_friction"})
    return WallSpec(
        name=r.string("name", f"wall{i}"),
        size=r.vector("size", 3, positive=True, maximum=MAX_SIZE_M),
        position=r.vector("position", 2, maximum=MAX_EXTENT_M),
        yaw=r.number("yaw", 0.0),
        z=r.number("z", 0.1, maximum=MAX_EXTENT_M),
        lateral_friction=r.number("lateral_friction", 0.7, nonneg=True, maximum=MAX_FRICTION),
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
        noise_mm=r.number("noise_mm", 0.5, nonneg=True, maximum=MAX_NOISE_MM),
        movable=movable,
        friction=r.boolean("friction", True),
        settle_steps=r.integer("settle_steps", 1000, maximum=MAX_SETTLE_STEPS),
        wrench=r.boolean("wrench", True),
        contact_truth=r.boolean("contact_truth", True),
        walls=r.boolean("walls", True),
    )


def _parse_actions(r: _Reader | None) -> tuple[tuple[tuple[float, float], ...] | None, float, str, float | None]:
    if r is None:
        return None, DEFAULT_ACTION_SCALE, "open", None
    r.check_keys({"scale", "sequence", "replay", "stop_force_n"})
    scale = r.number("scale", DEFAULT_ACTION_SCALE, positive=True, maximum=MAX_ACTION_SCALE_M)
    seq = r.get("sequence")
    if not isinstance(seq, list) or not seq or len(seq) > MAX_ACTIONS:
        raise r.fail("sequence", f"expected a non-empty list of at most {MAX_ACTIONS} [u_x, u_y] pairs")
    out = []
    for i, a in enumerate(seq):
        ok = isinstance(a, list) and len(a) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and -1.0 <= x <= 1.0 for x in a)
        if not ok:
            raise r.fail(f"sequence[{i}]", f"expected [u_x, u_y] with each in [-1, 1], got {a!r}")
        out.append((float(a[0]), float(a[1])))
    replay = r.string("replay", "open", choices=REPLAYS)
    stop = r.number("stop_force_n", None, positive=True, maximum=MAX_STOP_FORCE_N)
    if stop is not None and replay != "guarded":
        raise r.fail("stop_force_n", 'a force limit needs replay = "guarded" (an open replay never gives a leg up)')
    return tuple(out), scale, replay, stop


def _parse_walk(r: _Reader | None) -> WalkSpec | None:
    if r is None:
        return None
    r.check_keys({"bounds", "min_start_goal_distance", "max_actions", "goal_tolerance", "walk_length",
                  "n_candidates"})
    d = WalkSpec()
    bounds = r.vector("bounds", 2, d.bounds, maximum=MAX_EXTENT_M)
    if bounds[0] >= bounds[1]:
        raise r.fail("bounds", f"expected [low, high] with low < high, got {list(bounds)}")
    return WalkSpec(
        bounds=bounds,
        min_start_goal_distance=r.number("min_start_goal_distance", d.min_start_goal_distance, nonneg=True,
                                          maximum=2 * MAX_EXTENT_M),
        max_actions=r.integer("max_actions", d.max_actions, minimum=1, maximum=MAX_ACTIONS),
        goal_tolerance=r.number("goal_tolerance", d.goal_tolerance, positive=True, maximum=2 * MAX_EXTENT_M),
        walk_length=r.integer("walk_length", d.walk_length, maximum=MAX_ACTIONS),
        n_candidates=r.integer("n_candidates", d.n_candidates, minimum=1, maximum=10_000),
    )


def _parse_target_region(r: _Reader | None, objects: tuple[ObjectSpec, ...]
                         ) -> tuple[tuple[float, float], tuple[float, float]]:
    """``[target_region] min = [x, y], max = [x, y]`` (metres): inside the workspace, min < max on both axes, and
    holding the target (its centre inside, its footprint not wider than the region); the workspace if absent."""
    if r is None:
        return WORKSPACE_M
    r.check_keys({"min", "max"})
    lo, hi = r.vector("min", 2), r.vector("max", 2)
    (w_lo_x, w_lo_y), (w_hi_x, w_hi_y) = WORKSPACE_M
    for k, v in (("min", lo), ("max", hi)):
        if not (w_lo_x <= v[0] <= w_hi_x and w_lo_y <= v[1] <= w_hi_y):
            raise r.fail(k, f"{list(v)} lies outside the workspace (x in [{w_lo_x:g}, {w_hi_x:g}] m, "
                            f"y in [{w_lo_y:g}, {w_hi_y:g}] m)")
    if not (lo[0] < hi[0] and lo[1] < hi[1]):
        raise r.fail("min", f"expected min < max on both axes, got min {list(lo)}, max {list(hi)}")
    target = next((o for o in objects if o.target), None)
    if target is None:
        raise r.fail("min", "a target region needs an object with target = true")
    short, long = target.footprint_sides_m
    width, height = sorted((hi[0] - lo[0], hi[1] - lo[1]))
    # Refuse only what cannot fit in any orientation: a side wider than the region's narrow side, or a long side
    # beyond its diagonal.
    if short > width or long > math.hypot(width, height):
        raise r.fail("max", f"the target {target.name!r} (footprint {short:.3f} x {long:.3f} m) does not fit in the "
                            f"region ({hi[0] - lo[0]:.3f} x {hi[1] - lo[1]:.3f} m)")
    cx, cy = target.centre_xy
    if not (lo[0] <= cx <= hi[0] and lo[1] <= cy <= hi[1]):
        raise r.fail("min", f"the target {target.name!r} (centre ({cx:.3f}, {cy:.3f}) m) lies outside the region")
    return lo, hi


def parse_scene(data: dict[str, Any], path: Path) -> Scene:
    """Validate a decoded TOML document into a :class:`Scene` (``path`` only names the file in errors)."""
    r = _Reader(path, data)
    r.check_keys(_TOP_KEYS)
    name = r.string("name", path.stem)
    if not re.fullmatch(NAME_PATTERN, name):
        raise r.fail("name", f"expected a plain identifier (a letter, then letters, digits or '_'; at most 64), "
                             f"got {name!r}{' (from the file name)' if 'name' not in data else ''}")
    kind = r.string("kind", choices=("retrieval", "training"))
    g = r.sub("gripper")
    start = None
    if g is not None:
        g.check_keys({"start"})
        start = g.vector("start", 2, None, maximum=MAX_EXTENT_M)
    p = r.sub("plane")
    plane = Plane()
    if p is not None:
        p.check_keys({"lateral_friction", "spinning_friction"})
        plane = Plane(p.number("lateral_friction", None, nonneg=True, maximum=MAX_FRICTION),
                      p.number("spinning_friction", None, nonneg=True, maximum=MAX_FRICTION))
    objects = tuple(_parse_object(o) for o in r.subs("objects"))
    if not objects:
        raise r.fail("objects", "a scene needs at least one [[objects]] entry")
    walls = tuple(_parse_wall(w, i) for i, w in enumerate(r.subs("walls")))
    names = [o.name for o in objects] + [w.name for w in walls]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise r.fail("objects", f"duplicate object/wall names: {', '.join(dup)}")
    effects = _parse_effects(r.sub("effects"), [o.name for o in objects])
    actions, scale, replay, stop_force = _parse_actions(r.sub("actions"))
    walk = _parse_walk(r.sub("walk"))
    region = _parse_target_region(r.sub("target_region"), objects)
    if kind == "retrieval":
        if actions is None and r.sub("target_region") is None:
            raise r.fail("actions", "a retrieval scene needs [actions] with a sequence, or a [target_region] to "
                                    "search (the explore policy)")
        if start is None:
            raise r.fail("gripper.start", "a retrieval scene needs the gripper start [x, y]")
        if sum(o.target for o in objects) != 1:
            raise r.fail("objects", "a retrieval scene needs exactly one object with target = true")
    if kind == "training" and walk is None:
        raise r.fail("walk", "a training scene needs a [walk] table (greedy random walk)")
    desc = r.string("description", "")
    if "\n" in desc.strip():
        raise r.fail("description", "expected one line")
    impossible = containment_problem(objects, walls, start)
    if impossible:
        raise r.fail("objects", impossible)
    return Scene(name=name, description=desc.strip(), kind=kind, path=path, gripper_start=start, plane=plane,
                 objects=objects, walls=walls, effects=effects, actions=actions, action_scale=scale, replay=replay,
                 stop_force_n=stop_force,
                 walk=walk, sensors=parse_sensors(r.sub("sensors")),
                 hardware=parse_hardware(r.sub("detection"), r.sub("methods")),
                 target_region=region, notes=r.string("notes", ""))
