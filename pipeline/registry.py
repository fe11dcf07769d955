"""The one list of extension points: every tracker, pose estimator and data-collection policy, by name.

A *spec* says what a component is called (``name``, the report's ``title``), how it is built (``factory``), what
parameters it takes (``params``, a frozen dataclass whose fields declare their constraints, see
:mod:`pipeline.constraints`) and what else it needs. Factories and parameter classes are given as import paths
(``"pipeline.track.soft:SoftTrackingParams"``) or as objects, and resolved on first use, so importing this module
imports no stage: ``stucco --help`` and the CLI's choices stay fast.

Every command, the evaluation, the studies, the report and the metadata writers take names from here
(:func:`tracker_names`, :func:`estimator_names`, :func:`policy_names`). A new component is one call of
:func:`register`, in this file for a built-in one or anywhere else (a plug-in, a test) for the rest; a name
registered later shows up in the CLI choices of any command run afterwards (docs/architecture.md).
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["TrackerSpec", "EstimatorSpec", "PolicySpec", "register", "registers", "unregister", "tracker",
           "estimator", "policy", "trackers", "estimators", "policies", "tracker_names", "baseline_names", "tune_grid",
           "estimator_names", "policy_names", "default_policy", "method_title", "resolve", "build_params", "choices",
           "side_path", "side_suffixes", "remove_side_files", "DEFAULT_ESTIMATOR"]

#: An object, or ``"package.module:attribute"`` resolved on first use.
Ref = str | Callable[..., Any] | type | None


def resolve(ref: Ref) -> Any:
    """The object an import path ``"module:attribute"`` names (imported now), or ``ref`` itself."""
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class TrackerSpec:
    """A contact tracker (paper §V-A): ``stucco track --method NAME``.

    Attributes
    ----------
    name, title : str
        CLI name and the report's row title.
    params : type or import path
        Frozen parameter dataclass (field defaults = the method's defaults).
    factory : callable or import path
        ``factory(params, robot, rng) -> ContactTracker`` (:class:`pipeline.track.base.ContactTracker`), with
        ``params`` an instance of :attr:`params`, ``robot`` the gripper grid and ``rng`` the run's Generator.
    tune : (parameter, values) or None
        What ``stucco study tune`` sweeps on the training set.
    segment_by : {"components", "tracker"}
        How ``stucco segment --by auto`` groups its points: Alg. 3's connected components, or the tracker's own
        labels.
    needs : tuple of str
        ``"numba"``: the tracker's kernels are compiled or loaded before any timed update
        (:func:`pipeline.track.stage.warm_up`).
    """

    name: str
    title: str
    params: Ref
    factory: Ref
    tune: tuple[str, tuple[float, ...]] | None = None
    segment_by: str = "tracker"
    needs: tuple[str, ...] = ()


@dataclass(frozen=True)
class EstimatorSpec:
    """A pose estimator of the retrieve stage (paper §V-C): ``stucco retrieve --estimator NAME``.

    Attributes
    ----------
    name, title : str
    factory : callable or import path
        ``factory(segments, info, sdf, rngs, params, own) -> Estimate`` (:mod:`pipeline.estimators.estimate`):
        the run's segments, its :class:`~pipeline.estimators.run_info.RunInfo`, the gripper grid, the run's three
        Generators (model points, ICP restarts, hypotheses), the shared
        :class:`~pipeline.estimators.params.RetrievalParams` and the estimator's own parameters (None without).
    params : type, import path or None
        The estimator's own parameter dataclass, recorded in the metadata under :attr:`meta_key`.
    meta_key : str or None
        Metadata key of the own parameters (default: :attr:`name`).
    needs : tuple of str
        ``"every_step"``: the estimator also reads the segments of every in-contact step (tracks written with
        ``stucco track --every-step``), passed as the keyword ``history`` (:func:`pipeline.retrieve.estimate`);
        ``stucco evaluate`` then tracks every step.
    """

    name: str
    title: str
    factory: Ref
    params: Ref = None
    meta_key: str | None = None
    needs: tuple[str, ...] = ()


@dataclass(frozen=True)
class PolicySpec:
    """How the gripper moves while collecting (``stucco collect --policy NAME``).

    Attributes
    ----------
    name, title : str
    factory : callable or import path
        ``factory(scene, policy_rng, noise_rng, max_actions, params) -> Policy``
        (:class:`pipeline.policies.Policy`: where the gripper starts, its next action, whether to keep the run).
    params : type, import path or None
        The policy's own parameter dataclass (None: the scene holds them).
    needs : tuple of (scene key, what it is)
        Scene keys the policy reads, e.g. ``("actions", "action sequence")``; a scene without one is refused
        with the key named.
    default_for : tuple of str
        Scene kinds (``"retrieval"``, ``"training"``) collected with this policy when none is given.
    retrieval : callable, import path or None
        How ``retrieve`` ends a run this policy collected: ``retrieval(info, method, root_seed, grasp,
        grasp_params) -> dict`` of the retrieval row's pose, errors, grasp and notes (the active protocol's own
        pose and grasp for the whole plausible set). None: the estimator's pose and the paper's grasp script.
    side_files : tuple of str
        Suffixes of the files a run collected with this policy keeps beside its run file (what must not go in the
        Parquet file, e.g. wall times: the same command writes the run byte for byte again); the run file
        ``R.parquet`` has the side file ``_R<suffix>`` (:func:`side_path`). ``evaluate --from-runs`` copies them
        with the run.
    save_side_files : callable, import path or None
        ``save_side_files(run_path, result)`` writes the side files of a run just collected, from
        :class:`pipeline.collect.CollectResult` ``result``; None: the policy has none.
    """

    name: str
    title: str
    factory: Ref
    params: Ref = None
    needs: tuple[tuple[str, str], ...] = ()
    default_for: tuple[str, ...] = ()
    retrieval: Ref = None
    side_files: tuple[str, ...] = ()
    save_side_files: Ref = None

    def side_paths(self, run_file: str | Path) -> tuple[Path, ...]:
        """The side files of run file ``run_file`` (:attr:`side_files`, in order; they may not exist)."""
        return tuple(side_path(run_file, suffix) for suffix in self.side_files)

    def missing(self, scene) -> tuple[str, str] | None:
        """The first (scene key, what it is) of :attr:`needs` that ``scene`` lacks, or None."""
        return next(((key, what) for key, what in self.needs if getattr(scene, key, None) is None), None)


def side_path(run_file: str | Path, suffix: str) -> Path:
    """The side file ``_<stem><suffix>`` beside ``run_file``: the leading ``_`` keeps it out of a Parquet
    dataset of the folder (pyarrow skips such names; a ``*.parquet`` glob never matches a side file)."""
    run_file = Path(run_file)
    return run_file.with_name(f"_{run_file.stem}{suffix}")


Spec = TrackerSpec | EstimatorSpec | PolicySpec
_KIND = {TrackerSpec: "tracker", EstimatorSpec: "estimator", PolicySpec: "policy"}
_REGISTRY: dict[str, dict[str, Spec]] = {"tracker": {}, "estimator": {}, "policy": {}}


def register(spec: Spec, *, replace: bool = False) -> Spec:
    """Add a component; ValueError if its name is taken (unless ``replace``). Order of registration is the order
    of the report and of ``all``. Returns ``spec``."""
    kind = _KIND[type(spec)]
    if not spec.name or "," in spec.name or spec.name == "all":
        raise ValueError(f"invalid {kind} name {spec.name!r}")
    if spec.name in _REGISTRY[kind] and not replace:
        raise ValueError(f"{kind} {spec.name!r} is already registered")
    for suffix in getattr(spec, "side_files", ()):
        # a side file must not look like a partition of the runs folder, nor leave it
        if not suffix.startswith(".") or suffix.endswith(".parquet") or "/" in suffix or "\\" in suffix:
            raise ValueError(f"policy {spec.name!r}: side file suffix {suffix!r} must start with '.', stay in the "
                             "run's folder and not end with '.parquet'")
    _REGISTRY[kind][spec.name] = spec
    return spec


def registers(spec_class: type, name: str, title: str, **fields: Any) -> Callable:
    """Decorator form of :func:`register` for a factory::

        @registers(EstimatorSpec, "mine", "My estimator")
        def my_estimator(segments, info, sdf, rngs, params, own): ...

    registers ``spec_class(name, title, factory=<the function>, **fields)`` and returns the function unchanged."""

    def decorate(factory: Callable) -> Callable:
        register(spec_class(name=name, title=title, factory=factory, **fields))
        return factory

    return decorate


def unregister(kind: str, name: str) -> None:
    """Remove a component (tests that register a toy one clean up with this)."""
    _REGISTRY[kind].pop(name, None)


def _get(kind: str, name: str) -> Any:
    try:
        return _REGISTRY[kind][name]
    except KeyError:
        raise ValueError(f"unknown {'method' if kind == 'tracker' else kind} {name!r}; expected one of "
                         f"{', '.join(_REGISTRY[kind])}") from None


def tracker(name: str) -> TrackerSpec:
    """The spec of tracker ``name``; ValueError (one line listing the known ones) otherwise."""
    return _get("tracker", name)


def estimator(name: str) -> EstimatorSpec:
    """The spec of pose estimator ``name``; ValueError otherwise."""
    return _get("estimator", name)


def policy(name: str) -> PolicySpec:
    """The spec of collection policy ``name``; ValueError otherwise."""
    return _get("policy", name)


def trackers() -> tuple[TrackerSpec, ...]:
    return tuple(_REGISTRY["tracker"].values())


def estimators() -> tuple[EstimatorSpec, ...]:
    return tuple(_REGISTRY["estimator"].values())


def policies() -> tuple[PolicySpec, ...]:
    return tuple(_REGISTRY["policy"].values())


def side_suffixes() -> tuple[str, ...]:
    """The side-file suffixes every registered policy declares, each once (a run file may come from any of them)."""
    return tuple(dict.fromkeys(s for spec in policies() for s in spec.side_files))


def remove_side_files(run_file: str | Path) -> None:
    """Remove every side file any registered policy could have written beside ``run_file`` (absent ones are
    fine): done before a run file is replaced, so that a side file never outlives its run."""
    for suffix in side_suffixes():
        side_path(run_file, suffix).unlink(missing_ok=True)


def tracker_names() -> tuple[str, ...]:
    """Every tracking method, in the order of the paper's Table II (ours first), then any registered later."""
    return tuple(_REGISTRY["tracker"])


def baseline_names() -> tuple[str, ...]:
    """The methods compared against ours (every tracker but the first): the accuracy sweep runs them at their
    defaults."""
    return tuple(_REGISTRY["tracker"])[1:]


def tune_grid() -> dict[str, tuple[str, tuple[float, ...]]]:
    """Method -> (parameter, values) that ``stucco study tune`` sweeps, for every tracker that declares one."""
    return {s.name: s.tune for s in _REGISTRY["tracker"].values() if s.tune is not None}


def estimator_names() -> tuple[str, ...]:
    """Every pose estimator, the default first."""
    return tuple(_REGISTRY["estimator"])


def policy_names() -> tuple[str, ...]:
    return tuple(_REGISTRY["policy"])


def default_policy(scene_kind: str) -> str:
    """The policy that collects scenes of ``scene_kind`` ("retrieval", "training") when none is named (the first
    registered when no policy declares the kind)."""
    return next((s.name for s in _REGISTRY["policy"].values() if scene_kind in s.default_for),
                next(iter(_REGISTRY["policy"])))


def method_title(name: str) -> str:
    """The report's title of a tracking method (the name itself for one not registered)."""
    spec = _REGISTRY["tracker"].get(name)
    return spec.title if spec is not None else name


def build_params(spec: Spec, values: Any = None) -> Any:
    """The parameter instance of ``spec`` from None (defaults), an instance, or a mapping of overrides (checked by
    :func:`pipeline.constraints.from_dict`: unknown names, wrong kinds, then the class's declared constraints).
    None when the spec takes no parameters and none are given."""
    cls = resolve(spec.params)
    if cls is None:
        if values:
            raise ValueError(f"{_KIND[type(spec)]} {spec.name!r} takes no parameters, got {', '.join(values)}")
        return None
    if values is None:
        return cls()
    if isinstance(values, cls):
        return values
    if not isinstance(values, dict):
        raise ValueError(f"params for {spec.name!r} must be a dict or {cls.__name__}, got {type(values).__name__}")
    from pipeline.constraints import Params, from_dict  # imported here: it loads numpy, which the registry avoids

    return cls.from_dict(values, spec.name) if issubclass(cls, Params) else from_dict(cls, values, spec.name)


def choices(kind: str) -> Any:
    """A ``click.Choice`` over the names of ``kind`` read when the command runs, so that a component registered
    after import (a plug-in, a test) is accepted."""
    import click  # imported here: only the CLI asks for choices, and importing the registry stays cheap

    class _Lazy(click.Choice):
        def __init__(self) -> None:
            super().__init__([])

        @property
        def choices(self):  # noqa: D401  (click reads this attribute when it converts and in --help)
            return list(_REGISTRY[kind])

        @choices.setter
        def choices(self, value) -> None:
            pass

    return _Lazy()


# ---------------------------------------------------------------------------------------------------------------
# the built-in components (paper §V-A trackers in Table II order; estimators, the default first; policies)
# ---------------------------------------------------------------------------------------------------------------
register(TrackerSpec("stucco", "ours (STUCCO)", "pipeline.track.soft:SoftTrackingParams",
                     "pipeline.track.soft:soft_tracker", tune=("length", (0.005, 0.01, 0.02, 0.04, 0.08)),
                     segment_by="components", needs=("numba",)))
register(TrackerSpec("birch", "BIRCH", "pipeline.track.cluster:BirchParams", "pipeline.track.cluster:birch_tracker",
                     tune=("threshold", (0.02, 0.04, 0.08, 0.12, 0.2))))
register(TrackerSpec("dbscan", "DBSCAN", "pipeline.track.cluster:DBSCANParams",
                     "pipeline.track.cluster:dbscan_tracker", tune=("eps", (0.02, 0.035, 0.05, 0.075, 0.1))))
register(TrackerSpec("kmeans", "k-means", "pipeline.track.cluster:KMeansParams",
                     "pipeline.track.cluster:kmeans_tracker", tune=("inertia_ratio", (0.1, 0.2, 0.3, 0.5, 0.8))))
register(TrackerSpec("gmphd", "GM-PHD", "pipeline.track.gmphd:GMPHDParams", "pipeline.track.cluster:gmphd_tracker",
                     tune=("detection", (0.3, 0.5, 0.7, 0.9, 0.99))))

register(EstimatorSpec("plausible", "the paper's segment choice, then the best pose of a plausible set fitted to "
                                    "the target's shape, the contacts and the gripper's free space",
                       "pipeline.estimators.estimate:plausible_estimator",
                       params="pipeline.estimators.plausible.params:PlausibleParams"))
register(EstimatorSpec("paper", "the paper's ICP procedure (§V-C) as the authors ran it: at every in-contact step, "
                                "warm-started, the grasp at the last in-contact step's estimate",
                       "pipeline.estimators.estimate:paper_estimator", needs=("every_step",)))
register(EstimatorSpec("pushtrack", "the paper's segment choice, then the target's pose tracked through its pushes by "
                                    "a particle filter (contacts at their own steps, free space, quasi-static pushing)",
                       "pipeline.estimators.pushtrack.estimator:pushtrack_estimator",
                       params="pipeline.estimators.pushtrack.filter:PushTrackParams"))

register(PolicySpec("scripted", "the scene's action sequence plus replay noise", "pipeline.policies:ScriptedPolicy",
                    needs=(("actions", "action sequence"),), default_for=("retrieval",)))
register(PolicySpec("greedy-walk", "a greedy random walk to a random goal (the training set, §V-B)",
                    "pipeline.policies:GreedyWalkPolicy", needs=(("walk", "[walk] table"),),
                    default_for=("training",)))
register(PolicySpec("scripted+probe", "the scripted actions, then probes until the target's pose is known, and a "
                                      "grasp for the whole plausible set (active retrieval)",
                    "pipeline.probe.mover:ScriptedProbePolicy", params="pipeline.probe.policy:ProbeParams",
                    needs=(("actions", "action sequence"),), retrieval="pipeline.probe.retrieval:active_row",
                    side_files=(".probe_s.json",), save_side_files="pipeline.probe.report:save_collect_times"))
register(PolicySpec("explore", "no action list: a guarded search of the scene's target region from the start, then "
                               "probes until the target's pose is known, and a grasp for the whole plausible set, "
                               "within one action budget",
                    "pipeline.probe.explore:ExplorePolicy", params="pipeline.probe.explore:ExploreParams",
                    retrieval="pipeline.probe.retrieval:active_row", side_files=(".probe_s.json",),
                    save_side_files="pipeline.probe.report:save_collect_times"))
register(PolicySpec("rummage", "the scene's action sequence played again and again from the scene's starting "
                               "state until a given number of actions end in contact (long runs for `bench scale "
                               "--contacts`)",
                    "pipeline.policies:RummagePolicy", params="pipeline.policies:RummageParams",
                    needs=(("actions", "action sequence"),)))

#: The pose estimator used when none is named (the first registered).
DEFAULT_ESTIMATOR: str = estimator_names()[0]
