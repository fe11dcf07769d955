"""Collected run files as retrieval and scoring need them, and the per-run random streams of retrieval."""
from __future__ import annotations

import dataclasses
import hashlib
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import schema
from pipeline.detection import contact_forces, scene_detection
from pipeline.estimators.segment_choice import target_mass
from pipeline.estimators.target_model import target_primitive
from pipeline.geometry import Primitive
from pipeline.safe_open import regular_file
from pipeline.scenes import Scene, SceneError, load_scene, scene_digest, scene_from_text, scene_names
from pipeline.seeds import check_stream, run_key

__all__ = ["RunInfo", "load_run", "info_from_table", "run_files_by_name", "retrieval_rng", "run_scene", "check_runs"]


@dataclass(frozen=True, eq=False)
class RunInfo:
    """What retrieval and scoring need from a collected run file (``sim_run`` table, docs/simulation.md).

    Attributes
    ----------
    run : str
    path : Path or None
    scene : pipeline.scenes.Scene
    seed : int
    ee : ndarray, shape (K + 1, 2), metres
        Gripper positions visited: the start of the first action, then the end of every action.
    steps : ndarray, shape (K,), int64
        Step (action index) of each action, as the contacts table numbers them: action k moved the gripper from
        ``ee[k]`` to ``ee[k + 1]``.
    final_poses : ndarray, shape (B, 3)
        Every body's inertial-frame (x, y, yaw) after the last action, in ``scene.body_names`` order.
    target_id : int
    target : Primitive
    policy : str
        The collection policy that made the run (``params.policy``; ``scripted`` when not recorded): a policy of
        the active protocol has its own retrieval (:attr:`pipeline.registry.PolicySpec.retrieval`).
    contact_force : ndarray, shape (K,), N, or None
        The contact force each action met (:func:`pipeline.detection.contact_forces`; NaN without contact).
    target_mass_kg : float
        The target's known mass (NaN: unknown), for the segment choice by resistance.
    observed : (ndarray (K, 2), ndarray (K, 2)) or None
        Each action's contact point (NaN without) and the gripper's in-contact displacement (0 without), metres,
        as a robot's log gives them (:mod:`pipeline.estimators.log_run`); None: re-isolated from the run file.
    grasp_scene : pipeline.scenes.Scene or None
        For a log: the scene whose grasp plan and action scale an estimator that weighs the paper's grasp uses (the
        scene of a ``SCENE:OBJECT`` target, else the paper's task of the target's shape); None: ``scene``'s own.
    final_tilted : dict of int -> ndarray (7,)
        The bodies that ended knocked over or leaning (``params.tilted`` of the run file): body index -> inertial
        frame [x, y, z, qx, qy, qz, qw]; the grasp restores them so (:func:`pipeline.grasp.restore_world`). Empty:
        every body ended upright, or the run was recorded before tilts were.

    A run from a robot's log has no scene (``scene`` None), no recorded poses (``final_poses`` None) and no path.
    """

    run: str
    path: Path | None
    scene: Any
    seed: int
    ee: np.ndarray
    steps: np.ndarray
    final_poses: np.ndarray
    target_id: int
    target: Primitive
    policy: str = "scripted"
    contact_force: np.ndarray | None = None
    target_mass_kg: float = float("nan")
    observed: tuple[np.ndarray, np.ndarray] | None = None
    grasp_scene: Any = None
    final_tilted: dict = field(default_factory=dict)

    @property
    def final_ee(self) -> np.ndarray:
        return self.ee[-1]

    @property
    def true_pose(self) -> np.ndarray | None:
        """The target's pose after the last action (3,); None for a robot's log (no ground truth)."""
        return None if self.final_poses is None else self.final_poses[self.target_id]


def load_run(path: str | Path) -> RunInfo:
    """Read a collected run file (one (scene, seed)); SchemaError naming the file and column on problems."""
    path = Path(path)
    t, meta = schema.read_run_and_metadata(path)
    params = meta.get("params") or {}
    scene = run_scene(path, params)
    bodies = params.get("bodies")
    if bodies is not None and list(bodies) != list(scene.body_names):
        raise schema.SchemaError(path, "obj_pose", None, f"bodies {bodies} differ from scene {scene.name}'s "
                                                         f"{list(scene.body_names)}; was the scene file edited?")
    final = np.asarray(t.column("obj_pose")[t.num_rows - 1].as_py(), dtype=np.float64).reshape(-1, 3)
    if final.shape[0] != len(scene.body_names):
        raise schema.SchemaError(path, "obj_pose", t.num_rows - 1,
                                 f"has {final.shape[0]} bodies; scene {scene.name} has {len(scene.body_names)}")
    return dataclasses.replace(info_from_table(t, scene, path, final, str(params.get("policy") or "scripted")),
                               final_tilted=_tilted(path, params.get("tilted"), list(scene.body_names)))


def _tilted(path: Path, recorded, bodies: list) -> dict:
    """``params.tilted`` of a run file ({body name: [x, y, z, qx, qy, qz, qw]}) by body index; SchemaError naming
    the file and the key when it is not that."""
    out: dict[int, np.ndarray] = {}
    if recorded is None:
        return out
    if not isinstance(recorded, dict):
        raise schema.SchemaError(path, "params.tilted", None, "is not a mapping of body names to poses")
    for name, pose in recorded.items():
        try:
            v = np.asarray(pose, dtype=np.float64)
        except (TypeError, ValueError):
            v = np.zeros(0)
        if name not in bodies or v.shape != (7,) or not np.all(np.isfinite(v)) or \
                not abs(float(np.sum(v[3:] ** 2)) - 1.0) < 1e-6:
            raise schema.SchemaError(path, "params.tilted", None, f"{name!r}: not a body of the scene with a finite "
                                                                  "[x, y, z, qx, qy, qz, qw] (a unit quaternion)")
        out[bodies.index(name)] = v
    return out


def info_from_table(t: pa.Table, scene: Scene, path: Path | None = None, final: np.ndarray | None = None,
                    policy: str = "scripted") -> RunInfo:
    """The :class:`RunInfo` of a run's ``sim_run`` rows ``t`` collected in ``scene``: the gripper's path, the
    steps and the contact forces from the rows; ``final`` the bodies' final poses (B, 3), NaN when None (then
    nothing of the rows' recorded poses, ground truth, is read: the probing policy's view of its run)."""
    f64 = lambda c: np.asarray(t.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)  # noqa: E731
    ee = np.vstack([[f64("ee_start_x_m")[0], f64("ee_start_y_m")[0]], np.column_stack([f64("ee_x_m"), f64("ee_y_m")])])
    final = np.full((len(scene.body_names), 3), np.nan) if final is None else final
    tid, prim = target_primitive(scene)
    return RunInfo(run=t.column("run")[0].as_py(), path=path, scene=scene, seed=int(t.column("seed")[0].as_py()),
                   ee=ee, steps=np.asarray(t.column("step").to_numpy(zero_copy_only=False), dtype=np.int64),
                   final_poses=final, target_id=tid, target=prim, policy=policy,
                   contact_force=contact_forces(t, scene_detection(scene)),
                   target_mass_kg=target_mass(scene))


def run_scene(path: Path, params: dict) -> Scene:
    """The scene a run file was collected in: the TOML text its metadata carries (``params.scene_toml``), checked
    against its recorded SHA-256; for files written before runs carried their scene, the shipped scene of the
    recorded name. Never a file whose path a data file names (SchemaError naming the run file otherwise)."""
    name = params.get("scene")
    if not isinstance(name, str) or not name:
        raise schema.SchemaError(path, None, None, "metadata has no params.scene; expected a file from stucco collect")
    text, digest = params.get("scene_toml"), params.get("scene_sha256")
    if text:
        if not isinstance(text, str) or not isinstance(digest, str) or scene_digest(text) != digest:
            raise schema.SchemaError(path, None, None, "metadata params.scene_toml does not match its recorded "
                                                       "params.scene_sha256: the scene was edited after collection")
        try:
            scene = scene_from_text(text, path.parent / f"{path.name}#scene" / f"{name}.toml")
        except SceneError as e:
            raise schema.SchemaError(path, None, None, f"metadata params.scene_toml: {e}") from None
        if scene.name != name:
            raise schema.SchemaError(path, None, None, f"metadata params.scene {name!r} differs from the name "
                                                       f"{scene.name!r} of the scene it carries")
        return scene
    if name not in scene_names():  # a name, never a path: the metadata must not choose files to load
        raise schema.SchemaError(path, None, None, f"metadata params.scene {name[:60]!r} is not a shipped scene and "
                                                   "the file carries no scene (params.scene_toml); collect it again")
    return load_scene(name)


def check_runs(segments_path: str | Path, segments: pa.Table, files: dict[str, Path]) -> None:
    """Refuse (SchemaError naming the run file) a run file that is not the one ``segments`` were made from.

    Checked for every run of ``segments``, and every run they record they derive from (``stucco.runs``: a run
    tracked without any contact has no segment row), found in ``files`` (run name -> file): its root seed
    (``stucco.seed``) is the one the segments were made with; its last step is not before the step of the
    segments' final estimate (a truncated run, or a shorter run filed under this name, ends before it); and it is
    byte for byte the run the segments derive from, when they record it (its SHA-256 in ``stucco.runs``, carried
    from the contacts).
    """
    segments_path = Path(segments_path)
    seg_meta = schema.read_metadata(segments_path)
    seg_seed, recorded = seg_meta.get("seed"), seg_meta.get("runs") or {}
    runs = segments.column("run").to_pylist()
    steps = np.asarray(segments.column("step").to_numpy(zero_copy_only=False), dtype=np.int64)
    estimate = np.asarray(segments.column("estimate_step").to_numpy(zero_copy_only=False), dtype=np.int64)
    names = np.asarray(runs, dtype=object)
    for name in dict.fromkeys([*runs, *recorded]):
        path = files.get(name)
        if path is None:
            continue  # a missing run is the stage's own error
        seed = schema.read_metadata(path).get("seed")
        if isinstance(seed, int) and isinstance(seg_seed, int) and seed != seg_seed:
            raise schema.SchemaError(path, None, None,
                                     f"collected with root seed {seed}, but {segments_path.name} was made with seed "
                                     f"{seg_seed}: not the run it was tracked from")
        entry = recorded.get(name)
        if entry is not None and schema.file_digest(path) != entry:
            raise schema.SchemaError(path, None, None, f"not the run {name} that {segments_path.name} derives from "
                                                       f"(it recorded SHA-256 {entry[:12]}…, this file differs)")
        mine = names == name
        if not mine.any():
            continue  # no segment row: no step to reach
        run_steps = np.asarray(pq.read_table(path, columns=["step"]).column("step").to_numpy(), dtype=np.int64)
        last = int(max(estimate[mine].max(), steps[mine].max()))
        if not len(run_steps) or int(run_steps.max()) < last:
            raise schema.SchemaError(path, "step", None, f"run {name} ends at step "
                                     f"{int(run_steps.max()) if len(run_steps) else None}, but its segments in "
                                     f"{segments_path.name} were estimated at step {last}: a truncated run or "
                                     "another run under this name")


def _run_name(f: Path) -> str | None:
    """The run a collected run file holds (its first ``run``), or None for a Parquet file of another table kind;
    SchemaError for a file that is not Parquet or has no rows."""
    try:
        names = pq.read_schema(regular_file(f, "the run file")).names
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise schema.SchemaError(f, None, None, f"not a Parquet file ({' '.join(str(e).split())})") from None
    if "run" not in names or "obj_pose" not in names:
        return None
    try:
        runs = pq.read_table(f, columns=["run"]).column("run")
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise schema.SchemaError(f, None, None, f"unreadable ({' '.join(str(e).split())})") from None
    if not len(runs):
        raise schema.SchemaError(f, None, None, "has no actions; expected at least one row (a run file written by "
                                                "stucco collect)")
    return runs[0].as_py()


def run_files_by_name(directory: str | Path) -> dict[str, Path]:
    """Run name -> collected run file, for every ``*.parquet`` in ``directory`` (non-recursive), or for the one
    run file ``directory`` names."""
    # Only the `run` column is read here; the whole file is validated once, when load_run reads it.
    directory = Path(directory)
    if directory.is_file():
        name = _run_name(directory)
        if name is None:
            schema.read_run(directory)  # another table kind: raises the one-line error naming it
        return {name: directory}
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a directory of collected runs (nor a run file)")
    out: dict[str, Path] = {}
    for f in sorted(directory.glob("*.parquet")):
        try:
            regular = stat.S_ISREG(f.stat().st_mode)
        except OSError as e:  # a dangling link or a link loop
            raise schema.SchemaError(f, None, None, f"cannot be read ({e.strerror})") from None
        if not regular:  # opening a FIFO would wait for a writer for ever
            raise schema.SchemaError(f, None, None, "is not a regular file (a FIFO, socket or device); expected a "
                                                    "run file written by stucco collect")
        name = _run_name(f)
        if name is None:
            continue  # another table kind living in the same directory
        if name in out:
            raise ValueError(f"{directory}: run {name!r} is in both {out[name].name} and {f.name}")
        out[name] = f
    return out


#: Third entry of retrieval's SeedSequence: keeps its draws independent of the tracker's stream of the run.
_STREAM = int.from_bytes(hashlib.sha256(b"retrieve").digest()[:4], "little")
#: Fourth entry for the streams k >= 1: without it, stream k's generators would be those that stream 0's k-th
#: generator spawns (a SeedSequence's spawn key is appended to its entropy).
_OTHER_STREAM = int.from_bytes(hashlib.sha256(b"retrieve-stream").digest()[:4], "little")


def retrieval_rng(seed: int, run: str, stream: int = 0
                  ) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator]:
    """(model points, ICP restarts, pose hypotheses) generators of one run:
    SeedSequence([seed, run_key(run), STREAM]).spawn(3). Children are keyed by their index, so the first two are
    the streams the paper's estimator always had.

    ``stream`` k >= 1 gives an independent set of three, SeedSequence([seed, run_key(run), STREAM, OTHER,
    k]).spawn(3): every estimator rerun on the same segments with other random draws (the paper's model points and
    ICP restarts, which the others' segment choice shares, and their own), to see how much of a grasp success is
    the estimators' luck (``stucco evaluate --estimator-stream``; docs/evaluation.md, "The estimator's own
    randomness"). Stream 0 is the default and what every earlier table was made with."""
    stream = check_stream(stream)
    entropy = [int(seed), run_key(run), _STREAM] + ([_OTHER_STREAM, stream] if stream else [])
    return tuple(np.random.default_rng(c) for c in np.random.SeedSequence(entropy).spawn(3))
