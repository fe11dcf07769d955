"""The training set (SELECT1-4, paper §V-B): collected, isolated, its ground truth and ambiguity, tracked and
scored per method.

Runs are collected with the greedy random walk and its discard rule (docs/simulation.md, ``stucco collect``),
isolated into one contacts table and tracked by every method without retrieval; each run gets FMI, contact error
and run ambiguity (docs/studies.md, ``stucco study training``). :mod:`pipeline.studies.training_figure` and
:mod:`pipeline.studies.tuning` build on this module.
"""
from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from pipeline import registry, schema
from pipeline.action_summary import MIN_REP_FORCE_N
from pipeline.collect import collect, output_path
from pipeline.estimators.run_info import run_scene
from pipeline.evaluate import map_jobs, single_threaded
from pipeline.isolate import DetectionParams, IsolationParams, isolate_runs, params_dict
from pipeline.retrieve import Primitive, primitive_of
from pipeline.safe_open import regular_file
from pipeline.scenes import load_scene
from pipeline.score import contact_error_cm, fmi
from pipeline.segment import final_estimates, segment_table, segmentation_params

__all__ = ["TRAINING_SCENES", "TRAINING_SEEDS", "AMBIGUITY_DISTANCE_M", "MIN_REP_FORCE_N", "run_ambiguity",
           "collect_training", "training_scores", "load_training", "score_methods"]

TRAINING_SCENES = ("SELECT1", "SELECT2", "SELECT3", "SELECT4")
TRAINING_SEEDS = tuple(range(7, 47))
#: Distance (m) at which ambiguity reaches 0 (docs/studies.md, run ambiguity).
AMBIGUITY_DISTANCE_M = 0.15


def run_ambiguity(object_id: np.ndarray, obj_distance: np.ndarray) -> float:
    """Run ambiguity (docs/studies.md).

    Parameters
    ----------
    object_id : ndarray, shape (A,), int
        Ground-truth body of each action (-1: none), an index into the distance columns.
    obj_distance : ndarray, shape (A, B), metres
        Every body's distance to the gripper after each action.

    Returns
    -------
    float
        At each action end, d2 = the second smallest distance to the bodies the run ever contacted and
        a = clip(0.15 - d2, 0, inf) / 0.15; a 0 is prepended (the first action starts away from clutter), so
        action k gets the ambiguity of the state it started from; the run's value is the mean over actions with
        ground-truth contact (0 with fewer than 2 contacted bodies or no contact).
    """
    ids = np.asarray(object_id, dtype=np.int64)
    dist = np.asarray(obj_distance, dtype=np.float64).reshape(len(ids), -1)
    touched = np.unique(ids[ids >= 0])
    if len(touched) < 2 or not (ids >= 0).any():
        return 0.0
    d = np.sort(dist[:, touched], axis=1)[:, 1]
    a_end = np.clip(AMBIGUITY_DISTANCE_M - d, 0.0, None) / AMBIGUITY_DISTANCE_M
    a = np.concatenate([[0.0], a_end])[: len(ids)]
    return float(np.mean(a[ids >= 0]))


def collect_training(out: str | Path, scenes: Sequence[str] = TRAINING_SCENES,
                     seeds: Sequence[int] = TRAINING_SEEDS, *, root_seed: int = 0, jobs: int = 1,
                     progress: bool | None = None, max_actions: int | None = None) -> list[dict[str, Any]]:
    """Collect the greedy-walk runs into ``out/runs`` (discarded ones too, their verdict in the metadata) unless
    present; one dict per (scene, seed): scene, seed, path, discarded (reason or None)."""
    runs_dir = Path(out) / "runs"
    info = []
    for sc in scenes:
        scene = load_scene(sc)
        missing = [s for s in seeds if not output_path(runs_dir, scene.name, s).is_file()]
        if missing:
            collect(scene, list(missing), runs_dir, policy=registry.default_policy("training"), root_seed=root_seed,
                    jobs=jobs, progress=progress, max_actions=max_actions, keep_discarded=True)
        for s in seeds:
            path = output_path(runs_dir, scene.name, s)
            meta = schema.read_metadata(path).get("params") or {}
            info.append(dict(scene=scene.name, seed=int(s), path=path, discarded=meta.get("discarded")))
    return info


def _run_truth(path: Path) -> dict[str, Any]:
    """Per run: scene, final poses (B, 3), ground truth per step (force-masked, -1 = none), ambiguity."""
    t = pq.read_table(regular_file(path, "the run file"),
                      columns=["run", "step", "object_id", "force_rep_x_n", "force_rep_y_n", "obj_pose",
                                     "obj_distance_m"])
    params = schema.read_metadata(path).get("params") or {}
    scene = run_scene(path, params)  # the scene the run carries, never a path named in its metadata
    ids = t.column("object_id").to_numpy().astype(np.int64)
    force = np.hypot(t.column("force_rep_x_n").to_numpy(), t.column("force_rep_y_n").to_numpy())
    # The collect stage's label rule (docs/simulation.md): below MIN_REP_FORCE_N newtons, no ground truth.
    truth = np.where(force >= MIN_REP_FORCE_N, ids, -1)
    nb = len(scene.body_names)
    dist = np.asarray(t.column("obj_distance_m").to_pylist(), dtype=np.float64).reshape(t.num_rows, nb)
    final = np.asarray(t.column("obj_pose")[t.num_rows - 1].as_py(), dtype=np.float64).reshape(nb, 3)
    return dict(run=t.column("run")[0].as_py(), scene=scene, truth=dict(zip(t.column("step").to_pylist(), truth)),
                ambiguity=run_ambiguity(truth, dist), final=final)


def _training_primitive(spec) -> Primitive:
    """The body's horizontal slice for the contact error. Upright primitives as in :mod:`pipeline.score`; a
    cylinder lying on its side (SELECT2's ``topple_cylinder``, rp = (0, pi/2)) has a 2r x h rectangular slice
    whose yaw the recorded pose cannot give (the yaw of a body pitched 90 degrees is gimbal-locked), so it is
    approximated by a circle of the mean half-extent (r = 0.12, h/2 = 0.125 for SELECT2: exact at the face
    centres, up to about 5 cm off towards the slice's corners)."""
    try:
        return primitive_of(spec)
    except ValueError:
        if getattr(spec, "shape", None) != "cylinder":
            raise
        r, h = float(spec.size[0]), float(spec.size[1])
        return Primitive(kind="cylinder", half=((r + h / 2.0) / 2.0,), centre=np.zeros(2), yaw=0.0, name=spec.name)


def _isolate_training(out: Path, files: list[Path]) -> pa.Table:
    """The contacts of the kept runs, isolated once into ``out/contacts.parquet`` (reused while the same run
    files are kept)."""
    path = out / "contacts.parquet"
    names = sorted(str(f.name) for f in files)
    if path.is_file() and (schema.read_metadata(path).get("params") or {}).get("files") == names:
        return schema.read_contacts(path)
    det, iso = DetectionParams(), IsolationParams()
    res = isolate_runs(sorted(files), det, iso)
    schema.write_table(res.table, path, stage="isolate", params=dict(params_dict(det, iso), files=names), seed=0,
                       kind="contacts")
    return res.table


def training_scores(contacts: pa.Table, truths: dict[str, dict], method: str, params: dict | None = None, *,
                    root_seed: int = 0, robot: str = "panda") -> list[dict[str, Any]]:
    """Track every training run with one method and parameter set; FMI, CE (cm) and ambiguity per run.

    The contact error is :func:`pipeline.score.contact_error_cm` at the run's final poses, with the lying
    cylinder approximated (:func:`_training_primitive`).
    """
    # Imported here: the trackers load numba's kernels, which only the processes that track need.
    from pipeline.track.stage import TrackConfig, track_table

    params = dict(params or {})
    config = TrackConfig(method=method, robot=robot, params=params)
    t0 = time.perf_counter()
    tracks, diagnostics = track_table(contacts, config, seed=root_seed, jobs=1)
    length, alpha = segmentation_params(method, params)
    final = final_estimates(segment_table(tracks, length=length, alpha=alpha, by="auto", method=method))
    wall = time.perf_counter() - t0
    run = np.asarray(final.column("run").to_pylist(), dtype=object)
    xy = np.column_stack([final.column("x_m").to_numpy(), final.column("y_m").to_numpy()])
    seg = final.column("segment").to_numpy()
    step = final.column("step").to_numpy()
    rows = []
    for name, tr in truths.items():
        m = run == name
        truth = np.array([tr["truth"].get(int(s), -1) for s in step[m]], dtype=np.int64)
        rows.append(dict(scene=tr["scene"].name, run=name, method=method, params=json.dumps(params, sort_keys=True),
                         fmi=fmi(truth, seg[m]) if m.any() else None,
                         contact_error_cm=contact_error_cm(xy[m], tr["scene"], tr["final"],
                                                           primitive=_training_primitive),
                         ambiguity=tr["ambiguity"], n_points=int(m.sum()), track_wall_s=wall / max(len(truths), 1)))
    return rows


def load_training(out: Path, scenes, seeds, root_seed, jobs, progress, max_actions
                  ) -> tuple[list[dict[str, Any]], pa.Table, dict[str, dict]]:
    """Collect (:func:`collect_training`) and isolate the training set; (collect info, contacts of the kept
    runs, run name -> ground truth). ValueError if every run was discarded."""
    info = collect_training(out, scenes, seeds, root_seed=root_seed, jobs=jobs, progress=progress,
                            max_actions=max_actions)
    kept = [r for r in info if r["discarded"] is None]
    if not kept:
        raise ValueError("every training run was discarded; nothing to track")
    contacts = _isolate_training(out, [r["path"] for r in kept])
    truths = {}
    for r in kept:
        tr = _run_truth(r["path"])
        truths[tr["run"]] = tr
    return info, contacts, truths


def score_methods(contacts, truths, settings: list[tuple[str, dict]], root_seed: int, jobs: int,
                  progress) -> list[dict]:
    """:func:`training_scores` of every (method, parameters) in ``settings``, over ``jobs`` processes."""
    args = [(contacts, truths, m, p, root_seed) for m, p in settings]
    with tqdm(total=len(args), desc="track", unit="setting", disable=progress) as bar:
        return [r for chunk in map_jobs(_score_setting, args, jobs, bar) for r in chunk]


def _score_setting(contacts, truths, method, params, root_seed):
    with single_threaded():
        return training_scores(contacts, truths, method, params, root_seed=root_seed)
