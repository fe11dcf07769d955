"""A collected run's metadata checked against its rows: who the run is, which policy made it, what it recorded.

:func:`check_run_metadata` is called by :func:`pipeline.schema.read_run` on every run file read, so every reader
(isolate, retrieval, scoring, the active protocol's report and ``stucco bench probe``) sees a run whose

* ``run``, ``scene`` and ``seed`` columns agree with one another (``run`` is ``<scene>/<seed>``) and with the
  metadata's ``scene`` and ``run_seed``;
* ``probe`` column agrees with its policy: present exactly when the metadata records the probing policy's log
  (``params.probe``), a run of scripted rows then probe rows, as many probe rows as the log's ``actions``;
* probe log (``params.probe``) has the shape the policy writes (:func:`check_probe_record`): counts that are
  integers in range, one history entry per decision (``probes`` + 1), rows and steps within the run.

Each failure is one :class:`SchemaError` naming the file and the column or metadata key.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.schema.errors import SchemaError

__all__ = ["PROBE_POLICY", "MAX_PROBES", "check_run_metadata", "check_probe_record"]

#: The policy whose log the run's metadata records under ``params.probe`` (pipeline/registry.py).
PROBE_POLICY = "scripted+probe"
#: Most probes one run may record (the policy's budget is a handful; a count beyond this is not a count).
MAX_PROBES = 10_000
_KEY = "metadata stucco.params.probe"


def _fail(path, key: str, value: Any, expected: str):
    shown = repr(value) if not isinstance(value, (list, dict)) else f"{type(value).__name__} of {len(value)}"
    raise SchemaError(path, None, None, f"{_KEY}.{key} is {shown[:40]}; expected {expected}")


def _count(path, rec: dict, key: str, hi: int) -> int:
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= hi:
        _fail(path, key, v, f"an integer in [0, {hi}]")
    return v


def _fraction(path, key: str, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.0 <= v <= 1.0 + 1e-9:
        _fail(path, key, v, "a share in [0, 1]")


def _steps(path, key: str, v: Any, n_rows: int) -> None:
    if not isinstance(v, list) or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < n_rows
                                          for s in v):
        _fail(path, key, v, f"a list of action indices in [0, {n_rows})")


def check_probe_record(path: str | Path, rec: Any, n_rows: int, n_scripted: int) -> dict:
    """``rec`` (the run's ``params.probe``) when it has the shape :func:`pipeline.probe.policy.run_policy` writes
    for a run of ``n_rows`` rows, the first ``n_scripted`` scripted; SchemaError naming the file and key
    otherwise (a count of -3 or 1e300, a history emptied or of another length, rows past the run)."""
    if not isinstance(rec, dict):
        _fail(path, "", rec, "the probing policy's log (a JSON object)")
    if not isinstance(rec.get("params"), dict):
        _fail(path, "params", rec.get("params"), "the policy's parameters (a JSON object)")
    probes = _count(path, rec, "probes", min(MAX_PROBES, n_rows))
    actions = _count(path, rec, "actions", n_rows)
    if actions != n_rows - n_scripted:
        _fail(path, "actions", actions, f"{n_rows - n_scripted}, the run's probe rows")
    for key in ("contacts", "lines"):
        if not isinstance(rec.get(key), list) or len(rec[key]) != probes:
            _fail(path, key, rec.get(key), f"a list of one entry per probe ({probes})")
    if not isinstance(rec.get("flagged", ""), str):
        _fail(path, "flagged", rec.get("flagged"), "a string")
    for key in ("target_steps", "other_steps"):
        _steps(path, key, rec.get(key, []), n_rows)
    _fraction(path, "share", rec.get("share", 0.0))
    history = rec.get("history")
    if not isinstance(history, list) or len(history) != probes + 1:
        _fail(path, "history", history, f"a list of one entry per decision (probes + 1 = {probes + 1})")
    last = n_scripted
    for k, h in enumerate(history):
        key = f"history[{k}]"
        if not isinstance(h, dict):
            _fail(path, key, h, "a JSON object")
        rows = h.get("rows")
        if isinstance(rows, bool) or not isinstance(rows, int) or not last <= rows <= n_rows or \
                (k == 0 and rows != n_scripted):
            _fail(path, f"{key}.rows", rows, f"{n_scripted} (the scripted rows)" if k == 0 else
                  f"an integer in [{last}, {n_rows}] (rows sensed, non-decreasing)")
        last = rows
        seg = h.get("segment")
        if seg is not None and (isinstance(seg, bool) or not isinstance(seg, int) or seg < -1):
            _fail(path, f"{key}.segment", seg, "a segment index (-1: none)")
        _fraction(path, f"{key}.share", h.get("share"))
        if "held" in h:
            _fraction(path, f"{key}.held", h["held"])
        if "stop" in h and not isinstance(h["stop"], bool):
            _fail(path, f"{key}.stop", h["stop"], "true or false")
        _steps(path, f"{key}.target_steps", h.get("target_steps"), n_rows)
    return rec


def check_run_metadata(table: pa.Table, meta: dict, path: str | Path) -> None:
    """SchemaError (one line naming ``path`` and the column or key) unless the run table ``table`` and its
    metadata ``meta`` (:func:`pipeline.schema.read_metadata`) agree (the module docstring). A file without stucco
    metadata (written by other tools) is checked for its columns' agreement only."""
    run = table.column("run")[0].as_py()
    scene = table.column("scene")[0].as_py()
    seed = int(table.column("seed")[0].as_py())
    params = meta.get("params")
    if not isinstance(params, dict) or "run_seed" not in params:
        return
    # (a scene recorded as a path is refused by the run's reader, which names what it is: pipeline.estimators)
    named = isinstance(params.get("scene"), str) and not any(c in params["scene"] for c in "/\\.")
    if (named and scene != params.get("scene")) or seed != params.get("run_seed"):
        col, have, want = ("scene", scene, params.get("scene")) if scene != params.get("scene") else \
            ("seed", seed, params.get("run_seed"))
        raise SchemaError(path, col, 0, f"is {have!r}, but the metadata records {want!r} (stucco.params."
                                        f"{'scene' if col == 'scene' else 'run_seed'}); not the run it claims")
    if run != f"{scene}/{seed}":
        raise SchemaError(path, "run", 0, f"is {run!r}; expected {scene}/{seed} (its scene and seed columns)")
    flags = np.asarray(table.column("probe").to_numpy(zero_copy_only=False), dtype=bool) \
        if "probe" in table.column_names else None
    probing = params.get("policy") == PROBE_POLICY or "probe" in params
    if not probing:
        if flags is not None and flags.any():
            raise SchemaError(path, "probe", int(np.argmax(flags)), f"is true in a run of policy "
                                                                    f"{params.get('policy')!r}; only the probing "
                                                                    f"policy ({PROBE_POLICY}) makes probes")
        return
    if flags is None:
        raise SchemaError(path, "probe", None, f"missing from a run of policy {PROBE_POLICY}; the column marks "
                                               "the probe actions (a run file of stucco collect has it)")
    n_scripted = int(np.argmax(flags)) if flags.any() else len(flags)
    if (r := next((i for i in range(n_scripted, len(flags)) if not flags[i]), None)) is not None:
        raise SchemaError(path, "probe", r, "is false after a probe action; expected the scripted actions, then "
                                            "the probes")
    check_probe_record(path, params.get("probe"), table.num_rows, n_scripted)
