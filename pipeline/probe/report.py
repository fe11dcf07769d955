"""What the probing policy did, read back from run files: probes, decision times, how far probing moved the
target (the run's recorded poses; ground truth, read for reporting only), for ``stucco evaluate --policy
scripted+probe`` and ``stucco bench probe``."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from pipeline import registry, schema
from pipeline.atomic import write_text
from pipeline.geometry import wrap_angle
from pipeline.layout import partition
from pipeline.safe_open import optional_file, read_text
from pipeline.schema.rules import MAX_SECONDS

__all__ = ["PROBE_POLICY", "run_stats", "probe_lines", "times_path", "save_times", "save_collect_times", "read_times"]

#: The probing policy, whose :class:`~pipeline.registry.PolicySpec` declares the times side file.
PROBE_POLICY = "scripted+probe"


def times_path(path: str | Path) -> Path:
    """The side file of a run file holding the policy's decision times (the first side file its
    :class:`~pipeline.registry.PolicySpec` declares, ``_<run>.probe_s.json``): wall times are kept out of the
    Parquet file, which the same command must write byte for byte again."""
    return registry.policy(PROBE_POLICY).side_paths(path)[0]


def _legacy_times_path(path: str | Path) -> Path:
    """Where runs collected before layout 3 kept their times: ``<run>.probe_s.json`` (no leading ``_``)."""
    path = Path(path)
    return path.with_name(path.stem + registry.policy(PROBE_POLICY).side_files[0])


def save_times(path: str | Path, times: dict | None) -> None:
    """Write the policy's wall times of the run file ``path`` beside it (atomically): ``times`` holds
    ``decision_s`` (a list, s) and ``prior_s`` (s); nothing for ``None``."""
    if times is not None:
        decisions = [round(float(v), 6) for v in times.get("decision_s") or []]
        write_text(times_path(path), json.dumps({"decision_s": decisions,
                                                 "prior_s": round(float(times.get("prior_s") or 0.0), 6)}))


def save_collect_times(path: str | Path, result) -> None:
    """:attr:`pipeline.registry.PolicySpec.save_side_files` of the probing policy: the times of
    :class:`pipeline.collect.CollectResult` ``result`` (its ``probe_s``) beside the run file ``path``."""
    save_times(path, getattr(result, "probe_s", None))


def read_times(path: str | Path) -> tuple[list[float], float | None]:
    """(decision times, prior time or None) from a run file's side file (or its name before layout 3); a side
    file written before the prior was timed holds the list of decision times alone; none at all (e.g. a run
    copied by evaluate --from-runs without it): ([], None). The side file is checked before it is opened (a regular
    file) and after ({"decision_s": [s, ...], "prior_s": s}, times finite and >= 0): ValueError naming it and the
    key otherwise."""
    for side in (times_path(path), _legacy_times_path(path)):
        if optional_file(side, "the policy's times file") is not None:  # a FIFO there is refused, never opened
            break
    else:
        return [], None
    try:
        times = json.loads(read_text(side, "the policy's times file"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{side}: not JSON ({e})") from None
    if isinstance(times, list):  # written before the prior was timed
        return _seconds(side, "", times), None
    if not isinstance(times, dict) or set(times) - {"decision_s", "prior_s"}:
        raise ValueError(f"{side}: holds {json.dumps(times)[:40]}; expected "
                         '{"decision_s": [seconds, ...], "prior_s": seconds}')
    prior = times.get("prior_s")
    return (_seconds(side, "decision_s", times.get("decision_s", [])),
            None if prior is None else _seconds(side, "prior_s", [prior])[0])


def _seconds(side: Path, key: str, values) -> list[float]:
    """``values`` as wall times (finite numbers >= 0, s); ValueError naming the file and key otherwise."""
    if not isinstance(values, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 <= v <= MAX_SECONDS
            for v in values):
        raise ValueError(f"{side}: {key or 'the list'} is {json.dumps(values)[:40]}; expected "
                         f"{'a list of ' if key != 'prior_s' else ''}seconds (finite, in [0, {MAX_SECONDS:g}])")
    return [float(v) for v in values]


def run_stats(path: str | Path, rows: int | None = None) -> dict:
    """Probing figures of one run file (``scripted+probe``), up to its first ``rows`` rows (default: all).

    Returns
    -------
    dict
        ``probes`` (made), ``decision_s`` (list, seconds, from :func:`times_path`; empty without it),
        ``prior_s`` (seconds, the pushes' prior; None when not recorded), ``flagged``,
        ``moved_m`` (target's centre of mass moved between the end of the scripted part and ``rows``),
        ``turned_rad`` (|yaw change| over the same).
    """
    t, run_meta = schema.read_run_and_metadata(path)
    params = run_meta.get("params") or {}
    meta = schema.probe_log(run_meta)
    bodies, target = params.get("bodies"), params.get("target")
    if not isinstance(bodies, list) or target not in bodies:
        raise schema.SchemaError(path, None, None, f"metadata stucco.params.target {target!r} is not one of its "
                                                   "bodies (stucco.params.bodies)")
    tid = bodies.index(target)
    flags = np.asarray(t.column("probe").to_numpy(zero_copy_only=False), dtype=bool) \
        if "probe" in t.column_names else np.zeros(t.num_rows, dtype=bool)
    n0 = int(np.argmax(flags)) if flags.any() else t.num_rows
    end = t.num_rows if rows is None else int(rows)
    poses = t.column("obj_pose")
    before = np.asarray(poses[n0 - 1].as_py(), dtype=np.float64).reshape(-1, 3)[tid]
    after = np.asarray(poses[end - 1].as_py(), dtype=np.float64).reshape(-1, 3)[tid]
    turn = abs(float(wrap_angle(after[2] - before[2])))
    times, prior = read_times(path)
    return {"probes": int(meta.get("probes", 0)), "decision_s": times, "prior_s": prior,
            "flagged": meta.get("flagged", ""), "moved_m": math.hypot(*(after[:2] - before[:2])),
            "turned_rad": float(turn)}


def probe_lines(out: str | Path, jobs) -> list[str]:
    """One line per scene of an evaluation directory made with ``--policy scripted+probe``: runs, mean probes,
    decision time (median and largest), runs whose set was still wide, median displacement of the target by the
    probes."""
    by_scene: dict[str, list[dict]] = {}
    for sc, seed in dict.fromkeys((j.scene, j.seed) for j in jobs):
        path = partition(out, "runs", sc, seed)
        if path.is_file() and "probe" in (schema.read_metadata(path).get("params") or {}):
            by_scene.setdefault(sc, []).append(run_stats(path))
    lines = []
    for sc, st in by_scene.items():
        dec = np.concatenate([s["decision_s"] for s in st]) if st else np.zeros(0)
        lines.append(
            f"active protocol {sc}: {len(st)} runs, probes per run {np.mean([s['probes'] for s in st]):.2f}, "
            f"decision {np.median(dec) if dec.size else float('nan'):.3f} s median "
            f"({np.max(dec) if dec.size else float('nan'):.3f} s max), "
            f"budget spent without a stop in {sum(bool(s['flagged']) for s in st)}, target moved by probing "
            f"{1000 * np.median([s['moved_m'] for s in st]):.1f} mm / "
            f"{np.median([s['turned_rad'] for s in st]):.3f} rad (median)" + _prior_text(st))
    return lines


def _prior_text(stats: list[dict]) -> str:
    """", the pushes' prior X s per run (median, largest)" over the runs that timed one, else ""."""
    prior = [s["prior_s"] for s in stats if s["prior_s"]]
    return f", the pushes' prior {np.median(prior):.2f} s per run median ({np.max(prior):.2f} s max)" if prior else ""
