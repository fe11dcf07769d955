"""Run a scene in pybullet and record one Parquet file per (scene, seed): the ``sim_run`` table.

The gripper moves by a policy of :mod:`pipeline.registry` (``scripted``, ``greedy-walk``: :mod:`pipeline.policies`,
docs/simulation.md, "`stucco collect`"); runs of a policy that discards (the greedy walk) failing the discard rule
(paper §V-B; docs/simulation.md) are not written unless asked.

Every random draw of a job comes from ``numpy.random.SeedSequence([root_seed, scene_hash(scene), seed])``
(children: 0 = replay noise, 1 = policy), so every method sees the same scene and actions for a given seed.

The ``sim_run`` table has one row per action; see :data:`pipeline.schema.SIM_RUN` (columns, units, rules) and
docs/simulation.md. Files are written atomically with :func:`pipeline.schema.write_table`; the same scene, seed
and effects give byte-identical files.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import registry
from pipeline.action_summary import WINDOW_STEPS, action_label, discard_reason, representative_force, summarize_action
from pipeline.detection import DetectionParams, scene_detection
from pipeline.parallel import map_jobs
from pipeline.scenes import Scene, SceneError, scene_digest, scene_hash
from pipeline.schema import PAD_COLUMNS, SIM_RUN, write_table
from pipeline.sim import STEPS_PER_ACTION, World

__all__ = ["RUN_KIND", "WINDOW_STEPS", "parse_seeds", "job_seed_sequence", "run_name",
           "output_path", "collect_run", "collect_file", "collect", "summarize_action", "action_label",
           "representative_force", "discard_reason", "CollectResult"]

RUN_KIND = SIM_RUN.name


# ---------------------------------------------------------------------------------------------------------------
# Seeds
# ---------------------------------------------------------------------------------------------------------------


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-19"``, ``"3"``, ``"0,2,5-7"``; raises ValueError naming the bad part."""
    seeds: set[int] = set()
    for part in str(text).split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise ValueError(f"seed range {part!r}: expected N, N-M or a comma-separated list of them")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise ValueError(f"seed range {part!r}: end before start")
        if hi > MAX_SEED:
            raise ValueError(f"seed range {part!r}: seeds are at most {MAX_SEED}")
        if len(seeds) + hi - lo + 1 > MAX_SEEDS:  # checked before the range is made: 0-1000000000 is 8 GB of ints
            raise ValueError(f"seed range {part!r}: at most {MAX_SEEDS} seeds per command (one simulated run each)")
        seeds.update(range(lo, hi + 1))
    return sorted(seeds)


#: Most seeds one command takes (each is a simulated run of seconds), and the largest seed (a uint32 of the
#: job's SeedSequence, docs/simulation.md).
MAX_SEEDS = 100_000
MAX_SEED = 2**32 - 1


def job_seed_sequence(root_seed: int, scene_name: str, seed: int) -> np.random.SeedSequence:
    """The job's SeedSequence([root_seed, scene_hash(scene_name), seed])."""
    return np.random.SeedSequence([int(root_seed), scene_hash(scene_name), int(seed)])


def run_name(scene_name: str, seed: int) -> str:
    return f"{scene_name}/{seed}"


def output_path(out_dir: str | Path, scene_name: str, seed: int) -> Path:
    """``<out_dir>/<scene>-<seed:03d>.parquet``."""
    return Path(out_dir) / f"{scene_name}-{seed:03d}.parquet"


# ---------------------------------------------------------------------------------------------------------------
# One run
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class CollectResult:
    """What one job did (returned to the parent process; the data itself is in ``path``)."""

    scene: str
    seed: int
    path: Path | None
    n_actions: int
    n_contact: int
    touched: dict[str, int]
    discarded: str | None
    wall_s: float
    sim_s: float
    probe_s: dict | None = None  # a policy's wall times (s), e.g. the probing policy's; kept out of the file


def _fixed_list(a: np.ndarray) -> pa.Array:
    """Nested fixed-size lists of float64 (or int64) from an (A, d1, ..., dk) array."""
    a = np.ascontiguousarray(a)
    arr = pa.array(a.reshape(-1))
    for size in reversed(a.shape[1:]):
        arr = pa.FixedSizeListArray.from_arrays(arr, size)
    return arr


def _body_list(a: np.ndarray) -> pa.Array:
    """Per-body values from an (A, bodies, ...) array: a list per action (its length is the scene's number of
    bodies, which differs between scenes, so run files of several scenes still read as one table)."""
    a = np.ascontiguousarray(a)
    n, nb = a.shape[:2]
    inner = _fixed_list(a.reshape(n * nb, *a.shape[2:])) if a.ndim > 2 else pa.array(a.reshape(-1))
    return pa.ListArray.from_arrays(pa.array(np.arange(0, n * nb + 1, nb, dtype=np.int32)), inner)


def _build_table(scene: Scene, seed: int, rows: list[dict], probe_from: int | None = None) -> pa.Table:
    n = len(rows)
    name = run_name(scene.name, seed)

    def col(k, typ=pa.float64()):
        return pa.array([r[k] for r in rows], type=typ)

    nb = len(scene.body_names)
    data = {
        "run": pa.array([name] * n, type=pa.string()),
        "scene": pa.array([scene.name] * n, type=pa.string()),
        "seed": pa.array([seed] * n, type=pa.int64()),
        "step": pa.array(np.arange(n), type=pa.int64()),
    }
    for k in ("ee_start_x_m", "ee_start_y_m", "ee_x_m", "ee_y_m", "ee_z_m", "ee_yaw_rad", "cmd_ux", "cmd_uy",
              "cmd_dx_m", "cmd_dy_m", "exec_dx_m", "exec_dy_m"):
        data[k] = col(k)
    data["in_contact"] = col("in_contact", pa.bool_())
    for k in ("contact_dx_m", "contact_dy_m", "residual_max"):
        data[k] = col(k)
    data["win_wrench"] = _fixed_list(np.array([r["win_wrench"] for r in rows]).reshape(n, WINDOW_STEPS, 6))
    data["win_pose"] = _fixed_list(np.array([r["win_pose"] for r in rows]).reshape(n, WINDOW_STEPS, 7))
    data["win_true_contact_m"] = _fixed_list(
        np.array([r["win_true_contact_m"] for r in rows]).reshape(n, WINDOW_STEPS, 2))
    data["win_true_object"] = _fixed_list(
        np.array([r["win_true_object"] for r in rows], dtype=np.int64).reshape(n, WINDOW_STEPS))
    data["true_contact_x_m"] = col("true_contact_x_m")
    data["true_contact_y_m"] = col("true_contact_y_m")
    data["object_id"] = col("object_id", pa.int64())
    fr = np.array([r["force_rep"] for r in rows]).reshape(n, 2)
    data["force_rep_x_n"] = pa.array(fr[:, 0])
    data["force_rep_y_n"] = pa.array(fr[:, 1])
    data["obj_pose"] = _body_list(np.array([r["obj_pose"] for r in rows]).reshape(n, nb, 3))
    data["obj_distance_m"] = _body_list(np.array([r["obj_distance_m"] for r in rows]).reshape(n, nb))
    assert tuple(data) == SIM_RUN.required_names
    if n and "pad_contact_m" in rows[0]:  # the scene's fingertip sensors (docs/simulation.md)
        for k in PAD_COLUMNS:
            data[k] = _fixed_list(np.array([r[k] for r in rows]))
    if probe_from is not None:
        data["probe"] = pa.array(np.arange(n) >= probe_from, type=pa.bool_())
    return pa.table(data)


def collect_run(scene: Scene, seed: int, *, root_seed: int = 0, policy: str | None = None,
                max_actions: int | None = None, det: DetectionParams | None = None, policy_params=None
                ) -> tuple[pa.Table, dict, CollectResult]:
    """Simulate one run of a scene.

    Parameters
    ----------
    scene : Scene
    seed : int
        Run seed.
    root_seed : int
        The stage's root seed.
    policy : str
        A registered collection policy (:func:`pipeline.registry.policy_names`); None: the one for the scene's kind
        (:func:`pipeline.registry.default_policy`).
    max_actions : int, optional
        Stop after this many actions (short test runs; the scripted ones of ``scripted+probe``).
    policy_params : dataclass instance, dict or None
        The policy's own parameters (e.g. :class:`pipeline.probe.policy.ProbeParams`); None: its defaults.
    det : DetectionParams, optional
        The contact detector of the ``in_contact`` column; None: the scene's (its ``[detection]``, else the
        defaults).

    Returns
    -------
    table : pyarrow.Table
        The sim_run table (one row per action).
    params : dict
        Metadata for the file (scene, effects, bodies, initial state, discard verdict, ...).
    result : CollectResult
        Summary (``path`` None).
    """
    policy = policy or registry.default_policy(scene.kind)
    spec = registry.policy(policy)
    if (gap := spec.missing(scene)) is not None:
        raise SceneError(f"{scene.path}: key {gap[0]!r}: the {policy} policy needs the scene's {gap[1]}")
    t0 = time.perf_counter()
    # the third child (the sensors' noise) leaves the first two, and so every run without sensors, as they were
    noise_ss, policy_ss, sensor_ss = job_seed_sequence(root_seed, scene.name, seed).spawn(3)
    noise_rng = np.random.default_rng(noise_ss)
    policy_rng = np.random.default_rng(policy_ss)
    if det is None:
        det = scene_detection(scene)
    mover = registry.resolve(spec.factory)(scene, policy_rng, noise_rng, max_actions,
                                           registry.build_params(spec, policy_params))
    eff = scene.effects
    scale = scene.action_scale
    rows: list[dict] = []
    sim_s = 0.0
    with World(scene, gripper_start=mover.gripper_start, sensor_rng=np.random.default_rng(sensor_ss)) as world:
        mover.start(world)
        pos0, _ = world.gripper_pose()
        initial = {"ee_xy_m": pos0[:2].tolist(), "obj_pose": world.object_poses().tolist()}
        n_limit = mover.plan()
        last_contact, observe = False, getattr(mover, "observe", None)
        for k in range(n_limit):
            u = mover.action(world, k, last_contact)
            if u is None:
                break
            ts = time.perf_counter()
            trace = world.act(float(u[0] * scale), float(u[1] * scale))
            sim_s += time.perf_counter() - ts
            row = summarize_action(trace, det)
            last_contact = row["in_contact"]
            if observe is not None:
                observe(row)
            row.update(cmd_ux=float(u[0]), cmd_uy=float(u[1]), cmd_dx_m=float(u[0] * scale),
                       cmd_dy_m=float(u[1] * scale), obj_pose=world.object_poses(),
                       obj_distance_m=world.object_distances())
            rows.append(row)
        # A policy with a second phase (the active protocol's probes) acts on in the same world; its actions
        # are appended to the run and marked in the ``probe`` column.
        after, n_first = getattr(mover, "after", None), len(rows)
        extra = None if after is None else after(world, rows, partial(summarize_action, det=det),
                                                 lambda: _build_table(scene, seed, rows), seed, root_seed)
        # a policy that acts only in its second phase (explore: a search, then probes) says where its probes begin
        n_first = getattr(mover, "probes_from", n_first)
        # bodies knocked over or leaning: the grasp is simulated in the state the run ended in, not upright
        tilted = world.tilted_poses()
    table = _build_table(scene, seed, rows, None if extra is None else n_first)
    labels = table.column("object_id").to_numpy()
    fr = np.column_stack([table.column("force_rep_x_n").to_numpy(), table.column("force_rep_y_n").to_numpy()])
    discarded = discard_reason(labels, fr) if mover.discards else None
    touched = {scene.body_names[i]: int(np.sum(labels == i)) for i in sorted(set(labels.tolist())) if i >= 0}
    params = {
        "scene": scene.name, "scene_file": scene.path.name, "kind": scene.kind, "policy": policy,
        "run_seed": int(seed), "seed_sequence": [int(root_seed), scene_hash(scene.name), int(seed)],
        "effects": eff.as_dict(), **({"sensors": scene.sensors.as_dict()} if scene.sensors.any else {}),
        "action_scale_m": scale, "max_actions": max_actions,
        "bodies": list(scene.body_names), "target": scene.target.name if scene.target else None,
        "initial": initial, "goal_xy_m": None if mover.goal is None else mover.goal.tolist(),
        "detection": {"sigma_inv": list(det.sigma_inv), "threshold": det.threshold, "window": det.window,
                      **({"min_force_n": det.min_force_n} if det.min_force_n else {})},
        "steps_per_action": STEPS_PER_ACTION, "discarded": discarded,
        # the scene itself: retrieval and scoring use it, verified by its digest (pipeline.estimators.run_info)
        "scene_toml": scene.source, "scene_sha256": scene_digest(scene.source),
    }
    if tilted:
        params["tilted"] = tilted
    if extra is not None:
        params["probe"] = extra
    if hasattr(mover, "metadata"):  # a policy with its own parameters records them (the rummage's contacts)
        params["policy_params"] = mover.metadata()
    result = CollectResult(scene=scene.name, seed=int(seed), path=None, n_actions=table.num_rows,
                       n_contact=int(np.sum(table.column("in_contact").to_numpy(zero_copy_only=False))),
                       touched=touched, discarded=discarded, wall_s=time.perf_counter() - t0, sim_s=sim_s,
                       probe_s=getattr(mover, "times", None))
    return table, params, result


def collect_file(scene: Scene, seed: int, path: str | Path, *, root_seed: int = 0, policy: str | None = None,
                 max_actions: int | None = None, keep_discarded: bool = True, policy_params=None) -> CollectResult:
    """The `collect` stage on a file: simulate one run (:func:`collect_run`) and write its ``sim_run`` table to
    ``path`` (atomically, with its metadata), unless it is discarded and not ``keep_discarded``, then the side
    files its policy declares (:attr:`pipeline.registry.PolicySpec.save_side_files`, e.g. the probing policy's
    wall times). A side file of an earlier run at ``path`` (any policy's) is removed first: it never outlives its
    run, whatever the new run's policy writes."""
    table, params, result = collect_run(scene, seed, root_seed=root_seed, policy=policy, max_actions=max_actions,
                                        policy_params=policy_params)
    if result.discarded is None or keep_discarded:
        registry.remove_side_files(path)
        write_table(table, path, stage="collect", params=params, seed=root_seed, kind=RUN_KIND)
        result.path = Path(path)
        save = registry.policy(policy or registry.default_policy(scene.kind)).save_side_files
        if save is not None:
            registry.resolve(save)(path, result)
    return result


def collect(scene: Scene, seeds: list[int], out_dir: str | Path, *, policy: str | None = None, root_seed: int = 0,
            jobs: int = 1, progress: bool | None = None, max_actions: int | None = None,
            keep_discarded: bool = False, policy_params=None) -> list[CollectResult]:
    """Collect runs of ``scene`` for ``seeds`` into ``out_dir``, ``jobs`` processes in parallel.

    Parameters
    ----------
    progress : bool or None
        tqdm's ``disable`` (True: no bar; None: bar only on a TTY).
    policy_params : dict, dataclass instance or None
        The policy's own parameters (:func:`collect_run`'s).

    Returns
    -------
    list of CollectResult, in seed order.
    """
    from tqdm import tqdm

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job = partial(collect_file, root_seed=root_seed, policy=policy, max_actions=max_actions,
                  keep_discarded=keep_discarded, policy_params=policy_params)
    args = [(scene, s, output_path(out_dir, scene.name, s)) for s in seeds]
    bar = tqdm(total=len(seeds), desc=f"collect {scene.name}", unit="run", disable=progress)
    try:
        results = map_jobs(job, args, jobs, bar)
    finally:
        bar.close()
    return sorted(results, key=lambda r: r.seed)
