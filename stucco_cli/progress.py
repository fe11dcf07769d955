"""The progress bar the commands hand to a stage: one tqdm bar per stage call, off with ``-q``."""
from __future__ import annotations

from collections.abc import Callable

from stucco_cli.common import Settings


def run_bar(settings: Settings, desc: str) -> Callable:
    """``progress(iterable, total=)`` for a stage's ``progress`` argument: a bar over finished runs."""
    from tqdm import tqdm  # imported when a command runs: `stucco --help` stays fast

    return lambda it, total: tqdm(it, total=total, desc=desc, unit="run", disable=settings.progress)
