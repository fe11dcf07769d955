"""An evaluation folder of layout 2 brought to layout 3 in place (:data:`pipeline.layout.LAYOUT_VERSION`).

Layout 2 has the same tables at the same paths; it also kept each stage's wall time in side files
(``_wall_s.json`` beside a hive partition, ``_wall_s/<name>.json`` beside a flat file), now returned in memory and
kept in the scores only, and named a policy's side files ``<run><suffix>``, which pyarrow tries to read as Parquet
when it opens ``DIR/runs``; layout 3 names them ``_<run><suffix>`` (:func:`pipeline.registry.side_path`).
Every step can be redone, and ``evaluation.json`` is rewritten last (by the caller), so an interrupted migration
is finished by the next call.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from pipeline import registry
from pipeline.layout import KINDS

__all__ = ["MIGRATES_FROM", "migrate"]

#: The layout version :func:`migrate` upgrades.
MIGRATES_FROM = 2
#: Layout 2's wall-time side files: beside a hive partition, and the folder of them beside flat files.
_WALL_FILE, _WALL_DIR = "_wall_s.json", "_wall_s"


def migrate(out: str | Path) -> list[str]:
    """Bring the folder ``out`` of layout 2 to layout 3; returns what was done, one line per kind of change."""
    out = Path(out)
    removed = 0
    for kind in KINDS:
        root = out / kind
        if not root.is_dir():
            continue
        for wall in root.rglob(_WALL_FILE):
            wall.unlink()
            removed += 1
        if (root / _WALL_DIR).is_dir():
            removed += sum(1 for _ in (root / _WALL_DIR).iterdir())
            shutil.rmtree(root / _WALL_DIR)
    renamed = 0
    runs = out / "runs"
    for suffix in registry.side_suffixes() if runs.is_dir() else ():
        for old in runs.glob(f"*{suffix}"):
            if old.name.startswith("_"):
                continue
            stem = old.name[: -len(suffix)]
            old.replace(registry.side_path(runs / f"{stem}.parquet", suffix))
            renamed += 1
    return [f"removed {removed} wall-time side file(s) (the scores keep the stage times)",
            f"renamed {renamed} policy side file(s) to _<run><suffix>"]
