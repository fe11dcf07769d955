"""What every `stucco` command shares: the group's settings, one-line errors, checked option types and paths.

Errors a user can fix (bad input files, unknown scenes, bad option values, outputs that cannot be written)
surface as one line through :class:`click.ClickException` or :class:`click.UsageError` with a non-zero exit code,
never as a traceback.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click


@dataclass
class Settings:
    """Options of the `stucco` group, shared with every command through the click context."""

    seed: int = 0
    jobs: int = 1
    verbosity: int = 0  # -1 quiet, 0 normal, >0 verbose

    @property
    def progress(self) -> bool | None:
        """tqdm's `disable` argument: bars off when quiet, auto (TTY only) otherwise."""
        return True if self.verbosity < 0 else None


pass_settings = click.make_pass_decorator(Settings, ensure=True)


@contextmanager
def user_errors(what: str | None = None):
    """Turn the errors a user can fix (bad files, bad values) into one-line :class:`click.ClickException`."""
    from pipeline.atomic import FolderBusy
    from pipeline.schema import SchemaError

    try:
        yield
    except (SchemaError, FolderBusy) as e:
        raise click.ClickException(str(e)) from None
    except (ValueError, FileNotFoundError) as e:
        msg = " ".join(str(e).split())
        raise click.ClickException(f"{what}: {msg}" if what else msg) from None
    except OSError as e:  # an output the checks of check_paths could not foresee (full disk, read-only mount)
        where = f"{e.filename}: " if e.filename else ""
        raise click.ClickException(f"{what + ': ' if what else ''}{where}{e.strerror or e}") from None


def parsed(param_hint: str, parse, text):
    """``parse(text)``, a ValueError becoming click's one-line "Invalid value for PARAM_HINT" (exit code 2)."""
    try:
        return parse(text)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint=param_hint) from None


def unique(param_hint: str, values: tuple) -> tuple:
    """``values`` unless one is given twice: click's one-line "Invalid value for PARAM_HINT" (exit code 2)."""
    twice = [v for i, v in enumerate(values) if v in values[:i]]
    if twice:
        raise click.BadParameter(f"{twice[0]!r} is given twice", param_hint=param_hint)
    return values


class FiniteFloat(click.FloatRange):
    """A float option that must be finite (nan and inf refused, unlike :class:`click.FloatRange`) and in range."""

    name = "finite float"

    def convert(self, value, param, ctx):
        import math

        rv = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return super().convert(rv, param, ctx)


#: Physical or logical bounds of the options several commands share (docs/tables.md gives the units).
POSITIVE = FiniteFloat(min=0.0, min_open=True)
NON_NEGATIVE = FiniteFloat(min=0.0)
ALPHA = FiniteFloat(min=0.0, max=1.0, min_open=True, max_open=True)  # exp(-d^2/l) > alpha: 0 and 1 are degenerate
#: Worker processes: each holds pybullet, numba and Open3D (a few hundred MB), so 64 already fill a 24 GiB machine.
JOBS = click.IntRange(1, 64)


def check_paths(inputs: dict[str, object], outputs: dict[str, object]) -> None:
    """Refuse, in one line and before any work, outputs that could not be written or would destroy data.

    ``inputs`` and ``outputs`` map option names (``--in``) to paths (None: not given); every input of the command
    is listed, folders included. An output may not be one of the command's inputs, a file inside an input folder
    (``--runs DIR``'s run files), another output, an existing directory, a name longer than the file system
    allows, behind a symbolic link loop, or lie under a file or in a directory this user cannot write (missing
    parent directories are created later). Paths are compared after following symbolic links.
    """
    for opt, path in outputs.items():
        if path is not None:
            writable_file(opt, path)
    ins: dict[Path, str] = {}
    for opt, path in inputs.items():
        if path is None:
            continue
        k = resolved(opt, path)
        ins.setdefault(k, f"{opt} {path}")
        if k.is_dir():  # a folder's files are inputs too (the run files of --runs DIR)
            for entry in sorted(k.iterdir()):
                try:
                    ins.setdefault(entry.resolve(), f"{entry.name} of {opt} {path}")
                except (RuntimeError, OSError):  # a link loop inside an input folder is nothing one can overwrite
                    continue
    seen: dict[Path, str] = {}
    for opt, path in outputs.items():
        if path is None:
            continue
        k = resolved(opt, path)
        if k in ins:
            raise click.UsageError(f"{opt} {path} is also {ins[k]}: a command never overwrites its own input; "
                                   f"choose another {opt}")
        if k in seen:
            raise click.UsageError(f"{opt} {path} is also {seen[k]}: two outputs cannot share one file")
        seen[k] = opt


def resolved(opt: str, path) -> Path:
    """``path`` with ``~`` expanded and symbolic links followed; a one-line :class:`click.UsageError` naming
    ``opt`` for a symbolic link loop (or a path the system cannot follow)."""
    try:
        return Path(path).expanduser().resolve()
    except (RuntimeError, OSError) as e:  # Python 3.11 raises RuntimeError("Symlink loop ...")
        raise click.UsageError(f"{opt} {path}: cannot follow its symbolic links ({e}); remove the loop or choose "
                               f"another {opt}") from None


def writable_file(opt: str, path) -> None:
    """Raise a one-line :class:`click.UsageError` naming ``opt`` unless ``path`` can be created as a file."""
    p = Path(path).expanduser()
    resolved(opt, p)
    if len(p.name.encode()) > _NAME_MAX:
        raise click.UsageError(f"{opt}: the file name is {len(p.name.encode())} bytes long; at most {_NAME_MAX}")
    writable_dir(opt, p.parent)
    if p.is_dir():
        raise click.UsageError(f"{opt} {path} is a directory; expected a file name")


def writable_dir(opt: str, path) -> None:
    """Raise a one-line :class:`click.UsageError` naming ``opt`` unless ``path`` is, or can be made, a directory
    this user can write."""
    d = resolved(opt, path)
    if any(len(part.encode()) > _NAME_MAX for part in d.parts):
        raise click.UsageError(f"{opt} {path}: a directory name is longer than {_NAME_MAX} bytes")
    existing = d
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise click.UsageError(f"{opt} {path}: {existing} is a file, not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise click.UsageError(f"{opt} {path}: the directory {existing} is not writable")


#: Longest file name (bytes) of the usual Linux and macOS file systems.
_NAME_MAX = 255
