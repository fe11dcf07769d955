"""Studies over many runs: what accuracy costs in time, the training-set study (paper Fig. 5) and tuning.

* :func:`accuracy_bench` (``stucco bench accuracy``): the accuracy knobs (particles N, ICP restarts, the gripper
  SDF's resolution, the plausible estimator's hypotheses and free-space lattice, the paper's estimator) and the
  baselines over a (scene, seed) grid of the BOR tasks. Runs are collected and
  isolated once per (scene, seed) into ``DIR/runs`` and ``DIR/contacts`` with :func:`pipeline.evaluate.prepare_run`
  (the same files as ``stucco evaluate``); every setting then tracks, segments, retrieves and scores them in
  memory. Time per run (``compute_s``) = track + segment + ICP (the grasp simulation stands in for the robot's
  motion, not for computation, and is reported apart as ``grasp_s``).
* :func:`training_study` (``stucco study training``): the four training scenes SELECT1-4 collected with the greedy
  random walk (REFERENCE_SPEC §2.4, discard rule included), isolated, tracked by every method (no retrieval), with
  FMI, contact error and run ambiguity (§6.3); :func:`fig5` draws the paper's Fig. 5.
* :func:`tune` (``stucco study tune``): one parameter per method swept on the training set; the rule is
  :func:`choose`.

Every random stream comes from the stages' own derivations (collect: ``[root, scene, seed]``; track:
``[root, run_key(run)]``), so a setting's result does not depend on the order or the process it runs in.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pyarrow as pa

__all__ = ["Setting", "accuracy_settings", "pareto_front", "knee", "accuracy_bench", "summarise_settings",
           "pareto_figure", "run_ambiguity", "TRAINING_SCENES", "TRAINING_SEEDS", "collect_training",
           "training_scores", "training_study", "fig5", "TUNE_GRID", "choose", "tune"]

# ---------------------------------------------------------------------------------------------------------------
# Pareto front and knee
# ---------------------------------------------------------------------------------------------------------------


def pareto_front(points: np.ndarray, minimize: Sequence[bool] | None = None) -> np.ndarray:
    """Non-dominated rows of ``points``.

    Parameters
    ----------
    points : ndarray, shape (n, k)
        One row per candidate; NaN rows are never on the front.
    minimize : sequence of bool, length k
        Per column, True to minimise (default), False to maximise.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for rows that no other row dominates (at least as good in every column, better in one).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2:
        raise ValueError(f"points must be (n, k), got shape {p.shape}")
    sign = np.array([1.0 if m else -1.0 for m in (minimize or [True] * p.shape[1])])
    q = p * sign
    ok = np.all(np.isfinite(q), axis=1)
    front = ok.copy()
    for i in np.flatnonzero(ok):
        others = q[ok]
        dominated = np.any(np.all(others <= q[i], axis=1) & np.any(others < q[i], axis=1))
        front[i] = not dominated
    return front


def knee(cost: Sequence[float], error: Sequence[float], tolerance: float = 0.1) -> int:
    """Index of the knee: the cheapest candidate whose error is within ``tolerance`` (relative) of the best.

    Beyond the knee, spending more time buys less than ``tolerance`` of the best error. NaN errors never qualify.
    """
    c = np.asarray(cost, dtype=np.float64)
    e = np.asarray(error, dtype=np.float64)
    ok = np.isfinite(e) & np.isfinite(c)
    if not ok.any():
        raise ValueError("no candidate with a finite cost and error")
    best = np.min(e[ok])
    good = ok & (e <= best + tolerance * abs(best) + 1e-12)
    idx = np.flatnonzero(good)
    return int(idx[np.argmin(c[idx])])


# ---------------------------------------------------------------------------------------------------------------
# Accuracy bench
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """One point of the accuracy sweep: a method with its tracker parameters, ICP restarts, robot grid and pose
    estimator (with the plausible estimator's hypotheses and free-space lattice spacing in metres)."""

    name: str
    method: str
    knob: str
    value: float
    params: tuple[tuple[str, Any], ...] = ()
    restarts: int = 30
    robot: str = "panda"
    estimator: str = "plausible"
    hypotheses: int = 32
    free_resolution: float = 0.005


def accuracy_settings(n_list: Sequence[int] = (10, 30, 100, 300, 1000), restarts: Sequence[int] = (5, 10, 30),
                      sdf_mm: Sequence[float] = (1, 2, 4), hypotheses: Sequence[int] = (16, 32, 64, 128),
                      free_mm: Sequence[float] = (2.5, 5, 10), paper_estimator: bool = True,
                      baselines: Sequence[str] = ("birch", "dbscan", "kmeans", "gmphd")) -> list[Setting]:
    """The sweep: STUCCO's N (other knobs at their defaults), then restarts and SDF resolution (N = 100, Table
    I), the plausible estimator's hypotheses and free-space lattice spacing, the paper's estimator, then the
    baselines at their defaults. The default STUCCO setting appears once."""
    out: list[Setting] = []
    seen: set[tuple] = set()

    def add(s: Setting) -> None:
        key = (s.method, s.params, s.restarts, s.robot, s.estimator, s.hypotheses, s.free_resolution)
        if key not in seen:
            seen.add(key)
            out.append(s)

    for n in n_list:
        add(Setting(f"stucco N={n}", "stucco", "n_particles", n, (("n_particles", int(n)),) if n != 100 else ()))
    for r in restarts:
        add(Setting(f"stucco restarts={r}", "stucco", "restarts", r, (), restarts=int(r)))
    for mm in sdf_mm:
        spec = "panda" if float(mm) == 1.0 else f"panda:{float(mm) / 1000:g}"
        add(Setting(f"stucco sdf={mm:g}mm", "stucco", "sdf_mm", float(mm), (), robot=spec))
    for h in hypotheses:
        add(Setting(f"stucco hypotheses={h}", "stucco", "hypotheses", h, (), hypotheses=int(h)))
    for mm in free_mm:
        add(Setting(f"stucco free={mm:g}mm", "stucco", "free_mm", float(mm), (), free_resolution=float(mm) / 1000))
    if paper_estimator:
        add(Setting("stucco paper estimator", "stucco", "estimator", math.nan, (), estimator="paper"))
    for b in baselines:
        add(Setting(b, b, "method", math.nan))
    return out


def _run_setting(runs: Path, contacts: pa.Table, s: Setting, root_seed: int) -> dict[str, Any]:
    """Track, segment, retrieve (with the grasp) and score one (scene, seed) with one setting."""
    from pipeline.grasp import GraspParams
    from pipeline.retrieve import PlausibleParams, RetrievalParams, retrieve
    from pipeline.score import score
    from pipeline.segment import segment_table
    from pipeline.track.soft import SoftTrackingParams
    from pipeline.track.stage import TrackConfig, track_table

    config = TrackConfig(method=s.method, robot=s.robot, params=dict(s.params), every_step=False)
    t0 = time.perf_counter()
    tracks, diagnostics = track_table(contacts, config, seed=root_seed, jobs=1)
    t1 = time.perf_counter()
    sp = SoftTrackingParams.from_dict(dict(s.params) if s.method == "stucco" else {})
    segments = segment_table(tracks, length=sp.length, alpha=sp.alpha, by="auto", method=s.method)
    t2 = time.perf_counter()
    retrieval, _ = retrieve(segments, runs.parent, method=s.method, root_seed=root_seed,
                            params=RetrievalParams(n_restarts=s.restarts, robot=s.robot), grasp=True,
                            grasp_params=GraspParams(), jobs=1, estimator=s.estimator,
                            plausible_params=PlausibleParams(n_hypotheses=s.hypotheses,
                                                             free_resolution=s.free_resolution))
    table = score(segments, retrieval, runs.parent, diagnostics=diagnostics).to_pylist()[0]
    track_s, segment_s = t1 - t0, t2 - t1
    return dict(setting=s.name, method=s.method, knob=s.knob, value=s.value, scene=table["scene"],
                seed=table["seed"], fmi=table["fmi"], contact_error_cm=table["contact_error_cm"],
                grasp_success=table["grasp_success"], position_error_m=table["position_error_m"],
                track_s=track_s, segment_s=segment_s, icp_s=table["retrieve_s"], grasp_s=table["grasp_s"],
                compute_s=track_s + segment_s + table["retrieve_s"])


def _bench_pair(out: Path, scene: str, seed: int, settings: list[Setting], root_seed: int) -> list[dict]:
    from pipeline import schema
    from pipeline.evaluate import EvalConfig, partition, prepare_run, single_threaded

    cfg = EvalConfig(root_seed=root_seed)
    prepare_run(out, scene, seed, cfg)
    runs = partition(out, "runs", scene, seed)
    contacts = schema.read_contacts(partition(out, "contacts", scene, seed))
    with single_threaded():
        return [_run_setting(runs, contacts, s, root_seed) for s in settings]


def _warm_up(settings: list[Setting]) -> None:
    """Build every robot grid (cached on disk) and compile the kernels before any clock starts."""
    from pipeline.robot import load_robot

    for spec in dict.fromkeys(s.robot for s in settings):
        load_robot(spec)


def accuracy_bench(out: str | Path, scenes: Sequence[str], seeds: Sequence[int], settings: list[Setting], *,
                   root_seed: int = 0, jobs: int = 1, progress: bool | None = None) -> pa.Table:
    """Every setting on every (scene, seed); one row per (setting, scene, seed), also in ``out/accuracy.csv``.

    The first (scene, seed) is run once untimed in this process to compile the numba kernels (the timed rows
    then exclude compilation, which every long-running process pays once).
    """
    from tqdm import tqdm

    from pipeline.evaluate import _map

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _warm_up(settings)
    pairs = [(out, sc, int(s), settings, root_seed) for sc in scenes for s in seeds]
    if jobs <= 1:
        _bench_pair(*pairs[0])  # compile (numba) outside the timed rows
    with tqdm(total=len(pairs), desc="bench accuracy", unit="run", disable=progress) as bar:
        rows = [r for chunk in _map(_bench_pair, pairs, jobs, bar) for r in chunk]
    order = {s.name: i for i, s in enumerate(settings)}
    rows.sort(key=lambda r: (order[r["setting"]], r["scene"], r["seed"]))
    table = pa.Table.from_pylist(rows)
    _write_csv(table, out / "accuracy.csv")
    return table


def _write_csv(table: pa.Table, path: Path) -> None:
    import pyarrow.csv as pcsv

    tmp = path.with_name(f".{path.name}.tmp")
    pcsv.write_csv(table, tmp)
    tmp.replace(path)


def _med(v: list) -> float:
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if len(a) else math.nan


def _mean(v: list) -> float:
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    return float(np.mean(a)) if len(a) else math.nan


def summarise_settings(table: pa.Table) -> list[dict[str, Any]]:
    """Per setting: runs, median time per run, median CE and FMI, grasp success rate; plus Pareto flags (time
    against CE, against FMI, against GS) and the knee of the particle sweep (:func:`knee` on time vs CE)."""
    rows: list[dict[str, Any]] = []
    data = table.to_pylist()
    for name in dict.fromkeys(r["setting"] for r in data):
        sub = [r for r in data if r["setting"] == name]
        rows.append(dict(setting=name, method=sub[0]["method"], runs=len(sub),
                         compute_s=_med([r["compute_s"] for r in sub]),
                         track_s=_med([r["track_s"] for r in sub]), icp_s=_med([r["icp_s"] for r in sub]),
                         ce_cm=_med([r["contact_error_cm"] for r in sub]), fmi=_med([r["fmi"] for r in sub]),
                         gs=_mean([None if r["grasp_success"] is None else float(r["grasp_success"]) for r in sub])))
    t = np.array([r["compute_s"] for r in rows])
    for key, metric, minimize in (("front_ce", "ce_cm", True), ("front_fmi", "fmi", False),
                                  ("front_gs", "gs", False)):
        mask = pareto_front(np.column_stack([t, [r[metric] for r in rows]]), [True, minimize])
        for r, m in zip(rows, mask):
            r[key] = bool(m)
    # The knee is taken along the particle sweep: N is the knob that trades tracking time for tracking accuracy
    # (restarts and SDF resolution leave the tracked points of N = 100 unchanged or nearly so).
    knob = {r["setting"]: r["knob"] for r in data}
    st = [i for i, r in enumerate(rows) if knob[r["setting"]] == "n_particles"] or \
        [i for i, r in enumerate(rows) if r["method"] == "stucco"]
    if st:
        k = st[knee([rows[i]["compute_s"] for i in st], [rows[i]["ce_cm"] for i in st])]
        for i, r in enumerate(rows):
            r["knee"] = i == k
    return rows


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    head = "| setting | runs | time/run s | track s | pose s | CE cm | FMI | GS | front (CE/FMI/GS) |\n"
    head += "|---|---|---|---|---|---|---|---|---|\n"
    body = ""
    for r in rows:
        flags = "/".join("x" if r[k] else "-" for k in ("front_ce", "front_fmi", "front_gs"))
        body += (f"| {r['setting']}{' (knee)' if r.get('knee') else ''} | {r['runs']} | {r['compute_s']:.3f} | "
                 f"{r['track_s']:.3f} | {r['icp_s']:.3f} | {r['ce_cm']:.2f} | {r['fmi']:.3f} | {r['gs']:.2f} | "
                 f"{flags} |\n")
    return head + body


def pareto_figure(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """Three panels (CE, FMI, GS against median time per run), Pareto fronts drawn, the knee ringed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    t = np.array([r["compute_s"] for r in rows])
    for ax, (metric, label, front) in zip(axes, (("ce_cm", "median contact error (cm)", "front_ce"),
                                                 ("fmi", "median FMI", "front_fmi"),
                                                 ("gs", "grasp success rate", "front_gs"))):
        y = np.array([r[metric] for r in rows], dtype=float)
        for r, xi, yi in zip(rows, t, y):
            c = "C0" if r["method"] == "stucco" else "C1"
            ax.scatter(xi, yi, color=c, s=30, zorder=3)
            ax.annotate(r["setting"].replace("stucco ", ""), (xi, yi), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
            if r.get("knee"):
                ax.scatter(xi, yi, s=160, facecolors="none", edgecolors="red", zorder=4)
        m = np.array([r[front] for r in rows])
        o = np.argsort(t[m])
        ax.step(t[m][o], y[m][o], where="post", color="grey", lw=1, zorder=2)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("median time per run (s): track + segment + pose estimation")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_title("blue: STUCCO settings, orange: baselines; grey: Pareto front; red ring: knee", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------------------------
# Training set (paper §V-B, Fig. 5)
# ---------------------------------------------------------------------------------------------------------------

TRAINING_SCENES = ("SELECT1", "SELECT2", "SELECT3", "SELECT4")
TRAINING_SEEDS = tuple(range(7, 47))
#: Distance (m) at which ambiguity reaches 0 (REFERENCE_SPEC §6.3).
AMBIGUITY_DISTANCE_M = 0.15
#: Representative force below which an action has no ground truth (§6.2, training set).
MIN_REP_FORCE_N = 0.1


def run_ambiguity(object_id: np.ndarray, obj_distance: np.ndarray) -> float:
    """Run ambiguity (REFERENCE_SPEC §6.3).

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
    from pipeline import schema
    from pipeline.collect import collect, output_path
    from pipeline.scenes import load_scene

    runs_dir = Path(out) / "runs"
    info = []
    for sc in scenes:
        scene = load_scene(sc)
        missing = [s for s in seeds if not output_path(runs_dir, scene.name, s).is_file()]
        if missing:
            collect(scene, list(missing), runs_dir, policy="greedy-walk", root_seed=root_seed, jobs=jobs,
                    progress=progress, max_actions=max_actions, keep_discarded=True)
        for s in seeds:
            path = output_path(runs_dir, scene.name, s)
            meta = schema.read_metadata(path).get("params") or {}
            info.append(dict(scene=scene.name, seed=int(s), path=path, discarded=meta.get("discarded")))
    return info


def _run_truth(path: Path) -> dict[str, Any]:
    """Per run: scene, final poses, ground truth per step (force-masked), ambiguity."""
    import pyarrow.parquet as pq

    from pipeline import schema
    from pipeline.scenes import load_scene

    t = pq.read_table(path, columns=["run", "step", "object_id", "force_rep_x_n", "force_rep_y_n", "obj_pose",
                                     "obj_distance_m"])
    params = schema.read_metadata(path).get("params") or {}
    scene = load_scene(params["scene"])
    ids = t.column("object_id").to_numpy().astype(np.int64)
    force = np.hypot(t.column("force_rep_x_n").to_numpy(), t.column("force_rep_y_n").to_numpy())
    truth = np.where(force >= MIN_REP_FORCE_N, ids, -1)
    nb = len(scene.body_names)
    dist = np.asarray(t.column("obj_distance_m").to_pylist(), dtype=np.float64).reshape(t.num_rows, nb)
    final = np.asarray(t.column("obj_pose")[t.num_rows - 1].as_py(), dtype=np.float64).reshape(nb, 3)
    return dict(run=t.column("run")[0].as_py(), scene=scene, truth=dict(zip(t.column("step").to_pylist(), truth)),
                ambiguity=run_ambiguity(truth, dist), final=final)


def _training_primitive(spec):
    """The body's horizontal slice for the contact error. Upright primitives as in :mod:`pipeline.score`; a
    cylinder lying on its side (SELECT2's ``topple_cylinder``, rp = (0, pi/2)) has a 2r x h rectangular slice
    whose yaw the recorded pose cannot give (the yaw of a body pitched 90 degrees is gimbal-locked), so it is
    approximated by a circle of the mean half-extent (r = 0.12, h/2 = 0.125 for SELECT2: exact at the face
    centres, up to about 5 cm off towards the slice's corners)."""
    from pipeline.retrieve import Primitive, primitive_of

    try:
        return primitive_of(spec)
    except ValueError:
        if getattr(spec, "shape", None) != "cylinder":
            raise
        r, h = float(spec.size[0]), float(spec.size[1])
        return Primitive(kind="cylinder", half=((r + h / 2.0) / 2.0,), centre=np.zeros(2), yaw=0.0, name=spec.name)


def _training_contact_error_cm(points: np.ndarray, scene, poses: np.ndarray) -> float | None:
    """Mean |signed distance| (cm) of points to the scene's bodies (:func:`_training_primitive`)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return None
    best = np.full(len(pts), np.inf)
    for spec, pose in zip(list(scene.objects) + list(scene.walls), np.asarray(poses).reshape(-1, 3)):
        if np.all(np.isfinite(pose)):
            best = np.minimum(best, _training_primitive(spec).signed_distance(pts, pose))
    return float(np.mean(np.abs(best)) * 100.0)


def _isolate_training(out: Path, files: list[Path]) -> pa.Table:
    from pipeline import schema
    from pipeline.isolate import DetectionParams, IsolationParams, isolate_runs, params_dict

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
    """Track every training run with one method and parameter set; FMI, CE (cm) and ambiguity per run."""
    from pipeline.score import fmi
    from pipeline.segment import final_estimates, segment_table
    from pipeline.track.soft import SoftTrackingParams
    from pipeline.track.stage import TrackConfig, track_table

    params = dict(params or {})
    config = TrackConfig(method=method, robot=robot, params=params)
    t0 = time.perf_counter()
    tracks, diagnostics = track_table(contacts, config, seed=root_seed, jobs=1)
    sp = SoftTrackingParams.from_dict(params if method == "stucco" else {})
    final = final_estimates(segment_table(tracks, length=sp.length, alpha=sp.alpha, by="auto", method=method))
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
                         contact_error_cm=_training_contact_error_cm(xy[m], tr["scene"], tr["final"]),
                         ambiguity=tr["ambiguity"], n_points=int(m.sum()), track_wall_s=wall / max(len(truths), 1)))
    return rows


def _load_training(out: Path, scenes, seeds, root_seed, jobs, progress, max_actions):
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


def _score_methods(contacts, truths, settings: list[tuple[str, dict]], root_seed: int, jobs: int,
                   progress) -> list[dict]:
    from tqdm import tqdm

    from pipeline.evaluate import _map

    args = [(contacts, truths, m, p, root_seed) for m, p in settings]
    with tqdm(total=len(args), desc="track", unit="setting", disable=progress) as bar:
        return [r for chunk in _map(_score_setting, args, jobs, bar) for r in chunk]


def _score_setting(contacts, truths, method, params, root_seed):
    from pipeline.evaluate import single_threaded

    with single_threaded():
        return training_scores(contacts, truths, method, params, root_seed=root_seed)


def training_study(out: str | Path, scenes: Sequence[str] = TRAINING_SCENES, seeds: Sequence[int] = TRAINING_SEEDS,
                   methods: Sequence[str] = ("stucco", "birch", "dbscan", "kmeans", "gmphd"), *,
                   root_seed: int = 0, jobs: int = 1, progress: bool | None = None,
                   max_actions: int | None = None, min_ambiguity: float = 0.3) -> dict[str, Any]:
    """Collect (greedy walk, discard rule), isolate, track with every method at its defaults, score.

    Writes ``out/training.csv`` (one row per (run, method)) and ``out/fig5.png``; returns counts, the per-method
    summary (all runs and runs with ambiguity >= ``min_ambiguity``) and the wall time.
    """
    t0 = time.perf_counter()
    out = Path(out)
    info, contacts, truths = _load_training(out, scenes, seeds, root_seed, jobs, progress, max_actions)
    rows = _score_methods(contacts, truths, [(m, {}) for m in methods], root_seed, jobs, progress)
    table = pa.Table.from_pylist(rows)
    _write_csv(table, out / "training.csv")
    summ = {"all": _fig5_stats(rows, methods, 0.0), "ambiguous": _fig5_stats(rows, methods, min_ambiguity)}
    fig5(summ, out / "fig5.png", min_ambiguity)
    discarded = [r for r in info if r["discarded"] is not None]
    n_amb = sum(1 for t in truths.values() if t["ambiguity"] >= min_ambiguity)
    return dict(collected=len(info), kept=len(info) - len(discarded), ambiguous=n_amb,
                discarded_by_reason={k: sum(1 for r in discarded if r["discarded"] == k)
                                     for k in sorted({r["discarded"] for r in discarded})},
                per_scene_kept={sc: sum(1 for r in info if r["scene"] == sc and r["discarded"] is None)
                                for sc in dict.fromkeys(r["scene"] for r in info)},
                summary=summ, wall_s=time.perf_counter() - t0)


def _pct(v: list, q: float) -> float:
    a = np.asarray([x for x in v if x is not None], dtype=np.float64)
    return float(np.percentile(a, q)) if len(a) else math.nan


def _fig5_stats(rows: list[dict], methods: Sequence[str], min_ambiguity: float) -> dict[str, dict]:
    out = {}
    for m in methods:
        sub = [r for r in rows if r["method"] == m and r["ambiguity"] >= min_ambiguity]
        f = [r["fmi"] for r in sub]
        c = [r["contact_error_cm"] for r in sub]
        out[m] = dict(runs=len(sub), fmi=_pct(f, 50), fmi_lo=_pct(f, 20), fmi_hi=_pct(f, 80),
                      ce_cm=_pct(c, 50), ce_lo=_pct(c, 20), ce_hi=_pct(c, 80))
    return out


def fig5(summary: dict[str, dict[str, dict]], path: str | Path, min_ambiguity: float = 0.3) -> Path:
    """The paper's Fig. 5: median FMI against median CE, 20th-80th percentile bars; top all runs, bottom runs
    with ambiguity >= ``min_ambiguity``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(6, 8))
    for ax, (key, title) in zip(axes, (("all", "all runs"), ("ambiguous", f"runs with ambiguity >= {min_ambiguity:g}"))):
        for i, (m, s) in enumerate(summary[key].items()):
            if not s["runs"] or not math.isfinite(s["ce_cm"]):
                continue
            ax.errorbar(s["ce_cm"], s["fmi"], xerr=[[s["ce_cm"] - s["ce_lo"]], [s["ce_hi"] - s["ce_cm"]]],
                        yerr=[[s["fmi"] - s["fmi_lo"]], [s["fmi_hi"] - s["fmi"]]], fmt="o", capsize=3,
                        color=f"C{i}", label=f"{m} ({s['runs']} runs)")
        ax.set_xlabel("contact error (cm)")
        ax.set_ylabel("FMI")
        ax.set_title(f"training set, {title}")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------------------------
# Tuning
# ---------------------------------------------------------------------------------------------------------------

#: Method -> (parameter, values). Table I / §V-B values are included (STUCCO l = 0.02, BIRCH 0.08, DBSCAN 0.05,
#: k-means inertia ratio and GM-PHD detection at their defaults).
TUNE_GRID: dict[str, tuple[str, tuple[float, ...]]] = {
    "stucco": ("length", (0.005, 0.01, 0.02, 0.04, 0.08)),
    "birch": ("threshold", (0.02, 0.04, 0.08, 0.12, 0.2)),
    "dbscan": ("eps", (0.02, 0.035, 0.05, 0.075, 0.1)),
    "kmeans": ("inertia_ratio", (0.1, 0.2, 0.3, 0.5, 0.8)),
    "gmphd": ("detection", (0.3, 0.5, 0.7, 0.9, 0.99)),
}


def choose(stats: Sequence[dict[str, float]], fmi_tolerance: float = 0.01) -> int:
    """Index of the chosen setting: highest median FMI; among those within ``fmi_tolerance`` of it, the lowest
    median CE (the paper maximised median FMI and minimised median CE; FMI first, CE breaks near-ties)."""
    f = np.array([s["fmi"] for s in stats], dtype=float)
    c = np.array([s["ce_cm"] for s in stats], dtype=float)
    ok = np.isfinite(f)
    if not ok.any():
        raise ValueError("no setting has a finite median FMI")
    near = np.flatnonzero(ok & (f >= np.nanmax(f) - fmi_tolerance))
    cc = np.where(np.isfinite(c[near]), c[near], np.inf)
    return int(near[np.argmin(cc)])


def tune(out: str | Path, grid: dict[str, tuple[str, Sequence[float]]] | None = None,
         scenes: Sequence[str] = TRAINING_SCENES, seeds: Sequence[int] = TRAINING_SEEDS, *, root_seed: int = 0,
         jobs: int = 1, progress: bool | None = None, max_actions: int | None = None) -> dict[str, Any]:
    """Sweep one parameter per method on the training set (collected if needed, as :func:`training_study`);
    ``out/tune.csv`` holds the medians of every value; returns the chosen value per method (:func:`choose`)."""
    from pipeline.track.cluster import make_baseline
    from pipeline.track.soft import SoftTrackingParams

    t0 = time.perf_counter()
    out = Path(out)
    grid = dict(grid or TUNE_GRID)
    _, contacts, truths = _load_training(out, scenes, seeds, root_seed, jobs, progress, max_actions)
    settings = [(m, {p: v}) for m, (p, vals) in grid.items() for v in vals]
    rows = _score_methods(contacts, truths, settings, root_seed, jobs, progress)
    summary, chosen = [], {}
    for m, (p, vals) in grid.items():
        stats = []
        for v in vals:
            sub = [r for r in rows if r["method"] == m and json.loads(r["params"]) == {p: v}]
            stats.append(dict(method=m, parameter=p, value=v, runs=len(sub), fmi=_med([r["fmi"] for r in sub]),
                              ce_cm=_med([r["contact_error_cm"] for r in sub])))
        i = choose(stats)
        default = (SoftTrackingParams().to_dict() if m == "stucco"
                   else dataclass_dict(make_baseline(m, None, np.random.default_rng(0)).params))[p]
        for j, s in enumerate(stats):
            s["chosen"] = j == i
            s["default"] = math.isclose(s["value"], float(default))
        summary.extend(stats)
        chosen[m] = dict(parameter=p, value=stats[i]["value"], default=default, fmi=stats[i]["fmi"],
                         ce_cm=stats[i]["ce_cm"])
    _write_csv(pa.Table.from_pylist(summary), out / "tune.csv")
    return dict(chosen=chosen, table=summary, runs=len(truths), wall_s=time.perf_counter() - t0)


def dataclass_dict(obj) -> dict[str, Any]:
    import dataclasses

    return dataclasses.asdict(obj)
