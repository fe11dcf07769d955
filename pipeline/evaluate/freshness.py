"""Which stages of a job are out of date: ``make`` on recorded SHA-256 digests instead of file times.

An output is up to date when it exists and the SHA-256 of every input recorded in its metadata
(``stucco.inputs``, written by :func:`pipeline.schema.write_table`) matches the current input file. A job runs its
first out-of-date stage and everything after it; a job whose scores are up to date is skipped. Deleting a file,
or rewriting it with other content, reruns its stage and every later one; a byte-identical rewrite (a CLI rerun of
a deterministic stage) reruns nothing (docs/evaluation.md, "Resuming and skipping").
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

from pipeline import schema
from pipeline.estimators.estimate import needs_every_step
from pipeline.evaluate.config import Job
from pipeline.layout import STAGES, job_paths, partition
from pipeline.registry import DEFAULT_ESTIMATOR

__all__ = ["Digests", "up_to_date", "stale_stages", "run_stale", "figure_stale"]


class Digests:
    """SHA-256 (hex) of files, each computed once per check; None for a missing file."""

    def __init__(self) -> None:
        self._d: dict[Path, str] = {}

    def __call__(self, path: Path) -> str | None:
        if path not in self._d:
            if not path.is_file():
                return None
            self._d[path] = schema.file_digest(path)
        return self._d[path]


def up_to_date(path: Path, inputs: dict[str, Path], digest: Digests) -> bool:
    """``path`` exists and records exactly the current digest of each of ``inputs`` (role -> file)."""
    if not path.is_file():
        return False
    try:
        recorded = schema.read_metadata(path).get("inputs") or {}
    except schema.SchemaError:
        return False
    for role, src in inputs.items():
        d = digest(src)
        if d is None or (recorded.get(role) or {}).get("sha256") != d:
            return False
    return True


def _stage_inputs(p: dict[str, Path]) -> dict[str, tuple[tuple[str, dict[str, Path]], ...]]:
    """Stage -> ((output kind, {role: input file}), ...) as the stages record them."""
    return {
        "collect": (("runs", {}),),
        "isolate": (("contacts", {p["runs"].stem: p["runs"]}),),  # isolate names a run file's role by its stem
        "track": (("diagnostics", {"contacts": p["contacts"]}), ("tracks", {"contacts": p["contacts"]})),
        "segment": (("segments", {"tracks": p["tracks"]}),),
        "retrieve": (("candidates", {"segments": p["segments"]}), ("retrieval", {"segments": p["segments"]})),
        "score": (("scores", {"retrieval": p["retrieval"], "segments": p["segments"],
                              "diagnostics": p["diagnostics"]}),),
    }


def stale_stages(out: str | Path, job: Job, estimators: Sequence[str] = (DEFAULT_ESTIMATOR,)) -> tuple[str, ...]:
    """The stages of ``job`` to (re)run: the first whose outputs (for any of ``estimators``) are missing or out
    of date, and all after it.

    Empty when the job is finished (its scores are up to date with the whole chain, for every estimator). Tracks
    without the estimate after every step are out of date when one of ``estimators`` needs it.
    """
    digest = Digests()
    first = len(STAGES)
    tracks = partition(Path(out), "tracks", job.scene, job.seed, job.method)
    if needs_every_step(estimators) and tracks.is_file() and not _every_step(tracks):
        # Tracks of a folder made before an estimator read every in-contact step: track again (the final estimate is
        # the same bits, docs/retrieval.md "Online, as the authors ran it"), and everything after.
        first = STAGES.index("track")
    for est in estimators:
        p = job_paths(Path(out), job, est)
        for i, (stage, outputs) in enumerate(_stage_inputs(p).items()):
            if i >= first:
                break
            if not all(up_to_date(p[kind], inputs, digest) for kind, inputs in outputs):
                first = i
                break
    return STAGES[first:]


def _every_step(path: Path) -> bool:
    """The tracks file holds the estimate after every step (its metadata ``every_step``)."""
    try:
        return bool((schema.read_metadata(path).get("params") or {}).get("every_step"))
    except schema.SchemaError:
        return False


def run_stale(out: Path, scene: str, seed: int) -> bool:
    """The (scene, seed)'s collected run is missing, or its contacts are not up to date with it."""
    runs = partition(out, "runs", scene, seed)
    return not runs.is_file() or not up_to_date(partition(out, "contacts", scene, seed), {runs.stem: runs},
                                                Digests())


def figure_stale(png: Path, inputs: Iterable[Path]) -> bool:
    """A figure is redrawn when missing or older than any of its (existing) inputs (file times: a PNG records
    no input digests)."""
    if not png.is_file():
        return True
    t = png.stat().st_mtime_ns
    return any(p.is_file() and p.stat().st_mtime_ns > t for p in inputs)
