"""Every file a command reads is a regular file: checked before it is opened, in one line naming it.

A FIFO where a run, a side file or ``evaluation.json`` should be blocks the reader forever (and with it the folder's
lock); a device reads without end; a directory or a dangling symbolic link fails with an error that does not say
which file. :func:`regular_file` refuses all of them, one line naming the file and what it is, before anything
opens it; :func:`read_bytes` and :func:`read_text` open without blocking (``O_NONBLOCK``) and check the open file
itself, so a file swapped for a FIFO between the check and the open is refused too. :func:`optional_file` is the
same for a file that may be absent (a policy's side file).
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["NotRegularFile", "regular_file", "optional_file", "read_bytes", "read_text"]


class NotRegularFile(ValueError):
    """A path a command reads is missing or not a regular file (FIFO, socket, device, directory, dangling link);
    one line naming it. ``path`` and ``reason`` (the message without the path) let a caller re-raise it as its
    own error type."""

    def __init__(self, path: str | os.PathLike, reason: str):
        self.path, self.reason = Path(path), reason
        super().__init__(f"{path}: {reason}")


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a regular file"


def _refusal(path: Path, what: str, mode: int) -> NotRegularFile:
    return NotRegularFile(path, f"{what} is {_kind(mode)}, not a regular file; replace it with the file or "
                                "remove it")


def optional_file(path: str | os.PathLike, what: str = "the file") -> Path | None:
    """``path`` when it is a regular file (symbolic links followed), None when nothing is there; NotRegularFile
    (one line naming it) for anything else: a FIFO, socket, device, directory or dangling symbolic link."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        if os.path.lexists(p):
            raise NotRegularFile(p, f"{what} is a symbolic link to nothing ({os.readlink(p)}); fix or "
                                    "remove it") from None
        return None
    except OSError as e:  # a link loop, a name too long, a component that is a file
        raise NotRegularFile(p, f"{what} cannot be read ({e.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise _refusal(p, what, st.st_mode)
    return p


def regular_file(path: str | os.PathLike, what: str = "the file") -> Path:
    """``path`` when it is a regular file; NotRegularFile (one line naming it) when it is missing or anything
    else (a FIFO, socket, device, directory, dangling symbolic link)."""
    p = optional_file(path, what)
    if p is None:
        raise NotRegularFile(path, f"{what} not found")
    return p


def read_bytes(path: str | os.PathLike, what: str = "the file") -> bytes:
    """The bytes of the regular file ``path`` (:func:`regular_file`); the file is opened without blocking and the
    open file checked again, so nothing swapped in after the check can block the read."""
    p = regular_file(path, what)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise NotRegularFile(p, f"{what} cannot be read ({e.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _refusal(p, what, st.st_mode)
        with os.fdopen(fd, "rb", closefd=False) as f:
            return f.read()
    finally:
        os.close(fd)


def read_text(path: str | os.PathLike, what: str = "the file") -> str:
    """:func:`read_bytes` decoded as UTF-8 (ValueError naming the file for other bytes)."""
    data = read_bytes(path, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise NotRegularFile(path, f"{what} is not UTF-8 text (byte {e.start})") from None
