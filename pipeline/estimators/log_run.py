"""A robot's own log as the estimators' input: the target given by its shape, the gripper's trail and contacts
from a contacts table, no simulated run (docs/retrieval.md, "Retrieval from a robot's log").

:func:`parse_target` reads a target spec (``box:0.0616x0.1575``, ``cylinder:0.039``, optionally ``@10`` for a
known mass in kg, or ``SCENE:OBJECT`` for an object of a scene file); :func:`log_runs` builds the
:class:`~pipeline.estimators.run_info.RunInfo` of every run of a contacts table: the trail (the first step's
``ee_start_*`` as the start when given), the steps, each step's contact point and in-contact displacement as the
log recorded them, and the contact force when the table has ``force_n``. There is no scene, no recorded pose and so
no ground truth: every estimator runs on it as on a simulated run; nothing can be grasped or scored.
"""
from __future__ import annotations

import math
import re

import numpy as np
import pyarrow as pa

from pipeline.estimators.run_info import RunInfo
from pipeline.geometry import Primitive, primitive_of

__all__ = ["parse_target", "log_runs", "LOG_POLICY"]

#: The ``policy`` of a run read from a log (no collection policy made it).
LOG_POLICY = "log"

_NUMBER = r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"
_BOX = re.compile(rf"box:{_NUMBER}x{_NUMBER}(?:@{_NUMBER})?")
_CYLINDER = re.compile(rf"cylinder:{_NUMBER}(?:@{_NUMBER})?")
#: Largest target side or radius accepted (m): a spec in millimetres is refused rather than read as metres.
MAX_SIZE_M = 2.0
#: Largest gap (m) between a step's start and the previous step's end in a log.
MAX_GAP_M = 0.001


def _size(text: str, value: str, what: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and 0.0 < v <= MAX_SIZE_M):
        raise ValueError(f"--target {text!r}: {what} {value} m must be in (0, {MAX_SIZE_M}] (metres)")
    return v


#: A shipped scene whose target's grasp plan is the one :func:`pipeline.grasp.plan_for` gives a scene of its own, by
#: target shape (tested in tests/test_log_route.py).
_PLAN_SCENE = {"box": "REAL", "cylinder": "TC"}


def parse_target(text: str) -> tuple[Primitive, float, object]:
    """(primitive, mass kg or NaN, the scene whose grasp plan stands for the log's) of a target spec.

    * ``box:WxL``: a box of full extents W (its short side, the grasp's closing axis) by L (long side), metres;
    * ``cylinder:R``: an upright cylinder of radius R, metres;
    * either with ``@M``: its known mass M, kg (the segment choice by resistance needs it);
    * ``SCENE:OBJECT``: object OBJECT of a shipped scene or of a scene file, with its mass.

    The grasp plan's scene is the spec's scene, or one whose plan :func:`pipeline.grasp.plan_for` gives any scene
    of its own with a target of that shape (a box: REAL's, the deeper approach; a can: TC's).

    ValueError (one line naming the spec) for anything else."""
    from pipeline.scenes import SceneError, load_scene

    text = str(text).strip()
    m = _BOX.fullmatch(text)
    if m:
        w, length = _size(text, m.group(1), "width"), _size(text, m.group(2), "length")
        if w > length:
            raise ValueError(f"--target {text!r}: the width {w} m is the short side; give it first (box:WxL, W <= L)")
        mass = float(m.group(3)) if m.group(3) else math.nan
        box = Primitive(kind="box", half=(w / 2, length / 2), centre=np.zeros(2), yaw=0.0, name="target")
        return box, mass, load_scene(_PLAN_SCENE["box"])
    m = _CYLINDER.fullmatch(text)
    if m:
        r = _size(text, m.group(1), "radius")
        mass = float(m.group(2)) if m.group(2) else math.nan
        can = Primitive(kind="cylinder", half=(r,), centre=np.zeros(2), yaw=0.0, name="target")
        return can, mass, load_scene(_PLAN_SCENE["cylinder"])
    scene_name, sep, obj = text.rpartition(":")
    # A size after the colon is a shape spec gone wrong (sphere:1, box:-1x2), not an object of a scene.
    if sep and scene_name and obj and not re.fullmatch(r"[-+0-9.eEx@]+", obj):
        try:
            scene = load_scene(scene_name)
        except SceneError as e:
            raise ValueError(f"--target {text!r}: {e}") from None
        spec = next((o for o in scene.objects if o.name == obj), None)
        if spec is None:
            raise ValueError(f"--target {text!r}: scene {scene.name} has no object {obj!r} "
                             f"(objects: {', '.join(o.name for o in scene.objects)})")
        # the grasp plan of the scene is its target's: another object takes the paper's task of its shape
        plan_scene = scene if spec.target else load_scene(_PLAN_SCENE[spec.shape])
        return primitive_of(spec), float(spec.mass), plan_scene
    raise ValueError(f"--target {text!r}: expected box:WxL or cylinder:R (metres, optionally @MASS_KG), or "
                     "SCENE:OBJECT")


def _f64(table: pa.Table, name: str) -> np.ndarray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)


def log_runs(contacts: pa.Table, target: Primitive, mass_kg: float = math.nan, grasp_scene=None
             ) -> dict[str, RunInfo]:
    """Run -> the :class:`RunInfo` of each run of a validated contacts table (steps non-decreasing), for a target
    of shape ``target``, mass ``mass_kg`` and grasp plan of ``grasp_scene`` (:func:`parse_target`). A step with
    several rows (simultaneous contacts) keeps its first in-contact row's point and displacement: the estimators
    take one contact per action."""
    runs = np.asarray(contacts.column("run").to_pylist(), dtype=object)
    step = np.asarray(contacts.column("step").to_numpy(zero_copy_only=False), dtype=np.int64)
    ee = np.column_stack([_f64(contacts, "ee_x_m"), _f64(contacts, "ee_y_m")])
    inc = np.asarray(contacts.column("in_contact").to_numpy(zero_copy_only=False), dtype=bool)
    point = np.column_stack([_f64(contacts, "contact_x_m"), _f64(contacts, "contact_y_m")])
    push = np.column_stack([_f64(contacts, "dx_m"), _f64(contacts, "dy_m")])
    names = contacts.column_names
    start = np.column_stack([_f64(contacts, "ee_start_x_m"), _f64(contacts, "ee_start_y_m")]) \
        if "ee_start_x_m" in names and "ee_start_y_m" in names else np.full_like(ee, np.nan)
    force = _f64(contacts, "force_n") if "force_n" in names else None
    out: dict[str, RunInfo] = {}
    for run in dict.fromkeys(runs):
        rows = np.flatnonzero(runs == run)
        steps, first = np.unique(step[rows], return_index=True)
        # per step: its first in-contact row if any, else its first row (steps are sorted within a run)
        pick = rows[first].copy()
        touching = rows[inc[rows]]
        t_steps, t_first = np.unique(step[touching], return_index=True)
        pick[np.searchsorted(steps, t_steps)] = touching[t_first]
        # a step that starts away from where the last one ended: the gripper moved unlogged, and a straight line
        # between the two would be claimed as free space it never swept
        gap = np.hypot(*(start[pick[1:]] - ee[pick[:-1]]).T)
        bad = np.flatnonzero(np.isfinite(gap) & (gap > MAX_GAP_M))
        if len(bad):
            k = int(bad[0]) + 1
            raise ValueError(f"run {run!r}, step {int(steps[k])}: starts {gap[k - 1] * 1000:.1f} mm from where step "
                             f"{int(steps[k - 1])} ended (ee_start_* against ee_*); a log must be contiguous")
        at_start = start[rows[0]] if np.all(np.isfinite(start[rows[0]])) else ee[rows[0]]
        contact = np.where(inc[pick, None], point[pick], np.nan)
        moved = np.nan_to_num(np.where(inc[pick, None], push[pick], 0.0))
        out[str(run)] = RunInfo(
            run=str(run), path=None, scene=None, seed=0, ee=np.vstack([at_start[None, :], ee[pick]]), steps=steps,
            final_poses=None, target_id=0, target=target, policy=LOG_POLICY,
            contact_force=None if force is None else force[pick], target_mass_kg=float(mass_kg),
            observed=(contact, moved), grasp_scene=grasp_scene)
    return out
