"""The pushing models against the simulator, push by push: ``stucco bench pushes`` (docs/estimators.md, "Pushing
models").

Every action of a collected run that pushed the target (its isolation window's last true contact is on the target
and the gripper's in-contact displacement is at least ``MIN_PUSH``) is one case: the target's recorded pose before
and after it. Each pushing model of the pushtrack estimator (:data:`pipeline.estimators.pushtrack.params.MOTIONS`:
the point pusher at the true contact, the gripper's slice, translation, none) is run from the recorded pose before,
and, with ``replay``, pybullet itself: the action replayed from the recorded poses of every body (the whole scene)
and of the target alone (no other object, no wall). The errors against the recorded pose after say how much of
a model's error is the pusher's and the floor's physics (the target alone) and how much the clutter's (the whole
scene against the target alone).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from pipeline.atomic import together
from pipeline.estimators.pushtrack.filter import model_length, model_push
from pipeline.estimators.pushtrack.params import MOTIONS, SLICE_MOTIONS, PushTrackParams
from pipeline.estimators.pushtrack.slice_pusher import cached_gripper_slice, target_outline
from pipeline.estimators.run_info import load_run
from pipeline.geometry import wrap_angle
from pipeline.layout import partition
from pipeline.parallel import run_calls, single_threaded
from pipeline.safe_open import regular_file

__all__ = ["MIN_PUSH", "REPLAYS", "PushCase", "push_cases", "model_pose", "replay_pose", "push_rows", "summarise",
           "summary_markdown", "write_outputs"]

#: Shortest in-contact displacement (m) of a case: shorter touches barely move the target.
MIN_PUSH = 0.002
#: The pybullet replays: every body at its recorded pose, or the target alone.
REPLAYS = ("replay_scene", "replay_alone")


@dataclass(frozen=True)
class PushCase:
    """One push of the target (an action of a run).

    Attributes
    ----------
    step : int
        The action's index in the run.
    before, after : ndarray, shape (B, 3)
        Every body's recorded (x, y, yaw) before and after the action (m, rad).
    ee_start, ee_end : ndarray, shape (2,), metres
        The gripper's position at the action's start and end.
    command : ndarray, shape (2,), metres
        The commanded displacement (noise included), as the simulation executed it.
    contact : ndarray, shape (2,), metres
        The true contact point at the action's last step in contact.
    push : ndarray, shape (2,), metres
        The gripper's in-contact displacement.
    """

    step: int
    before: np.ndarray
    after: np.ndarray
    ee_start: np.ndarray
    ee_end: np.ndarray
    command: np.ndarray
    contact: np.ndarray
    push: np.ndarray


def push_cases(path: str | Path, target_id: int) -> list[PushCase]:
    """The pushes of the target ``target_id`` in one run file (the module docstring), in step order."""
    t = pq.read_table(regular_file(path, "the run file")).to_pydict()
    out = []
    for k in range(1, len(t["step"])):
        last = t["win_true_object"][k][-1] if t["win_true_object"][k] else -1
        d = np.array([t["contact_dx_m"][k], t["contact_dy_m"][k]], dtype=np.float64)
        cp = np.array([t["true_contact_x_m"][k], t["true_contact_y_m"][k]], dtype=np.float64)
        if not t["in_contact"][k] or last != target_id or not np.all(np.isfinite(np.r_[d, cp])):
            continue
        if math.hypot(d[0], d[1]) < MIN_PUSH:
            continue
        out.append(PushCase(step=k, before=np.asarray(t["obj_pose"][k - 1], dtype=np.float64),
                            after=np.asarray(t["obj_pose"][k], dtype=np.float64),
                            ee_start=np.array([t["ee_start_x_m"][k], t["ee_start_y_m"][k]]),
                            ee_end=np.array([t["ee_x_m"][k], t["ee_y_m"][k]]),
                            command=np.array([t["cmd_dx_m"][k], t["cmd_dy_m"][k]]), contact=cp, push=d))
    return out


def model_pose(motion: str, prim, case: PushCase, target_id: int, sdf, params: PushTrackParams = PushTrackParams()
               ) -> np.ndarray:
    """The target's COM pose (3,) after the push by the pushing model ``motion`` (``PushTrackParams.motion``) from
    its recorded pose before, as the pushtrack filter moves a particle (without its noise)."""
    params = dataclasses.replace(params, motion=motion)
    sweep = (cached_gripper_slice(sdf), target_outline(prim), case.ee_end) if motion in SLICE_MOTIONS else None
    return model_push(prim, case.before[target_id][None, :], params, case.contact, case.push,
                      model_length(prim, params), sweep)[0]


def _rest_heights(scene) -> list[float]:
    """Every object's resting height (m) in a settled world of ``scene`` (the replays place bodies at it)."""
    import pybullet as p

    from pipeline.sim import World

    eff = dataclasses.replace(scene.effects, wrench=False, contact_truth=False)
    with World(scene, eff, gripper_start=(-10.0, -10.0)) as w:
        return [p.getBasePositionAndOrientation(w.body_of[i], physicsClientId=w.client)[0][2]
                for i in range(len(scene.objects))]


def replay_pose(scene, case: PushCase, target_id: int, heights: Sequence[float], alone: bool) -> np.ndarray:
    """The target's pose (3,) after the action replayed in pybullet: every object put at its recorded pose before
    (at rest, upright), the gripper at the action's start, the same command; with ``alone`` the target only (no
    other object, no wall)."""
    import pybullet as p

    from pipeline.sim import World

    ids = [target_id] if alone else list(range(len(scene.objects)))
    if alone:
        scene = dataclasses.replace(scene, objects=(scene.objects[target_id],), walls=())
    eff = dataclasses.replace(scene.effects, wrench=False, contact_truth=False, settle_steps=0)
    with World(scene, eff) as w:
        for j, i in enumerate(ids):
            x, y, yaw = case.before[i]
            p.resetBasePositionAndOrientation(w.body_of[j], (x, y, heights[i]), p.getQuaternionFromEuler((0, 0, yaw)),
                                              physicsClientId=w.client)
        w.place(float(case.ee_start[0]), float(case.ee_start[1]), settle=False)
        w.act(float(case.command[0]), float(case.command[1]))
        return w.object_poses()[0 if alone else target_id]


def _wrap(a: float) -> float:
    return float(wrap_angle(a))


def _run_pushes(path: Path, replay: bool) -> list[dict]:
    """The rows of one run file (:func:`push_rows`)."""
    from pipeline.robot import load_robot

    with single_threaded():
        info = load_run(path)
        tid, prim, sdf = info.target_id, info.target, load_robot("panda")
        cases = push_cases(path, tid)
        heights = _rest_heights(info.scene) if replay and cases else []
        rows = []
        for case in cases:
            b, a = case.before[tid], case.after[tid]
            row = {"scene": info.scene.name, "seed": info.seed, "step": case.step,
                   "push_m": math.hypot(*case.push), "true_turn_rad": _wrap(a[2] - b[2]),
                   "true_shift_m": math.hypot(a[0] - b[0], a[1] - b[1])}
            poses = {m: model_pose(m, prim, case, tid, sdf) for m in MOTIONS}
            if replay:
                poses.update({r: replay_pose(info.scene, case, tid, heights, r == "replay_alone") for r in REPLAYS})
            for name, q in poses.items():
                row[f"{name}_turn_rad"] = _wrap(float(q[2] - b[2]))
                row[f"{name}_yaw_error_rad"] = abs(_wrap(float(q[2] - a[2])))
                row[f"{name}_position_error_m"] = math.hypot(float(q[0] - a[0]), float(q[1] - a[1]))
            rows.append(row)
        return rows


def push_rows(runs_dir: str | Path, pairs: Sequence[tuple[str, int]], replay: bool = True, jobs: int = 1,
              progress: Callable | None = None) -> list[dict]:
    """One row per push of the target in the runs ``pairs`` ((scene, seed)) of an evaluation directory's
    ``runs/`` (``stucco evaluate`` layout): the push, the true motion, and every model's and replay's turn (rad),
    yaw error (rad) and position error (m), in grid and step order."""
    args = [(partition(Path(runs_dir), "runs", sc, int(s)), bool(replay)) for sc, s in pairs]
    results = run_calls(_run_pushes, args, jobs)
    if progress is not None:
        results = progress(results, total=len(args))
    return [r for chunk in results for r in chunk]


def summarise(rows: Sequence[dict]) -> list[dict]:
    """Per task and model (the pushing models, then the replays present): pushes, median and 90th percentile of
    the yaw error (rad), median position error (m)."""
    names = [m for m in MOTIONS + REPLAYS if rows and f"{m}_yaw_error_rad" in rows[0]]
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == scene]
        for m in names:
            yaw = np.array([r[f"{m}_yaw_error_rad"] for r in mine])
            pos = np.array([r[f"{m}_position_error_m"] for r in mine])
            out.append({"scene": scene, "model": m, "pushes": len(mine),
                        "median_true_turn_rad": float(np.median([abs(r["true_turn_rad"]) for r in mine])),
                        "median_yaw_error_rad": float(np.median(yaw)),
                        "p90_yaw_error_rad": float(np.quantile(yaw, 0.9)),
                        "median_position_error_m": float(np.median(pos))})
    return out


def summary_markdown(summary: Sequence[dict]) -> str:
    """The summary as a markdown table: per task, each model's median (90th percentile) yaw error and median
    position error."""
    lines = ["| task | model | pushes | median true turn rad | yaw error rad, median (p90) | position error mm, "
             "median |", "|---|---|---|---|---|---|"]
    for r in summary:
        lines.append(f"| {r['scene']} | {r['model']} | {r['pushes']} | {r['median_true_turn_rad']:.3f} | "
                     f"{r['median_yaw_error_rad']:.3f} ({r['p90_yaw_error_rad']:.3f}) | "
                     f"{1000.0 * r['median_position_error_m']:.1f} |")
    return "\n".join(lines) + "\n"


@together()  # its outputs appear all together or not at all
def write_outputs(rows: Sequence[dict], out: str | Path) -> tuple[Path, Path, Path]:
    """``pushes.csv`` (one row per push), ``pushes_summary.csv`` and ``pushes.png`` (per task, each model's yaw
    errors as a box plot) into ``out``, each written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.atomic import save_figure, write_csv_rows

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(rows)
    paths = (out / "pushes.csv", out / "pushes_summary.csv", out / "pushes.png")
    write_csv_rows(paths[0], rows, list(rows[0]) if rows else ["scene", "seed", "step"])
    write_csv_rows(paths[1], summary, list(summary[0]) if summary else ["scene", "model"])
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    names = list(dict.fromkeys(r["model"] for r in summary))
    fig, axes = plt.subplots(1, max(1, len(scenes)), figsize=(3.2 * max(1, len(scenes)), 3.6), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        mine = [r for r in rows if r["scene"] == scene]
        ax.boxplot([[r[f"{m}_yaw_error_rad"] for r in mine] for m in names], showfliers=False)
        ax.set_xticks(np.arange(1, len(names) + 1), names, rotation=45, ha="right", fontsize=7)
        ax.set_title(f"{scene} ({len(mine)} pushes)", fontsize=9)
        ax.set_ylabel("yaw error per push, rad")
    fig.tight_layout()
    save_figure(fig, paths[2])
    return paths
