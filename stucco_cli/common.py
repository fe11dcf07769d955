"""What every `stucco` command shares: the group's settings, one-line errors, checked option types and paths.

Errors a user can fix (bad input files, unknown scenes, bad option values, outputs that cannot be written)
surface as one line through :class:`click.ClickException` or :class:`click.UsageError` with a non-zero exit code,
never as a traceback.
"""
from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import click


@dataclass
class Settings:
    """The global options (``--seed``, ``-j``, ``-v``, ``-q``), shared with every command through the click context.

    They may be given before the command (``stucco -j 2 track ...``) or after it (``stucco track ... -j 2``), with
    the same meaning; given in both places, the one after the command wins.
    """

    seed: int = 0
    jobs: int = 1
    verbosity: int = 0  # -1 quiet, 0 normal, >0 verbose

    @property
    def quiet(self) -> bool:
        return self.verbosity < 0


pass_settings = click.make_pass_decorator(Settings, ensure=True)


def configure_logging(verbosity: int) -> None:
    """Root log level for ``verbosity`` (-1: errors only; 0: warnings; 1: info; 2+: debug)."""
    level = logging.ERROR if verbosity < 0 else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbosity, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)


def say(settings: Settings, text: str) -> None:
    """What a command did (the files it wrote), one line to stderr; nothing with ``-q``."""
    if not settings.quiet:
        click.echo(text, err=True)


#: Worker processes: each holds pybullet, numba and Open3D (a few hundred MB), so 64 already fill a 24 GiB machine.
JOBS = click.IntRange(1, 64)
SEED = click.IntRange(min=0)

#: Commands that run independent runs in worker processes, where ``-j`` applies (stated in its messages).
JOBS_COMMANDS = "collect, track, retrieve, evaluate, study, bench"


def _apply(name: str, ctx: click.Context, value) -> None:
    s = ctx.ensure_object(Settings)
    if name == "seed":
        s.seed = value
    elif name == "jobs":
        s.jobs = value
    elif name == "verbose":
        s.verbosity = value if s.verbosity < 0 else s.verbosity + value
    elif name == "quiet":
        s.verbosity = -1
    configure_logging(s.verbosity)


def _setter(name: str, refuse: str | None):
    def callback(ctx: click.Context, param: click.Parameter, value):
        if value is None or value is False or (name == "verbose" and value == 0):  # not given
            return
        if refuse:
            flag = "/".join(sorted(param.opts, key=len))
            raise click.UsageError(f"{flag} does not apply to `{ctx.command_path}`: {refuse}")
        _apply(name, ctx, value)

    return callback


def global_options(jobs: str | None = None, seed: str | None = None, own_jobs: bool = False):
    """Accept the group's global options after a command too, with the same meaning.

    ``jobs`` / ``seed``: None when the option applies to the command, else why it does not (the usage error then
    says so and where the option goes). ``own_jobs``: the command has its own ``-j`` (``evaluate``), left alone.
    """
    opts = [click.option("--seed", type=SEED, default=None, expose_value=False,
                         callback=_setter("seed", seed), hidden=seed is not None,
                         help="Root seed, as `stucco --seed` (before or after the command).")]
    if not own_jobs:
        opts.append(click.option("--jobs", "-j", type=JOBS, default=None, expose_value=False,
                                 callback=_setter("jobs", jobs), hidden=jobs is not None,
                                 help="Worker processes, as `stucco -j` (before or after the command)."))
    opts += [click.option("-v", "--verbose", count=True, expose_value=False, callback=_setter("verbose", None),
                          help="More log output, as `stucco -v`."),
             click.option("-q", "--quiet", is_flag=True, default=False, expose_value=False,
                          callback=_setter("quiet", None), help="Only errors, as `stucco -q`.")]

    def decorate(f):
        for o in reversed(opts):
            f = o(f)
        return f

    return decorate


#: Why ``-j`` does not apply to a command that runs in one process, and where it goes.
ONE_PROCESS = f"it runs in one process; -j goes with {JOBS_COMMANDS} (before or after the command name)"
#: Why ``--seed`` does not apply to a command that draws nothing at random.
NOT_RANDOM = "it draws nothing at random; --seed goes with the stages (collect ... score), evaluate, study, bench"

FORCE_OVERWRITE = click.option("--force-overwrite", is_flag=True,
                               help="Replace existing output files (without it the command refuses to overwrite).")


def refuse_overwrite(outputs: dict[str, object] | list[tuple[str, object]], force: bool) -> None:
    """The one overwrite rule of every stage command: an output that exists is refused, in one line naming it, the
    option that names it and the flag that allows replacing it, unless ``force`` (``--force-overwrite``).

    ``outputs``: option -> path, or (option, path) pairs where one option names several files (collect's runs)."""
    if force:
        return
    for opt, path in (outputs.items() if isinstance(outputs, dict) else outputs):
        if path is not None and Path(path).expanduser().exists():
            raise click.ClickException(f"{path}: exists ({opt}); pass --force-overwrite to replace it")


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


def policy_params(values: tuple[str, ...], policy: str) -> tuple[tuple[str, object], ...]:
    """``--policy-param NAME=VALUE`` options -> ((name, value), ...), each value read as JSON where it is JSON
    (``400``, ``0.02``, ``["front", "far"]``) and as text otherwise (``touch``), checked against ``policy``'s
    parameter class: click's one-line "Invalid value for '--policy-param'" otherwise."""
    import json

    from pipeline import registry

    out = []
    for item in values:
        name, eq, text = item.partition("=")
        if not eq or not name.strip():
            raise click.BadParameter(f"expected NAME=VALUE, got {item!r}", param_hint="'--policy-param'")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        out.append((name.strip(), value))
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise click.BadParameter(f"{names[0]} given twice", param_hint="'--policy-param'")
    try:
        registry.build_params(registry.policy(policy), dict(out))
    except (ValueError, TypeError) as e:
        raise click.BadParameter(f"--policy {policy}: {e}", param_hint="'--policy-param'") from None
    return tuple(out)


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
