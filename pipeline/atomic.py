"""Safe writes: every output goes to a unique temporary name beside its target and is renamed; one writer per folder.

A reader (or a second process writing the same target) sees either the old file or the complete new one, never
a partial file; a failed or interrupted write removes its temporary file. The temporary name carries the process
id and a random token, so concurrent writers of one target never share it, and ends in ``.tmp``, so a leftover
of a killed process never matches a reader's ``*.parquet`` or ``*.png``. :func:`exclusive` lets one process at
a time write a folder that several commands may target (``stucco evaluate --out``).
"""
from __future__ import annotations

import errno
import fcntl
import os
import secrets
import stat
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "all_or_none", "write_text", "save_figure", "exclusive", "FolderBusy", "LockLost",
           "held_lock", "guard_writes", "together"]


class FolderBusy(RuntimeError):
    """Another process holds the folder's lock (the message names the folder and the holder's pid)."""


class LockLost(RuntimeError):
    """A worker's writes are refused: the process that holds the folder's lock for it is gone or released it."""


#: (lock file, pid) of the folder lock this process holds (:func:`exclusive`), handed to its worker processes.
_HELD: list[tuple[str, int]] = []
#: (lock file, pid) of the lock this worker process writes under (:func:`guard_writes`); every rename checks it.
_GUARD: list[tuple[str, int]] = []


def held_lock() -> tuple[str, int] | None:
    """The folder lock this process holds now (lock file, pid), for :func:`guard_writes` in its workers."""
    return _HELD[-1] if _HELD else None


def guard_writes(held: tuple[str, int] | None) -> None:
    """In a worker process: from now on, every output (:func:`atomic_path`, :func:`all_or_none`) is renamed into
    place only while the process ``held[1]`` is this process's parent and its lock file ``held[0]`` still names
    it; otherwise the write is dropped and :class:`LockLost` raised. A worker orphaned by a killed parent, or still
    busy after the parent released the folder, never writes into it. None: no guard."""
    _GUARD[:] = [] if held is None else [(str(held[0]), int(held[1]))]


def _check_guard() -> None:
    if not _GUARD:
        return
    lock, pid = _GUARD[0]
    try:
        holder = Path(lock).read_bytes()[:32].decode(errors="replace").strip()
    except OSError:
        holder = ""
    if os.getppid() != pid or holder != str(pid):
        raise LockLost(f"{lock}: the process {pid} that holds this folder is gone or released it; this worker "
                       "writes nothing more")


def _temporary(path: Path) -> Path:
    """A hidden name beside `path`, unique to this process and call, ending in ``.tmp``."""
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


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
    tmp = _temporary(path)
    try:
        yield tmp
        if fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        if _GROUPS:  # renamed with the rest of its group (:func:`together`)
            _GROUPS[-1].append((tmp, path))
            return
        _check_guard()
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise _named(e, tmp, path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _named(e: OSError, tmp: Path, path: Path) -> OSError:
    """``e`` naming the target ``path`` instead of its hidden temporary name (what a user can find and fix)."""
    if e.filename is not None and Path(e.filename).name == tmp.name:
        return type(e)(e.errno, e.strerror, str(path))
    return e


#: The open groups of :func:`together`: (temporary, target) of each write made inside, in order.
_GROUPS: list[list[tuple[Path, Path]]] = []


@contextmanager
def together() -> Iterator[None]:
    """Outputs that belong together (a bench's CSV files and figure, ``report.md`` and ``report.csv``, a regression
    snapshot) appear all together or not at all: every write made inside the block through this module
    (:func:`atomic_path`, :func:`write_text`, :func:`write_csv_rows`, :func:`save_figure`, and
    :func:`pipeline.schema.write_table`) goes to its temporary name, and all are renamed onto their targets only
    when the block ends without error; if it fails, every temporary is removed and no target is touched. Blocks
    nest (the outer one renames)."""
    _GROUPS.append([])
    try:
        yield
    except BaseException:
        for tmp, _ in _GROUPS.pop():
            tmp.unlink(missing_ok=True)
        raise
    group = _GROUPS.pop()
    if _GROUPS:  # an inner block: its writes are the outer block's
        _GROUPS[-1].extend(group)
        return
    try:
        _check_guard()
    except BaseException:
        for tmp, _ in group:
            tmp.unlink(missing_ok=True)
        raise
    for tmp, target in group:
        os.replace(tmp, target)


@contextmanager
def all_or_none(paths: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield one temporary path per target, to write a stage's outputs to; after the block every one is renamed
    onto its target, so the outputs appear together. If the block fails, no target is touched and the
    temporaries are removed: a stage leaves all of its outputs or none (renames within a folder do not fail once
    the files are written)."""
    targets = [Path(p) for p in paths]
    if len(set(targets)) != len(targets):
        raise ValueError(f"two outputs share one path: {sorted(str(t) for t in targets)}")
    tmps = [_temporary(t) for t in targets]
    for t in targets:
        t.parent.mkdir(parents=True, exist_ok=True)
    try:
        yield tmps
        _check_guard()
        for tmp, target in zip(tmps, targets):
            os.replace(tmp, target)
    except BaseException:
        for tmp in tmps:
            tmp.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically; returns `path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_csv_rows(path: str | os.PathLike, rows: Sequence[dict], fields: Sequence[str]) -> Path:
    """Write dict rows as CSV (header ``fields``, the csv module's default dialect) to `path` atomically; returns
    `path`."""
    import csv  # only the callers that write CSV pay for it

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(fields))
        w.writeheader()
        w.writerows(rows)
    return Path(path)


def save_figure(fig, path: str | os.PathLike, dpi: int = 100, image_format: str | None = None,
                metadata: dict[str, str] | None = None) -> Path:
    """Save a matplotlib figure to `path` atomically (format: `image_format`, else from the suffix, else PNG) and
    close it; `metadata` (key -> text) goes into the file as the format allows (a PNG's text chunks); returns
    `path`."""
    import matplotlib.pyplot as plt  # only callers that draw pay for matplotlib

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=image_format or Path(path).suffix.lstrip(".") or "png",
                        **({"metadata": metadata} if metadata else {}))
    finally:
        plt.close(fig)
    return Path(path)


@contextmanager
def exclusive(folder: str | os.PathLike, name: str = ".lock") -> Iterator[Path]:
    """Hold an exclusive lock on `folder` (created if needed) while the block runs, or raise :class:`FolderBusy`.

    The lock is an advisory ``flock`` on ``folder/name``, released by the operating system when the process ends,
    so a killed process never leaves the folder locked. The holder's pid is written into the file for the message.
    A ``folder/name`` that is a symbolic link or not a regular file is refused (ValueError), never followed.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / name
    # Never through a link (its target would be truncated) nor into a FIFO or device (open or write could block).
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise ValueError(f"{lock}: is a symbolic link; the lock must be a plain file (remove the link)") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ValueError(f"{lock}: is not a regular file; the lock must be a plain file (remove it)")
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise FolderBusy(f"{folder}: another process (pid {holder}) is writing here; wait for it to finish or "
                             "use another folder") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        _HELD.append((str(lock.resolve()), os.getpid()))
        try:
            yield lock
        finally:
            _HELD.pop()
            os.ftruncate(fd, 0)  # no longer names this process: its workers' writes are refused from now on
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
