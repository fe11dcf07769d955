"""Reading an evaluation directory back: one kind as a table, the scores of a grid, and the report files.

Each kind directory is a Parquet dataset read with ``pyarrow.dataset``: a flat kind as it is (its files hold their
keys), a hive-partitioned kind with an explicit partitioning schema, so its keys come back as string and int64
like the flat kinds' (docs/evaluation.md, "The output directory").
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa

from pipeline.atomic import together, write_text
from pipeline.environment import environment_line
from pipeline.evaluate.config import Job
from pipeline.evaluate.stages import STAGE_COLUMNS
from pipeline.layout import FLAT, KINDS, PER_ESTIMATOR, SHARED, partition
from pipeline.registry import DEFAULT_ESTIMATOR
from pipeline.report import claims, table_ii, to_csv, to_markdown
from pipeline.score import SCORES_COLUMNS, read_scores

__all__ = ["read_kind", "gather_scores", "write_report"]


def _partitioning(kind: str):
    # Imported here: pyarrow.dataset (80 ms to import, measured) is only needed to read a whole kind back.
    import pyarrow.dataset as ds

    if kind in FLAT:
        return None
    fields = [("scene", pa.string()), ("seed", pa.int64())]
    if kind not in SHARED:
        fields.append(("method", pa.string()))
    if kind in PER_ESTIMATOR:
        fields.append(("estimator", pa.string()))
    return ds.partitioning(pa.schema(fields), flavor="hive")


def read_kind(out: str | Path, kind: str, filter=None) -> pa.Table:
    """Every partition of one kind under an evaluation directory as one table (``pyarrow.dataset``).

    Partition keys (scene, seed[, method[, estimator]]) are columns of the result (the flat kinds' files hold them;
    the hive kinds' come from the path).
    ``filter`` is a ``pyarrow.dataset`` expression, e.g. ``ds.field("method") == "stucco"``.
    """
    import pyarrow.dataset as ds

    root = Path(out) / kind
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such directory; has the evaluation run?")
    return ds.dataset(root, format="parquet", partitioning=_partitioning(kind)).to_table(filter=filter)


def gather_scores(out: str | Path, job_list: Sequence[Job], estimators: Sequence[str] = (DEFAULT_ESTIMATOR,)
                  ) -> pa.Table:
    """The scores of the given jobs (those finished), one row per job and estimator, in grid order.

    With no finished job, an empty table with the scores columns and :data:`STAGE_COLUMNS`.
    """
    tables = []
    for j in sorted(job_list):
        for est in estimators:
            path = partition(out, "scores", j.scene, j.seed, j.method, est)
            if path.is_file():
                tables.append(read_scores(path))
    if not tables:
        cols = [pa.field(c.name, c.type) for c in SCORES_COLUMNS] + [pa.field(c, pa.float64()) for c in STAGE_COLUMNS]
        return pa.schema(cols).empty_table()
    return pa.concat_tables(tables, promote_options="permissive")


@together()  # its outputs appear all together or not at all
def write_report(out: str | Path, scores: pa.Table, extra: tuple[str, ...] = (),
                 estimator_stream: int = 0, tail: str = "") -> tuple[Path, Path]:
    """``out/report.md`` (Table II with the paper's claims checked below it, then the ``extra`` lines, e.g. the
    active protocol's probes) and ``out/report.csv``, atomically, from a scores table made with the pose
    estimators' random stream ``estimator_stream``; ``tail`` (Markdown, e.g. the active protocol's summary table)
    goes after the notes."""
    rows = table_ii(scores, estimator_stream)
    md = to_markdown(rows)
    notes = claims(rows) + list(extra)
    if notes:
        md += "\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    if tail:
        md += "\n" + tail
    md += f"\nComputed with {environment_line()} (requirements.lock).\n"
    paths = (Path(out) / "report.md", Path(out) / "report.csv")
    for path, text in zip(paths, (md, to_csv(rows))):
        write_text(path, text)
    return paths
