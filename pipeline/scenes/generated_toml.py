"""A drawn :class:`~pipeline.scenes.generate.Layout` as a scene file's TOML text (docs/simulation.md, "Scenes are
data"), in the layout of the shipped task files, with the generic rummage as its ``[actions] sequence``.

The text is a pure function of the layout and the knobs (no clock, no host, no version), so the same draw gives
byte-identical files.
"""
from __future__ import annotations

from pipeline.scenes.catalogue import PLANE_LATERAL_FRICTION, PLANE_SPINNING_FRICTION
from pipeline.scenes.coverage import SIDES, coverage_passes
from pipeline.scenes.footprint import wall_outline
from pipeline.scenes.generate import GeneratorSpec, Layout
from pipeline.scenes.types import DEFAULT_ACTION_SCALE, ObjectSpec

__all__ = ["layout_actions", "layout_toml", "describe"]

#: Replay noise and settling of the generated scenes: the tasks' (docs/simulation.md, "Effects").
NOISE_MM = 0.5
SETTLE_STEPS = 1000
#: The rummage's force limit, N (``[actions] stop_force_n``): a leg is given up after an action that met it, above the
#: few newtons that push the clutter along and below the forces at which a heavy target pushed at the hand's height
#: tips over rather than slides (docs/scene_generator.md, "Guarded replay").
STOP_FORCE_N = 10.0
_ACTIONS_PER_LINE = 6


def layout_actions(layout: Layout, spec: GeneratorSpec) -> tuple[tuple[float, float], ...]:
    """The rummage of a layout: coverage passes over its target region from its gripper start, nothing else."""
    return coverage_passes(layout.region, layout.start, scale_m=DEFAULT_ACTION_SCALE,
                           lane_spacing_m=spec.lane_spacing_m, sides=SIDES,
                           walls=[wall_outline(w) for w in layout.walls])


def describe(layout: Layout, n_actions: int) -> str:
    """One line: what the scene holds."""
    target = layout.objects[0]
    walls = ", ".join(w.name for w in layout.walls) or "no walls"
    return (f"Generated: retrieve a {target.mass:.1f} kg {target.name} {layout.placement} "
            f"{len(layout.objects) - 1} distractors ({layout.hidden:.0%} of it hidden from the start); {walls}; "
            f"{n_actions} rummage actions (pokes) over the target region.")


def layout_toml(layout: Layout, spec: GeneratorSpec) -> str:
    """The scene file of ``layout`` (a ``kind = "retrieval"`` scene that :func:`pipeline.scenes.load_scene`
    accepts and ``stucco collect --policy scripted`` plays)."""
    actions = layout_actions(layout, spec)
    (rx0, ry0), (rx1, ry1) = layout.region
    lines = [
        "# Generated retrieval scene (stucco scenes generate; docs/scene_generator.md): YCB primitives of the tasks",
        "# (paper §V-D) drawn at random; the actions are a generic rummage of the target region, made from the",
        "# region and the gripper start only.",
        "",
        f'name = "{layout.name}"',
        'kind = "retrieval"',
        f"description = {_str(describe(layout, len(actions)))}",
        f"notes = {_str(f'seed {layout.seed}, index {layout.index}, draw {layout.draw}; {spec.summary()}')}",
        "",
        "[gripper]",
        f"start = {_vec(layout.start)}",
        "",
        "[target_region]  # the user knows the target lies in this rectangle, m",
        f"min = {_vec((rx0, ry0))}",
        f"max = {_vec((rx1, ry1))}",
        "",
        "[plane]",
        f"lateral_friction = {_num(PLANE_LATERAL_FRICTION)}",
        f"spinning_friction = {_num(PLANE_SPINNING_FRICTION)}",
        "",
        "[effects]",
        f"noise_mm = {_num(NOISE_MM)}",
        'movable = "all"',
        "friction = true",
        f"settle_steps = {SETTLE_STEPS}",
        "wrench = true",
        "contact_truth = true",
        "walls = true",
        "",
        "[actions]",
        f"scale = {_num(DEFAULT_ACTION_SCALE)}",
        'replay = "guarded"  # waypoints followed in closed loop, a leg given up where an object stops it',
        f"stop_force_n = {_num(STOP_FORCE_N)}  # N: or where what the hand pushes resists that much",
        "sequence = [",
    ]
    for k in range(0, len(actions), _ACTIONS_PER_LINE):
        lines.append("    " + ", ".join(_vec(a) for a in actions[k:k + _ACTIONS_PER_LINE]) + ",")
    lines.append("]")
    for o in layout.objects:
        lines += ["", *_object_lines(o)]
    for w in layout.walls:
        lines += ["", "[[walls]]", f'name = "{w.name}"', f"size = {_vec(w.size)}", f"position = {_vec(w.position)}",
                  f"yaw = {_num(w.yaw)}", f"z = {_num(w.z)}", f"lateral_friction = {_num(w.lateral_friction)}"]
    return "\n".join(lines) + "\n"


def _object_lines(o: ObjectSpec) -> list[str]:
    out = ["[[objects]]", f'name = "{o.name}"', f"model = {_str(o.model)}", f'shape = "{o.shape}"',
           f"size = {_vec(o.size)}", f"position = {_vec(o.position)}", f"yaw = {_num(o.yaw)}", f"mass = {_num(o.mass)}",
           f"lateral_friction = {_num(o.lateral_friction)}"]
    if o.spinning_friction is not None:
        out.append(f"spinning_friction = {_num(o.spinning_friction)}")
    if o.rolling_friction is not None:
        out.append(f"rolling_friction = {_num(o.rolling_friction)}")
    out += [f"shape_offset = {_vec(o.shape_offset)}"]
    if o.shape_yaw:
        out.append(f"shape_yaw = {_num(o.shape_yaw)}")
    out.append(f"com_offset = {_vec(o.com_offset)}")
    if o.com_yaw:
        out.append(f"com_yaw = {_num(o.com_yaw)}")
    if o.target:
        out.append("target = true")
    return out


def _num(x: float) -> str:
    """A float as TOML: Python's shortest round-tripping form (TOML reads it back to the same double)."""
    return repr(float(x) + 0.0)


def _vec(v) -> str:
    return "[" + ", ".join(_num(x) for x in v) + "]"


def _str(s: str) -> str:
    """A basic TOML string (the texts here hold no control characters)."""
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'
