"""Progress bars and progress lines of every command: one rule, here.

tqdm bars are drawn only when stderr is a terminal and ``-q`` was not given: a log file or a pipe never gets the
``\\r``-rewritten lines of a bar. Every command hands a stage either :func:`bars_off` (the ``progress`` argument
of the stages that draw their own bar, tqdm's ``disable``) or :func:`run_bar` (a bar over finished runs).
"""
from __future__ import annotations

import sys
from collections.abc import Callable

from stucco_cli.common import Settings


def stderr_is_terminal() -> bool:
    """Whether stderr is a terminal (False when it is a file, a pipe, or click's test runner)."""
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stream
        return False


def bars_off(settings: Settings) -> bool:
    """tqdm's ``disable`` for a stage's own bar: True with ``-q`` or when stderr is not a terminal."""
    return settings.verbosity < 0 or not stderr_is_terminal()


def run_bar(settings: Settings, desc: str) -> Callable:
    """``progress(iterable, total=)`` for a stage's ``progress`` argument: a bar over finished runs (off as
    :func:`bars_off` says)."""
    from tqdm import tqdm  # imported when a command runs: `stucco --help` stays fast

    off = bars_off(settings)
    return lambda it, total: tqdm(it, total=total, desc=desc, unit="run", disable=off)


def progress_lines(settings: Settings) -> Callable[[str], None] | None:
    """A function printing a progress line to stderr, or None with ``-q`` (plain lines, never ``\\r``)."""
    if settings.verbosity < 0:
        return None
    import click

    return lambda text: click.echo(text, err=True)
