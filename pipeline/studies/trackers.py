"""Speed and accuracy of the trackers on the authors' benchmark streams, side by side with their implementation.

Each (T, N) combination runs in a fresh process (``python -m pipeline.studies.trackers worker ...``) so that peak
memory is that process's own, as in the reference harness; compiled kernels are loaded and warmed up before the clock
starts, as the reference's torch import and set-up are excluded from its figures. The reference figures come
from ``data/anchors/reference.json`` (the authors' recorded timings, with their source in the file) or, with
``reference_python``, from rerunning the authors' harness on this machine.
"""
from __future__ import annotations

import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.studies.anchors import ANCHOR_DIR, contact_error_cm, load_contacts_stream, untracked_contact_error_cm

REFERENCE_FILE = ANCHOR_DIR / "reference.json"
DEFAULT_REFERENCE_SCRIPT = Path(__file__).resolve().parents[3] / "shared" / "anchors" / "ref_tracker_bench.py"
#: Seconds of replay after which the authors' harness stops a rerun, its own default (``stucco bench track
#: --reference-budget`` sets another).
REFERENCE_BUDGET_S = 180.0


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def replay(stream: dict, tracker) -> dict:
    """Feed a stream to a tracker step by step, timing every update (wall and this process's CPU time).

    Returns
    -------
    dict with ``step_ms`` (L,) wall, ``cpu_ms`` (L,) CPU, ``points`` (M, 2) and ``labels`` (M,) of the final
    estimate.
    """
    c = stream["in_contact"].astype(bool)
    step_ms = np.empty(len(c))
    cpu_ms = np.empty(len(c))
    for i in range(len(c)):
        t0, u0 = time.perf_counter(), time.process_time()
        if c[i]:
            tracker.update(stream["x"][i], stream["dx"][i][None], stream["p"][i][None])
        else:
            tracker.update(stream["x"][i], None, None)
        cpu_ms[i] = (time.process_time() - u0) * 1e3
        step_ms[i] = (time.perf_counter() - t0) * 1e3
    return dict(step_ms=step_ms, cpu_ms=cpu_ms, points=tracker.points_, labels=np.asarray(tracker.labels()))


def score(stream: dict, points: np.ndarray, labels: np.ndarray) -> dict:
    from sklearn.metrics import fowlkes_mallows_score

    truth = stream["obj_id"][stream["in_contact"].astype(bool)]
    return dict(fmi=float(fowlkes_mallows_score(truth, labels)), ce_cm=contact_error_cm(points, stream))


def stream_tracker(method: str, n_particles: int, seed: int, robot_spec: str, weighting: str = "reference"):
    from pipeline.robot import load_robot
    from pipeline.track.stage import TrackConfig
    from pipeline.track.stage import make_tracker as build

    params = dict(n_particles=n_particles, weighting=weighting) if method == "stucco" else {}
    return build(TrackConfig(method=method, robot=robot_spec, params=params), load_robot(robot_spec),
                 np.random.default_rng(seed))


def _warm_up(method: str, robot_spec: str) -> float:
    """Load (or compile) the kernels outside the timed region; returns the seconds it took (the compilation of
    a fresh checkout, or loading numba's cache). The whole T=50 stream with 16 particles resamples and runs
    Alg. 2, so every kernel of the replay is loaded."""
    t0 = time.perf_counter()
    replay(load_contacts_stream(50), stream_tracker(method, 16, 0, robot_spec))
    return time.perf_counter() - t0


def worker(T: int, N: int, method: str = "stucco", seed: int = 0, weighting: str = "reference",
           streams: str | Path | None = None, robot_spec: str = "disc:0.05") -> dict:
    """One timed replay in this process (call it in a fresh process for a clean peak-memory figure).

    Start-up (``startup_cpu_s``: the CPU time of this process before the replay: interpreter, imports) and
    compilation (``warmup_s``: compiling the kernels, or loading them from numba's cache) are reported apart
    from the replay; ``cpu_s``/``cpu_ms_*`` are the replay's CPU time (``time.process_time``), the figure to
    compare on a shared machine, beside its wall time (``total_s``, ``ms_*``)."""
    warmup_s = _warm_up(method, robot_spec)
    startup_cpu_s = time.process_time()
    rss_setup = _peak_rss_mb()
    stream = load_contacts_stream(T, streams)
    out = replay(stream, stream_tracker(method, N, seed, robot_spec, weighting))
    c = stream["in_contact"].astype(bool)
    ms, cpu = out["step_ms"], out["cpu_ms"]
    contact_ms = ms[c]
    last = max(1, math.ceil(0.1 * len(contact_ms)))
    return dict(T=T, N=N, method=method, seed=seed, weighting=weighting, L=len(c), total_s=float(ms.sum() / 1e3),
                ms_all=float(ms.mean()), ms_contact=float(contact_ms.mean()),
                ms_free=float(ms[~c].mean()) if (~c).any() else float("nan"),
                last10_ms=float(contact_ms[-last:].mean()), cpu_s=float(cpu.sum() / 1e3),
                cpu_ms_all=float(cpu.mean()), cpu_ms_contact=float(cpu[c].mean()),
                cpu_last10_ms=float(cpu[c][-last:].mean()), warmup_s=warmup_s, startup_cpu_s=startup_cpu_s,
                threads=_threads(), load_avg=os.getloadavg()[0], peak_rss_mb=_peak_rss_mb(), setup_rss_mb=rss_setup,
                **score(stream, out["points"], out["labels"]))


def _threads() -> int:
    import numba

    return int(numba.get_num_threads())


class WorkerError(ValueError):
    """A benchmark subprocess failed; the one-line message names it and gives its last line of stderr."""


def _last_line(stderr: str) -> str:
    lines = [ln.strip() for ln in stderr.strip().splitlines() if ln.strip()]
    return lines[-1][:300] if lines else "(no output)"


def check_reference(python: str, script: str | Path = DEFAULT_REFERENCE_SCRIPT) -> None:
    """Refuse, before any measurement, a reference python that cannot import the authors' package or a missing
    harness script (one-line :class:`WorkerError`)."""
    if not Path(script).is_file():
        raise WorkerError(f"--reference-python: the reference harness {script} is missing (see the anchors README)")
    try:
        res = subprocess.run([python, "-c", "import stucco"], capture_output=True, text=True, check=False,
                             timeout=120)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise WorkerError(f"--reference-python {python}: cannot run it ({e})") from None
    if res.returncode != 0:
        raise WorkerError(f"--reference-python {python}: 'import stucco' failed (exit code {res.returncode}: "
                          f"{_last_line(res.stderr)}); expected the python of a venv with stucco==1.2.1")


def run_worker(T: int, N: int, *, method: str = "stucco", seed: int = 0, weighting: str = "reference",
               streams: str | Path | None = None, threads: int = 1) -> dict:
    cmd = [sys.executable, "-m", "pipeline.studies.trackers", "worker", str(T), str(N), method, str(seed), weighting,
           str(streams or ANCHOR_DIR)]
    env = dict(os.environ, STUCCO_THREADS=str(threads))
    res = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    if res.returncode != 0:
        raise WorkerError(f"benchmark worker (T={T}, N={N}, {method}) failed: {_last_line(res.stderr)}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def run_reference_worker(T: int, N: int, python: str, script: str | Path = DEFAULT_REFERENCE_SCRIPT,
                         seed: int = 0, budget_s: float = REFERENCE_BUDGET_S,
                         streams: str | Path | None = None) -> dict:
    """Rerun the authors' implementation on the same stream through their harness (see ../shared/anchors).

    The harness reads ``stream_T{T}.npz`` beside its script. For a count it has no file for (T=300: the streams
    are prefixes of one trajectory, and the harness writes 50, 100, 200 and 400), the harness runs from a
    temporary folder holding a copy of the script and the stream our replay uses (:func:`load_contacts_stream`
    of ``streams``: the longer stream cut after its T-th contact step, as the harness itself cuts)."""
    script = Path(script)
    if (script.parent / f"stream_T{T}.npz").is_file() or not script.is_file():
        return _reference_worker([python, str(script)], T, N, python, seed, budget_s)
    with tempfile.TemporaryDirectory(prefix="stucco-reference-") as tmp:
        shutil.copy2(script, Path(tmp) / script.name)
        np.savez(Path(tmp) / f"stream_T{T}.npz", **load_contacts_stream(T, streams))
        return _reference_worker([python, str(Path(tmp) / script.name)], T, N, python, seed, budget_s)


def _reference_worker(prefix: list[str], T: int, N: int, python: str, seed: int, budget_s: float) -> dict:
    cmd = prefix + ["--worker", "--T", str(T), "--N", str(N), "--seed", str(seed), "--budget", str(budget_s)]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    except OSError as e:
        raise WorkerError(f"--reference-python {python}: cannot run it ({e.strerror})") from None
    if res.returncode != 0:
        raise WorkerError(f"--reference-python {python}: the reference worker (T={T}, N={N}) failed with exit "
                          f"code {res.returncode}: {_last_line(res.stderr)}")
    r = json.loads(res.stdout.strip().splitlines()[-1])
    return dict(total_s=r["total_s"], ms_contact=r["mean_ms_contact"], last10_ms=r["last10pct_contact_ms"],
                peak_rss_mb=r["rss_peak_mb"], truncated=r.get("truncated", False), fmi=r.get("fmi_cc"),
                ce_cm=r.get("ce_map_cm"), source="rerun here")


def recorded_reference() -> dict:
    with open(REFERENCE_FILE) as f:
        return json.load(f)


def track_bench(T_list=(50, 100, 200, 400), N_list=(100, 500), *, repeats: int = 3, acc_seeds: int = 5,
                streams: str | Path | None = None, reference_python: str | None = None,
                reference_budget_s: float = REFERENCE_BUDGET_S, methods=("stucco",), threads=(1, 2),
                echo=print) -> dict:
    """Print the speed table, the accuracy table and the weighting comparison; return every figure.

    ``reference_budget_s``: seconds of replay after which the authors' harness stops a rerun (its own default,
    180 s, cuts their T=400, N=500 replay short; a cut reference gives only a lower bound on the speed-up)."""
    ref = recorded_reference()
    results: dict = {"speed": [], "accuracy": [], "weighting": [], "methods": []}
    echo("SPEED: STUCCO soft tracking on the anchor streams (disc robot r=0.05 m, 1 mm grid, seed 0); median of "
         f"{repeats} runs, each in a fresh process; thr = threads of the particle loops; cpu = the replay's CPU time "
         "(process_time), wall beside it; warm = compiling or loading the kernels, start = the process's CPU time "
         "before the replay (both apart from the replay); load = 1-min load average.\nReference = the authors' "
         "stucco 1.2.1 " + ("rerun on this machine now." if reference_python else "as recorded in "
         "data/anchors/reference.json (../shared/anchors/ref_tracker_bench.txt, 2-core Xeon, torch 2 threads)."))
    hdr = (f"{'T':>4} {'N':>4} {'thr':>3} {'L':>5} {'cpu_s':>7} {'wall_s':>7} {'cpu_ms/c':>8} {'cpu_l10':>7} "
           f"{'warm_s':>6} {'start_s':>7} {'load':>5} {'peakMB':>6} {'FMI':>6} {'CE_cm':>6} | {'ref_s':>7} "
           f"{'ref_ms/c':>8} {'ref_last10':>10} {'ref_MB':>6} {'speedup':>8}")
    echo(hdr)
    for N in N_list:
        for T in T_list:
            key = f"T{T}_N{N}"
            if reference_python:
                rr = run_reference_worker(T, N, reference_python, streams=streams, budget_s=reference_budget_s)
            else:
                rr = ref["timing"].get(key)
            for thr in threads:
                runs = sorted((run_worker(T, N, streams=streams, threads=thr) for _ in range(repeats)),
                              key=lambda r: r["cpu_s"])
                r = dict(runs[len(runs) // 2], threads=thr)
                # ours in CPU seconds (fair on a shared machine, equal to wall on an idle one) against theirs
                speedup = (rr["total_s"] / r["cpu_s"]) if rr else float("nan")
                cut = ">" if rr and rr.get("truncated") else ""
                rs = (f"{cut + format(rr['total_s'], '.2f'):>7} {rr['ms_contact']:>8.1f} {rr['last10_ms']:>10.1f} "
                      f"{rr['peak_rss_mb']:>6.0f} {cut + format(speedup, '.0f') + 'x':>8}") if rr else "(no reference)"
                echo(f"{T:>4} {N:>4} {thr:>3} {r['L']:>5} {r['cpu_s']:>7.3f} {r['total_s']:>7.3f} "
                     f"{r['cpu_ms_contact']:>8.2f} {r['cpu_last10_ms']:>7.2f} {r['warmup_s']:>6.2f} "
                     f"{r['startup_cpu_s']:>7.2f} {r['load_avg']:>5.1f} {r['peak_rss_mb']:>6.0f} {r['fmi']:>6.3f} "
                     f"{r['ce_cm']:>6.2f} | {rs}")
                results["speed"].append(dict(ours=r, reference=rr, speedup=speedup))
    if acc_seeds:
        echo(f"\nACCURACY of the final MAP particle over tracker seeds 0..{acc_seeds - 1} (N=100; mean ± std; "
             "FMI of Alg. 3 vs true objects; CE = mean distance to the nearest true surface at the end)")
        echo(f"{'T':>4} {'weighting':>10} {'FMI':>13} {'CE_cm':>13} {'s/run':>6} | {'ref FMI':>13} {'ref CE_cm':>13}"
             f" {'untracked CE':>12}")
        for T in T_list:
            stream = load_contacts_stream(T, streams)
            for weighting in ("reference", "paper"):
                rows = [run_worker(T, 100, seed=s, weighting=weighting, streams=streams) for s in range(acc_seeds)]
                fmi = np.array([x["fmi"] for x in rows])
                ce = np.array([x["ce_cm"] for x in rows])
                ra = ref["accuracy"].get(f"T{T}")
                refs = (f"{ra['fmi_mean']:>6.3f}±{ra['fmi_std']:<6.3f} {ra['ce_cm_mean']:>6.2f}±{ra['ce_cm_std']:<6.2f}"
                        if ra else "")
                echo(f"{T:>4} {weighting:>10} {fmi.mean():>6.3f}±{fmi.std():<6.3f} {ce.mean():>6.2f}±{ce.std():<6.2f} "
                     f"{np.mean([x['total_s'] for x in rows]):>6.2f} | {refs} "
                     f"{untracked_contact_error_cm(stream):>12.2f}")
                results["accuracy"].append(dict(T=T, weighting=weighting, fmi=fmi.tolist(), ce_cm=ce.tolist()))
    others = [m for m in methods if m != "stucco"]
    if others:
        echo("\nMETHODS on the anchor streams (seed 0; baselines have no particles)")
        echo(f"{'method':>8} {'T':>4} {'total_s':>8} {'ms/contact':>10} {'FMI':>6} {'CE_cm':>6}")
        for m in ("stucco",) + tuple(others):
            for T in T_list:
                r = run_worker(T, 100, method=m, streams=streams)
                echo(f"{m:>8} {T:>4} {r['total_s']:>8.3f} {r['ms_contact']:>10.2f} {r['fmi']:>6.3f} {r['ce_cm']:>6.2f}")
                results["methods"].append(r)
    return results


# worker entry point: python -m pipeline.studies.trackers worker T N method seed weighting dir
if __name__ == "__main__":
    if len(sys.argv) >= 7 and sys.argv[1] == "worker":
        os.environ.setdefault("PYTHONHASHSEED", "0")
        _, _, T, N, method, seed, weighting, streams = sys.argv[:8]
        print(json.dumps(worker(int(T), int(N), method, int(seed), weighting, streams)))
    else:
        sys.exit("usage: python -m pipeline.studies.trackers worker T N METHOD SEED WEIGHTING STREAM_DIR")
