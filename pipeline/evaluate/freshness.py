"""Which stages of a job are out of date: ``make`` on recorded SHA-256 digests instead of file times.

An output is up to date when it exists and the SHA-256 of every input recorded in its metadata
(``stucco.inputs``, written by :func:`pipeline.schema.write_table`) matches the current input file. A job runs its
first out-of-date stage and everything after it; a job whose scores are up to date is skipped. Deleting a file,
or rewriting it with other content, reruns its stage and every later one; a byte-identical rewrite (a CLI rerun of
a deterministic stage) reruns nothing (docs/evaluation.md, "Resuming and skipping").

What each stage records is declared once, in :data:`pipeline.layout.STAGE_SPECS`. The driver checks every job with
one :class:`Digests`, so each file is hashed at most once per evaluation call (the shared contacts of a seed once
for all its methods), and hands the stale stages on to the job (:func:`pipeline.evaluate.run_job`).
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

from pipeline import registry, schema
from pipeline.collect import output_path
from pipeline.constraints import plain
from pipeline.estimators.estimate import needs_every_step
from pipeline.evaluate.config import EvalConfig, Job
from pipeline.layout import STAGE_SPECS, STAGES, JobPaths, job_paths, run_paths, stage_spec
from pipeline.registry import DEFAULT_ESTIMATOR
from pipeline.safe_open import optional_file
from pipeline.scenes import scene_digest
from pipeline.seeds import check_root_seed

__all__ = ["file_digest", "Digests", "up_to_date", "stale_stages", "job_stale_stages", "shared_stale_stages",
           "check_run_settings", "figure_stale"]

def file_digest(path: Path) -> str:
    """SHA-256 (hex) of a file's bytes (:func:`pipeline.schema.file_digest`): every digest the freshness check
    takes goes through this function (the stages' own checks inside their ``<stage>_file`` functions do not)."""
    return schema.file_digest(path)


class Digests:
    """SHA-256 (hex) of files, each computed once for the life of this object; None for a missing file.

    Share one between checks made while the files stay unchanged (the driver's check of every job, after the
    runs are collected and isolated); a file rewritten after its digest was taken needs a new object.
    """

    def __init__(self) -> None:
        self._d: dict[Path, str] = {}

    def __call__(self, path: Path) -> str | None:
        path = Path(path)
        if path not in self._d:
            if optional_file(path) is None:
                return None
            self._d[path] = file_digest(path)
        return self._d[path]

    def forget(self, path: Path) -> None:
        """Drop the digest of ``path`` (a file rewritten since it was taken: a stored run copied again)."""
        self._d.pop(Path(path), None)


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


def job_stale_stages(paths: JobPaths, digest: Digests) -> tuple[str, ...]:
    """The stages of the job of ``paths`` to (re)run: the first whose outputs (for any of ``paths.estimators``)
    are missing or out of date, and all after it; empty when the job is finished.

    Tracks without the estimate after every step are out of date when one of the estimators needs it.
    """
    first = len(STAGES)
    tracks = paths["tracks"]
    if needs_every_step(paths.estimators) and tracks.is_file() and not _every_step(tracks):
        # Tracks of a folder made before an estimator read every in-contact step: track again (the final estimate is
        # the same bits, docs/estimators.md "Online, as the authors ran it"), and everything after.
        first = STAGES.index("track")
    for i, spec in enumerate(STAGE_SPECS[:first]):
        ests = paths.estimators if spec.per_estimator else paths.estimators[:1]
        if not all(up_to_date(out, paths.inputs(spec, est), digest)
                   for est in ests for out in paths.outputs(spec, est).values()):
            first = i
            break
    return STAGES[first:]


def stale_stages(out: str | Path, job: Job, estimators: Sequence[str] = (DEFAULT_ESTIMATOR,),
                 digest: Digests | None = None) -> tuple[str, ...]:
    """:func:`job_stale_stages` of ``job`` under ``out`` (its paths made here; a new :class:`Digests` unless
    given)."""
    return job_stale_stages(job_paths(out, job, estimators), Digests() if digest is None else digest)


def _every_step(path: Path) -> bool:
    """The tracks file holds the estimate after every step (its metadata ``every_step``)."""
    try:
        return bool((schema.read_metadata(path).get("params") or {}).get("every_step"))
    except schema.SchemaError:
        return False


def shared_stale_stages(out: Path, scene: str, seed: int, digest: Digests, source: Path | None = None,
                        root_seed: int | None = None, cfg: EvalConfig | None = None) -> tuple[str, ...]:
    """The stages of a (scene, seed) shared by its methods to (re)run: ``("collect", "isolate")`` when the run
    file is missing, or differs from the stored run ``source`` it was copied from (``--from-runs``: the stored
    run was collected again since), ``("isolate",)`` when the contacts are not up to date with it, else ``()``.

    A run file that is not the run of ``scene`` and ``seed`` (a run of another seed placed there), was collected
    with another root seed than ``root_seed``, or (collected here, ``cfg`` given without ``source``) not the way
    ``cfg`` collects it (:func:`check_run_settings`), is refused (ValueError naming it): its results would be
    reported as this seed's."""
    paths = run_paths(out, scene, seed)
    run = paths["runs"]
    if optional_file(run, "the run file") is None:
        return "collect", "isolate"
    check_run_identity(run, scene, seed, root_seed)
    if cfg is not None and source is None:
        check_run_settings(run, cfg.scene(scene), cfg.collect_policy, cfg.max_actions, dict(cfg.policy_params) or None)
    if source is not None and digest(run) != digest(output_path(source, scene, seed)):
        return "collect", "isolate"
    isolate = stage_spec("isolate")
    fresh = all(up_to_date(p, paths.inputs(isolate), digest) for p in paths.outputs(isolate).values())
    return () if fresh else (isolate.name,)


def check_run_identity(path: Path, scene: str, seed: int, root_seed: int | None, folder: str = "--out") -> None:
    """ValueError (one line naming ``path``) unless the run file holds the run of ``scene`` and ``seed``, collected
    with ``root_seed`` (None: any); its rows agree with its metadata (:func:`pipeline.schema.read_run`). ``folder``
    is the option the error tells the user to change."""
    meta = schema.read_metadata(path)
    params = meta.get("params") or {}
    have = (params.get("scene"), params.get("run_seed"))
    if have != (scene, seed):
        raise ValueError(f"{path}: holds the run {have[0]}/{have[1]}, not {scene}/{seed}; a run file stands for "
                         "the scene and seed of its name (remove it to collect the right one)")
    if root_seed is not None:
        check_root_seed(path, meta, root_seed, ", this evaluation's is {root}; use another " + folder)


def check_run_settings(path: Path, scene, policy: str | None, max_actions: int | None, policy_params,
                       ignore: tuple[str, ...] = ()) -> None:
    """ValueError (one line naming ``path`` and the setting) unless the run file was collected as
    :func:`pipeline.collect.collect_file` collects ``scene`` (a :class:`pipeline.scenes.Scene`) with ``policy``
    (None: the scene's default), ``max_actions`` and ``policy_params`` (the policy's overrides): the scene file's
    digest (when recorded), its effects, the policy, the action limit and the policy's parameters as recorded
    (but those named in ``ignore``)."""
    params = schema.read_metadata(path).get("params") or {}
    policy = policy or registry.default_policy(scene.kind)
    spec = registry.policy(policy)
    own = registry.build_params(spec, policy_params)
    drop = lambda d: None if d is None else {k: v for k, v in d.items() if k not in ignore}  # noqa: E731
    expected = {"policy": policy, "max_actions": max_actions, "effects": scene.effects.as_dict(),
                "scene_sha256": scene_digest(scene.source),
                "policy parameters": None if own is None else drop(own.to_dict())}
    # (the probing policies record their parameters with their log, the others under policy_params)
    own_recorded = (params.get("probe") or {}).get("params") or params.get("policy_params")
    recorded = {**{k: params.get(k) for k in ("policy", "max_actions", "effects", "scene_sha256")},
                "policy parameters": drop(own_recorded) if own is not None else None}
    for key, want in expected.items():
        if key == "scene_sha256" and recorded[key] is None:
            continue  # a run file written before runs carried their scene
        if plain(recorded[key]) != plain(want):  # (JSON kept tuples as lists)
            raise ValueError(f"{path}: collected with {key} {_short(recorded[key])}, not {_short(want)} as asked "
                             "here; remove it to collect it again, or use another folder")


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def figure_stale(png: Path, inputs: Iterable[Path]) -> bool:
    """A figure is redrawn when missing or older than any of its (existing) inputs (file times: a PNG records
    no input digests)."""
    if not png.is_file():
        return True
    t = png.stat().st_mtime_ns
    return any(p.is_file() and p.stat().st_mtime_ns > t for p in inputs)
