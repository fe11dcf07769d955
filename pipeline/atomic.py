"""Atomic file writes: every output is written under a unique temporary name beside its target, then renamed.

A reader (or a second process writing the same target) sees either the old file or the complete new one, never
a partial file; a failed or interrupted write removes its temporary file. The temporary name carries the process
id and a random token, so concurrent writers of one target never share it, and ends in ``.tmp``, so a leftover
of a killed process never matches a reader's ``*.parquet`` or ``*.png``.
"""
from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text", "save_figure"]


@contextmanager
def atomic_path(path: str | os.PathLike, *, fsync: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write `path`'s new content to; on success it is renamed onto `path`.

    Parameters
    ----------
    path : path-like
        The target; its parent directories are created.
    fsync : bool
        Flush the temporary file to disk before the rename (for files a crash must not leave empty).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        yield tmp
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically; returns `path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(fig, path: str | os.PathLike, dpi: int = 100) -> Path:
    """Save a matplotlib figure to `path` atomically (format from the suffix) and close it; returns `path`."""
    import matplotlib.pyplot as plt  # only callers that draw pay for matplotlib

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return Path(path)
