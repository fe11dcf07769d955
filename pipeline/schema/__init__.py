"""The Parquet tables the stages exchange: their columns, units and rules, validation on read, atomic writes.

Tables (long format, one row per (run, step[, contact])):

``contacts``
    Input of ``stucco track``; written by ``collect`` or by hand from a real robot log.
``tracks``
    Output of ``stucco track``: tracked contact point positions and the tracker's hard labels.
``segments``
    Output of ``stucco segment``: the tracks columns plus ``segment``.
``diagnostics``
    Side output of ``stucco track``: one row per control step describing the filter update.
``sim_run``
    Output of ``stucco collect``, input of ``isolate``, ``retrieve`` and ``score``: one row per action.

Each table is described once, as data (:data:`CONTACTS_COLUMNS`, :data:`TRACKS_COLUMNS`, ...; gathered in
:data:`TABLES`), and both validation and ``docs/tables.md`` are derived from those descriptions. Validation
fails with a one-line :class:`SchemaError` naming the file, the column and the first bad row.

Every file a stage writes goes through :func:`write_table`, which validates, attaches provenance
(``stucco.*`` schema metadata: stage, version, parameters, seed, input digests, table kind) and writes to a
temporary name in the target directory before renaming it onto the target, so a reader never sees a partial
file. Writing the same table with the same metadata twice gives identical bytes.

One role per module (each imports only the ones listed before it):

:mod:`~pipeline.schema.errors`
    :class:`SchemaError`.
:mod:`~pipeline.schema.columns`
    The description types :class:`Column`, :class:`TableSpec` and the column views table rules receive.
:mod:`~pipeline.schema.validate`
    The validation engine (:func:`validate_spec`): per-column checks, then the spec's rule.
:mod:`~pipeline.schema.rules`
    The multi-column and multi-row rules of the stage tables.
:mod:`~pipeline.schema.runs`
    The ``sim_run`` table as data (:data:`SIM_RUN`) and its rule.
:mod:`~pipeline.schema.run_meta`
    A run file's rows against its metadata: run, scene and seed, the ``probe`` column, the probing policy's log.
:mod:`~pipeline.schema.specs`
    The stage tables as data (:data:`TABLES`) and their validators (:func:`validate_table`, ...).
:mod:`~pipeline.schema.io`
    Reading (:func:`read_table`, ...) and atomic writing with provenance (:func:`write_table`).
:mod:`~pipeline.schema.contacts`
    :class:`RunContacts`: a contacts table split into runs, grouped by step, for the tracker.
:mod:`~pipeline.schema.docs`
    The Markdown of ``docs/tables.md``.

This package re-exports the public names; import them from here (``from pipeline import schema``).
"""
from __future__ import annotations

from pipeline.schema.columns import Column, TableSpec
from pipeline.schema.contacts import RunContacts, contacts_by_run, step_bounds
from pipeline.schema.docs import columns_markdown, table_markdown
from pipeline.schema.errors import SchemaError
from pipeline.schema.io import (
    METADATA_KEYS,
    WRITER_OPTIONS,
    file_digest,
    probe_log,
    probe_record,
    read_contacts,
    read_diagnostics,
    read_metadata,
    read_parquet,
    read_run,
    read_run_and_metadata,
    read_segments,
    read_table,
    read_tracks,
    recorded_number,
    write_table,
)
from pipeline.schema.runs import PAD_COLUMNS, SIM_RUN, SIM_RUN_COLUMNS
from pipeline.schema.specs import (
    CONTACTS,
    CONTACTS_COLUMNS,
    DIAGNOSTICS,
    DIAGNOSTICS_COLUMNS,
    SEGMENTS,
    SEGMENTS_COLUMNS,
    TABLES,
    TRACKS,
    TRACKS_COLUMNS,
    validate_contacts,
    validate_diagnostics,
    validate_segments,
    validate_table,
    validate_tracks,
)
from pipeline.schema.validate import validate_spec

__all__ = [
    "SchemaError",
    "Column",
    "TableSpec",
    "CONTACTS_COLUMNS",
    "TRACKS_COLUMNS",
    "SEGMENTS_COLUMNS",
    "DIAGNOSTICS_COLUMNS",
    "CONTACTS",
    "TRACKS",
    "SEGMENTS",
    "DIAGNOSTICS",
    "SIM_RUN_COLUMNS",
    "PAD_COLUMNS",
    "SIM_RUN",
    "TABLES",
    "METADATA_KEYS",
    "WRITER_OPTIONS",
    "read_contacts",
    "validate_contacts",
    "read_tracks",
    "validate_tracks",
    "read_segments",
    "validate_segments",
    "read_diagnostics",
    "read_run",
    "read_run_and_metadata",
    "probe_log",
    "probe_record",
    "validate_diagnostics",
    "read_table",
    "validate_table",
    "validate_spec",
    "read_parquet",
    "write_table",
    "read_metadata",
    "file_digest",
    "recorded_number",
    "RunContacts",
    "contacts_by_run",
    "step_bounds",
    "columns_markdown",
    "table_markdown",
]
