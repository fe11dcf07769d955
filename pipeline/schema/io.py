"""Parquet files: reading with validation, and atomic writing with provenance metadata.

Every file a stage writes goes through :func:`write_table`, which validates, attaches provenance (``stucco.*``
schema metadata: stage, version, parameters, seed, input digests, table kind; :data:`METADATA_KEYS`) and
writes to a temporary name in the target directory before renaming it onto the target, so a reader never sees
a partial file. Writing the same table with the same metadata twice gives identical bytes. The metadata and
the writer options are documented in ``docs/tables.md``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import __version__
from pipeline.atomic import atomic_path
from pipeline.environment import environment
from pipeline.safe_open import NotRegularFile, regular_file
from pipeline.schema.csv_tables import is_csv, read_csv
from pipeline.schema.errors import SchemaError
from pipeline.schema.run_meta import check_run_metadata
from pipeline.schema.specs import CONTACTS_COLUMNS, TABLES, validate_table

__all__ = [
    "METADATA_KEYS",
    "WRITER_OPTIONS",
    "read_parquet",
    "read_table",
    "read_contacts",
    "read_tracks",
    "read_segments",
    "read_diagnostics",
    "write_table",
    "read_metadata",
    "probe_record",
    "file_digest",
    "recorded_number",
]

# The provenance keys write_table sets, with their meaning (the metadata section of docs/tables.md).
METADATA_KEYS: tuple[tuple[str, str], ...] = (
    ("stucco.stage", "Stage that wrote the file (e.g. `track`)."),
    ("stucco.version", "`pipeline.__version__` of the writer."),
    ("stucco.params", "JSON object of the stage's parameters, keys sorted."),
    ("stucco.seed", "JSON integer root seed, or `null`."),
    ("stucco.inputs", "JSON object role -> {\"file\": file name, \"sha256\": hex digest of the file bytes}."),
    ("stucco.environment", "JSON object: Python's version and those of the libraries that compute (numpy, scipy, "
                           "scikit-learn, numba, llvmlite, open3d-cpu, pybullet, pyarrow), pinned by "
                           "`requirements.lock`."),
    ("stucco.runs", "JSON object run name (`FB/0`) -> SHA-256 of the collected run file the table derives from, "
                    "carried through every input (absent when none is known); retrieval and scoring check their "
                    "run files against it."),
    ("stucco.schema", "Table kind: `sim_run`, `contacts`, `tracks`, `diagnostics`, `segments`, `retrieval`, "
                      "`candidates`, `scores` (or a stage's own kind)."),
)

# Fixed writer options: same bytes for the same table (no timestamps are written by parquet-cpp; the
# `created_by` string depends only on the pyarrow version).
WRITER_OPTIONS: dict[str, Any] = dict(
    compression="zstd",
    compression_level=3,
    version="2.6",
    use_dictionary=True,
    write_statistics=True,
    row_group_size=1 << 20,
)


# --------------------------------------------------------------------------------------------------------
# Reading


def read_parquet(path: str | os.PathLike) -> pa.Table:
    """Read a Parquet file without validating it (stage-owned tables validate it with their own spec).

    Raises
    ------
    SchemaError
        One line, when `path` does not exist, is not a file or is not Parquet.
    """
    p = _regular(path)
    try:
        return pq.ParquetFile(p).read()
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise SchemaError(p, None, None, f"not a Parquet file ({e})") from None


def read_table(path: str | os.PathLike, kind: str) -> pa.Table:
    """Read and validate a Parquet file of table kind `kind`; see :func:`validate_table`.

    A file of another table kind (e.g. a segments file given where a tracks file is expected) is refused by name:
    before its columns are checked when its provenance records the kind (``stucco.schema``); otherwise (a file
    written by other tools) when its columns, though valid for `kind`, are those of another kind
    (:func:`_infer_kind`: a segments table holds every tracks column).
    """
    table = read_parquet(path)
    raw = table.schema.metadata or {}
    recorded = raw.get(b"stucco.schema", b"").decode(errors="replace")
    if recorded != kind and recorded in TABLES:
        stage = raw.get(b"stucco.stage", b"").decode(errors="replace")
        raise SchemaError(path, None, None, f"is a {recorded} table{f' (written by stucco {stage})' if stage else ''}; "
                                            f"expected a {kind} table")
    valid = validate_table(table, kind, path)
    inferred = _infer_kind(table.column_names)
    if recorded not in TABLES and inferred != kind and inferred in TABLES:
        raise SchemaError(path, None, None, f"has the columns of a {inferred} table; expected a {kind} table")
    return valid


def read_contacts(path: str | os.PathLike) -> pa.Table:
    """Read and validate a contacts file (the input of ``stucco track``): Parquet, or CSV with the same columns
    (by the ``.csv`` extension: a robot's log written by other tools)."""
    if is_csv(path):
        return validate_table(read_csv(_regular(path), CONTACTS_COLUMNS), "contacts", path)
    return read_table(path, "contacts")


def read_tracks(path: str | os.PathLike) -> pa.Table:
    """Read and validate a tracks file (the output of ``stucco track``)."""
    return read_table(path, "tracks")


def read_segments(path: str | os.PathLike) -> pa.Table:
    """Read and validate a segments file (the output of ``stucco segment``)."""
    return read_table(path, "segments")


def read_diagnostics(path: str | os.PathLike) -> pa.Table:
    """Read and validate a diagnostics file (the side output of ``stucco track``)."""
    return read_table(path, "diagnostics")


def read_run(path: str | os.PathLike) -> pa.Table:
    """Read and validate a collected run file (``sim_run``, the output of ``stucco collect``), its rows against
    its metadata too (:func:`pipeline.schema.run_meta.check_run_metadata`: run, scene and seed; the ``probe``
    column and the probing policy's log)."""
    return read_run_and_metadata(path)[0]


def read_run_and_metadata(path: str | os.PathLike) -> tuple[pa.Table, dict[str, Any]]:
    """:func:`read_run`, and the run file's decoded metadata (:func:`read_metadata`) it was checked against: one
    read of each for callers that need both."""
    table = read_table(path, "sim_run")
    meta = read_metadata(path)
    check_run_metadata(table, meta, path)
    return table, meta


def probe_record(path: str | os.PathLike) -> dict:
    """The probing policy's log of a run file (its metadata's ``params.probe``), checked against the run's rows
    (:func:`read_run`); ``{}`` for a run of another policy. Every reader of the log goes through here."""
    return probe_log(read_run_and_metadata(path)[1])


def probe_log(meta: dict[str, Any]) -> dict:
    """The probing policy's log in a run file's metadata as :func:`read_run_and_metadata` returned it (checked
    against the run's rows there); ``{}`` for a run of another policy."""
    return (meta.get("params") or {}).get("probe") or {}


# --------------------------------------------------------------------------------------------------------
# Writing with provenance


def _regular(path: str | os.PathLike) -> Path:
    """``path`` when it is a regular file (:func:`pipeline.safe_open.regular_file`), else SchemaError naming it:
    "file not found", or what it is (a FIFO would block the reader, and with it the folder's lock)."""
    try:
        return regular_file(path, "the table")
    except NotRegularFile as e:
        raise SchemaError(e.path, None, None, "file not found" if e.reason.endswith("not found") else
                          e.reason.replace("the table is", "is")) from None


def file_digest(path: str | os.PathLike) -> str:
    """Hex SHA-256 of the file's bytes (SchemaError naming a path that is not a regular file)."""
    with open(_regular(path), "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (Path, os.PathLike)):
        return os.fspath(o)
    if isinstance(o, (set, frozenset)):
        return sorted(o)
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def _dumps(o: Any) -> str:
    return json.dumps(o, sort_keys=True, separators=(",", ":"), allow_nan=False, default=_json_default)


#: Columns that tell a table's kind when its provenance does not (checked in this order).
_KIND_MARKERS: tuple[tuple[str, frozenset[str]], ...] = tuple((k, frozenset(c)) for k, c in (
    ("diagnostics", ("ess", "n_replaced")), ("segments", ("segment", "tracker_label")),
    ("tracks", ("tracker_label", "estimate_step")), ("contacts", ("in_contact", "contact_x_m")),
    ("sim_run", ("win_wrench", "obj_pose")), ("retrieval", ("grasp_outcome", "true_x_m")),
    ("candidates", ("segment_chosen", "rank")), ("scores", ("contact_error_cm", "wall_s"))))


def _infer_kind(names: list[str]) -> str | None:
    s = set(names)
    return next((kind for kind, marker in _KIND_MARKERS if marker <= s), None)


def _write_parquet(table: pa.Table, sink) -> None:
    """The one place bytes are written (patched in tests to fail midway)."""
    pq.write_table(table, sink, **WRITER_OPTIONS)


def write_table(
    table: pa.Table,
    path: str | os.PathLike,
    *,
    stage: str,
    params: Mapping[str, Any],
    seed: int | None,
    inputs: Mapping[str, str | os.PathLike] | None = None,
    kind: str | None = None,
) -> Path:
    """Validate `table`, attach provenance and write it atomically to `path`.

    Parameters
    ----------
    table : pyarrow.Table
    path : path-like
        Target file; parent directories are created.
    stage : str
        Name of the writing stage (``stucco.stage``).
    params : mapping (or dataclass)
        The stage's parameters; stored as JSON with sorted keys (``stucco.params``). numpy scalars and
        arrays, paths and dataclasses are converted; NaN/inf are refused.
    seed : int or None
        Root seed (``stucco.seed``).
    inputs : mapping role -> path, optional
        Input files; each is recorded by file name and SHA-256 of its bytes (``stucco.inputs``).
    kind : str, optional
        Table kind (``stucco.schema``). Inferred from the columns when omitted; a kind of :data:`TABLES` is
        validated (and written in canonical form), any other kind is written as given.

    Returns
    -------
    pathlib.Path
        `path`.

    Notes
    -----
    The file is written under a temporary name in the target directory and renamed onto `path`
    (``os.replace``), so `path` is either the old file or the complete new one; on any error the temporary
    file is removed. The table's own schema metadata is replaced by the ``stucco.*`` keys. The same table
    and metadata give byte-identical files (fixed :data:`WRITER_OPTIONS`, chunks combined, no timestamps).
    """
    path = Path(path)
    if kind is None:
        kind = _infer_kind(table.column_names)
        if kind is None:
            raise ValueError(f"{path}: cannot tell the table kind from columns {table.column_names}; pass kind=")
    if kind in TABLES:
        table = validate_table(table, kind, path)
    if dataclasses.is_dataclass(params) and not isinstance(params, type):
        params = dataclasses.asdict(params)

    recorded = {role: {"file": Path(p).name, "sha256": file_digest(p)} for role, p in (inputs or {}).items()}
    runs = _runs_behind(inputs or {}, recorded)
    meta = {
        "stucco.stage": stage,
        "stucco.version": __version__,
        "stucco.params": _dumps(dict(params)),
        "stucco.seed": _dumps(None if seed is None else int(seed)),
        "stucco.inputs": _dumps(recorded),
        "stucco.environment": _dumps(environment()),
        "stucco.schema": kind,
    }
    if runs:
        meta["stucco.runs"] = _dumps(runs)
    table = table.replace_schema_metadata(meta).combine_chunks()

    with atomic_path(path, fsync=True) as tmp:
        with open(tmp, "xb") as f:  # default permissions (umask), unlike mkstemp's 0600
            _write_parquet(table, f)
    return path


def _runs_behind(inputs: Mapping[str, str | os.PathLike], recorded: Mapping[str, dict]) -> dict[str, str]:
    """Run name -> SHA-256 of the collected runs behind ``inputs``: a run file itself (its digest), or what an
    input table recorded (``stucco.runs``). Inputs without provenance add nothing."""
    runs: dict[str, str] = {}
    for role, p in inputs.items():
        try:
            meta = read_metadata(p)
        except SchemaError:
            continue
        params = meta.get("params") or {}
        if meta.get("schema") == "sim_run" and "scene" in params and "run_seed" in params:
            runs[f"{params['scene']}/{params['run_seed']}"] = recorded[role]["sha256"]
        else:
            runs.update(meta.get("runs") or {})
    return dict(sorted(runs.items()))


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """Decoded ``stucco.*`` schema metadata of a Parquet file, keys without the prefix.

    Returns
    -------
    dict
        Present keys among ``stage``, ``version``, ``schema`` (str), ``params``, ``inputs``, ``runs`` (dict), ``seed``
        (int or None). A file written by other tools gives ``{}``.
    """
    p = _regular(path)
    try:
        raw = pq.read_schema(p).metadata or {}
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as e:
        raise SchemaError(p, None, None, f"not a Parquet file ({e})") from None
    out: dict[str, Any] = {}
    for k, v in raw.items():
        key = k.decode()
        if not key.startswith("stucco."):
            continue
        name, text = key[len("stucco."):], v.decode()
        if name in ("params", "inputs", "seed", "environment", "runs"):
            try:
                out[name] = json.loads(text)
            except json.JSONDecodeError as e:
                raise SchemaError(p, None, None, f"metadata {key} is not valid JSON ({e})") from None
            _check_shape(p, key, out[name])
        else:
            out[name] = text
    return out


def _shown(value: Any) -> str:
    """A decoded JSON value as its (short) text, for messages."""
    return json.dumps(value, default=str)[:40]


def recorded_number(path: str | os.PathLike, params: Mapping[str, Any], key: str, default: float,
                    above: float = -np.inf, below: float = np.inf) -> float:
    """``params[key]`` (the ``stucco.params`` of ``path``) as a finite float in the open interval (``above``,
    ``below``), ``default`` when absent; SchemaError naming the file and key for a value of another type (``[1]``,
    ``"x"``), not finite or out of the interval."""
    value = params.get(key, default)
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value)
            or not above < value < below):
        raise SchemaError(Path(path), None, None, f"metadata stucco.params.{key} is {_shown(value)}; expected a "
                                                  f"finite number in ({above:g}, {below:g})")
    return float(value)


def _check_shape(path: Path, key: str, value: Any) -> None:
    """SchemaError naming ``path`` and ``key`` unless the decoded JSON has the shape :data:`METADATA_KEYS` gives."""
    if key == "stucco.seed":
        if value is not None and (not isinstance(value, int) or isinstance(value, bool)):
            raise SchemaError(path, None, None, f"metadata {key} is {_shown(value)}; expected an integer or null")
        return
    if not isinstance(value, dict):
        raise SchemaError(path, None, None, f"metadata {key} is {_shown(value)}; expected a JSON object")
    if key == "stucco.runs" and not all(isinstance(v, str) for v in value.values()):
        raise SchemaError(path, None, None, f"metadata {key} is {_shown(value)}; expected run name -> SHA-256")
    if key == "stucco.inputs":
        for role, entry in value.items():
            if not (isinstance(entry, dict) and all(isinstance(entry.get(k), str) for k in ("file", "sha256"))):
                raise SchemaError(path, None, None, f"metadata {key}: input {role!r} is {_shown(entry)}; "
                                                    'expected {"file": name, "sha256": hex digest}')
