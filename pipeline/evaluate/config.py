"""What an evaluation is made of: the grid's scenes and methods, :class:`EvalConfig` and :class:`Job`.

The configuration is stored in ``DIR/evaluation.json`` (:func:`check_config`) and an existing directory is only
resumed with the same one (docs/evaluation.md, "Resuming and skipping").
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline import registry
from pipeline.atomic import write_text
from pipeline.constraints import Params
from pipeline.estimators.params import MAX_COUNT
from pipeline.evaluate.migrate import MIGRATES_FROM, migrate
from pipeline.layout import CONFIG, LAYOUT_VERSION
from pipeline.safe_open import optional_file, read_text
from pipeline.scenes import Scene, SceneError, load_scene, scene_digest, scene_names
from pipeline.seeds import check_stream

__all__ = ["SCENES", "METHODS", "QUICK_SCENES", "QUICK_SEEDS", "EvalConfig", "Job", "parse_scenes",
           "parse_methods", "check_config", "scene_files", "config_lines"]

#: The paper's Table II tasks, in its order.
SCENES = ("FB", "BC", "IB", "TC")
#: STUCCO and the baselines, in the order of Table II (the methods registered when this module was imported;
#: :func:`parse_methods` reads :func:`pipeline.registry.tracker_names` when called, so later ones count too).
METHODS = registry.tracker_names()
#: `stucco evaluate --quick`: a couple of seeds of one scene.
QUICK_SCENES = ("FB",)
QUICK_SEEDS = (0, 1)


@dataclass(frozen=True)
class EvalConfig(Params):
    """What an evaluation directory is made with; stored in ``DIR/evaluation.json``, checked on resume.

    Attributes
    ----------
    root_seed : int
        Root of every job's SeedSequence (the CLI's ``--seed``).
    max_actions : int or None
        Cut every scripted run after this many actions (short test grids); None = the whole sequence.
    restarts : int
        ICP restarts per segment (30, the paper's).
    grasp : bool
        Simulate the grasp (grasp success is null without it).
    robot : str
        Gripper grid for tracking and retrieval.
    source : str or None
        Directory of stored run files replayed instead of simulating (``--from-runs``); None = simulate.
    estimators : tuple of str
        Pose estimators run on every job's segments (:func:`pipeline.registry.estimator_names`), each into its own
        ``estimator=`` partition; the report shows them side by side.
    scene_files : tuple of (name, path, sha256)
        Scenes given as files whose content is not the shipped scene of their name (:func:`scene_files`):
        collected from that file, checked against its digest; empty for shipped scenes (and then left out of
        ``evaluation.json``, which older folders lack).
    policy : str or None
        Collection policy of the retrieval scenes (:func:`pipeline.registry.policy_names`); None: the default for
        retrieval scenes (``scripted``, the paper's protocol). ``scripted+probe`` is the active protocol (probes,
        then the grasp for the plausible set; docs/active.md). Left out of
        ``evaluation.json`` when None, so folders made before it still resume.
    policy_params : tuple of (name, value)
        Overrides of the collection policy's own parameters (e.g. ``(("action_budget", 400),)`` for ``explore``),
        checked against the policy's parameter class; left out of ``evaluation.json`` when empty.
    estimator_stream : int
        The estimators' random stream (:class:`pipeline.retrieve.RetrieveConfig` ``stream``): 0, the default;
        k >= 1 reruns every stochastic estimator with other draws on the same segments (docs/evaluation.md,
        "The estimator's own randomness"). Left out of ``evaluation.json`` when 0.
    """

    root_seed: int = 0
    max_actions: int | None = None
    restarts: int = 30
    grasp: bool = True
    robot: str = "panda"
    source: str | None = None
    estimators: tuple[str, ...] = registry.estimator_names()
    scene_files: tuple[tuple[str, str, str], ...] = ()
    policy: str | None = None
    estimator_stream: int = 0
    policy_params: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "estimator_stream", check_stream(self.estimator_stream, "estimator_stream"))
        if self.policy is not None:
            registry.policy(self.policy)  # ValueError naming the registered policies
        object.__setattr__(self, "policy_params", tuple((str(k), tuple(v) if isinstance(v, list) else v)
                                                        for k, v in self.policy_params))
        if self.policy_params:  # ValueError naming the first unknown or bad parameter
            registry.build_params(registry.policy(self.collect_policy), dict(self.policy_params))
        object.__setattr__(self, "estimators", tuple(self.estimators))
        object.__setattr__(self, "scene_files", tuple(tuple(f) for f in self.scene_files))
        known = registry.estimator_names()
        bad = [e for e in self.estimators if e not in known]
        if not self.estimators or bad:
            raise ValueError(f"unknown estimator {bad[0] if bad else ''!r}; expected some of {', '.join(known)}")
        if len(set(self.estimators)) != len(self.estimators):  # each would count every run once more
            raise ValueError(f"estimators {', '.join(self.estimators)}: each may be given once")
        if self.max_actions is not None and self.max_actions < 1:
            raise ValueError(f"max_actions must be a positive integer, got {self.max_actions!r}")
        if not 2 <= self.restarts <= MAX_COUNT:
            raise ValueError(f"restarts must be in [2, {MAX_COUNT}], got {self.restarts!r}")
        super().__post_init__()

    def to_dict(self) -> dict[str, Any]:
        """The JSON form kept in ``DIR/evaluation.json`` (estimators as a list)."""
        out = super().to_dict()
        if not self.scene_files:
            del out["scene_files"]
        if self.policy is None:
            del out["policy"]
        if not self.estimator_stream:
            del out["estimator_stream"]
        if not self.policy_params:
            del out["policy_params"]
        return out

    @property
    def collect_policy(self) -> str:
        """The policy the retrieval scenes are collected with."""
        return self.policy or registry.default_policy("retrieval")

    def scene(self, name: str) -> Scene:
        """The scene ``name`` to collect: its file of ``scene_files`` (ValueError if it changed since the
        evaluation began), else the shipped scene."""
        for n, path, digest in self.scene_files:
            if n == name:
                scene = load_scene(path)
                if scene_digest(scene.source) != digest:
                    raise ValueError(f"{path}: scene file changed since this evaluation began (SHA-256 "
                                     f"{digest[:12]}…); use another --out")
                return scene
        return load_scene(name)


@dataclass(frozen=True, order=True)
class Job:
    """One cell of the grid: a run of ``scene`` with ``seed``, tracked by ``method``."""

    scene: str
    seed: int
    method: str

    def __str__(self) -> str:
        return f"{self.scene}/{self.seed}/{self.method}"


def _split(text: str) -> list[str]:
    return [p.strip() for p in str(text).split(",") if p.strip()]


def parse_scenes(text: str, files: bool = False) -> tuple[str, ...]:
    """``"FB,BC"`` or ``"all"`` -> scene names; ValueError (one line) for a scene that cannot be evaluated.

    A scene can be evaluated when it has a target (``kind = "retrieval"``; the collection policy may need more,
    e.g. the scripted ones an action sequence, checked when the evaluation starts). A scene file whose content is
    not the shipped scene of its name is accepted only with ``files`` (callers that pass :func:`scene_files` on, as
    ``stucco evaluate`` does): stages look scenes up by name.
    """
    return tuple(name for name, _, _ in _scenes(text, files))


def scene_files(text: str) -> tuple[tuple[str, str, str], ...]:
    """(name, absolute path, SHA-256 of the text) of the scene files of ``text`` whose content is not the shipped
    scene of their name: :attr:`EvalConfig.scene_files`."""
    return tuple((name, str(Path(given).resolve()), scene_digest(sc.source))
                 for name, given, sc in _scenes(text, True) if sc is not None and not _shipped(sc))


def _shipped(sc: Scene) -> bool:
    """Whether ``sc`` has the content of the shipped scene of its name."""
    return sc.name in scene_names() and load_scene(sc.name).source == sc.source


def _folder_files(given: str) -> list[str]:
    """A folder given as a scene: its ``*.toml`` files in name order (``stucco scenes generate``'s output); anything
    else as given."""
    folder = Path(given)
    if not folder.is_dir():
        return [given]
    found = sorted(str(f) for f in folder.glob("*.toml") if f.is_file())
    if not found:
        raise ValueError(f"{folder}: a folder with no scene file (*.toml) in it")
    return found


def _scenes(text: str, files: bool) -> list[tuple[str, str, Scene | None]]:
    """(name, as given, scene) of every distinct scene of ``text`` (no scene object for 'all')."""
    names = _split(text)
    if not names:
        raise ValueError("no scene given; expected a comma-separated list such as FB,BC,IB,TC or 'all'")
    if names == ["all"]:
        return [(n, n, None) for n in SCENES]
    names = [f for n in names for f in _folder_files(n)]
    out: dict[str, tuple[str, Scene]] = {}
    for n in names:
        try:
            sc = load_scene(n)
        except SceneError:
            raise ValueError(f"unknown scene {n!r}; expected some of {', '.join(scene_names())} "
                             f"(retrieval tasks: {', '.join(SCENES)})") from None
        if sc.target is None:
            raise ValueError(f"scene {n!r} is a training scene (no target); "
                             f"evaluate retrieval tasks: {', '.join(SCENES)}")
        if not files and not _shipped(sc):
            raise ValueError(f"{sc.path}: is not the shipped scene {sc.name!r}; this command runs shipped scenes "
                             "(stucco evaluate --scenes takes scene files)")
        if sc.name in out and out[sc.name][1].source != sc.source:
            raise ValueError(f"{n} and {out[sc.name][0]} are two different scenes named {sc.name!r}")
        out.setdefault(sc.name, (n, sc))
    return [(name, given, sc) for name, (given, sc) in out.items()]


def parse_methods(text: str) -> tuple[str, ...]:
    """``"stucco,kmeans"`` or ``"all"`` -> method names in Table II order; ValueError for an unknown one."""
    names = _split(text)
    methods = registry.tracker_names()
    if not names:
        raise ValueError(f"no method given; expected some of {', '.join(methods)} or 'all'")
    if names == ["all"]:
        return methods
    bad = [n for n in names if n not in methods]
    if bad:
        raise ValueError(f"unknown method {bad[0]!r}; expected some of {', '.join(methods)} or 'all'")
    return tuple(m for m in methods if m in names)


def check_config(out: Path, cfg: EvalConfig) -> None:
    """Write ``cfg`` to ``out/evaluation.json`` (atomically, creating ``out``), or check that an existing one
    matches it; ValueError (one line) naming the first differing field otherwise. A matching folder of the
    previous layout is migrated in place (:func:`pipeline.evaluate.migrate.migrate`), then its
    ``evaluation.json`` rewritten; an older layout is refused."""
    path = out / CONFIG
    want = dict(cfg.to_dict(), layout=LAYOUT_VERSION)
    if optional_file(path, CONFIG) is None:
        # Results without the record of what made them: stamping this call's settings over them would claim
        # settings they were not made with (a deleted evaluation.json, then another --restarts).
        found = sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) if out.is_dir() else []
        if found:
            raise ValueError(f"{path}: missing, but {out} holds {', '.join(found[:3])}"
                             f"{', …' if len(found) > 3 else ''}; what made them is unknown: restore {CONFIG} or "
                             "use another --out (or delete the folder)")
    else:
        try:
            have = json.loads(read_text(path, CONFIG))
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: unreadable ({e}); remove it or use another --out") from None
        if not isinstance(have, dict):
            raise ValueError(f"{path}: holds {type(have).__name__} {json.dumps(have)[:40]}, not the JSON object "
                             "stucco evaluate writes; remove it or use another --out")
        # A folder of the previous layout holds the same tables: migrated in place once it matches otherwise.
        older = have.get("layout") == MIGRATES_FROM and MIGRATES_FROM + 1 == LAYOUT_VERSION
        if older:
            have = dict(have, layout=LAYOUT_VERSION)
        diff = sorted(k for k in set(want) | set(have) if have.get(k) != want.get(k))
        if "layout" in diff:
            raise ValueError(f"{out}: was made with another layout of the output folder (layout "
                             f"{have.get('layout', 1)!r}, this version writes {LAYOUT_VERSION}); use another --out "
                             f"(or delete {out})")
        if diff:
            k = diff[0]
            # (a field left out of evaluation.json holds its default)
            default = getattr(EvalConfig(), k, None)
            raise ValueError(f"{out}: was made with {k}={have.get(k, default)!r}, this evaluation asks for "
                             f"{k}={want.get(k, default)!r}; use another --out (or delete {out})")
        if not older:
            return
        migrate(out)
    write_text(path, json.dumps(want, indent=1, sort_keys=True) + "\n")


def config_lines(cfg: EvalConfig) -> list[str]:
    """What the report says of a configuration that changes its numbers beyond the grid itself: the estimators'
    random stream when it is not the default (docs/evaluation.md, "The estimator's own randomness")."""
    if cfg.estimator_stream:
        return [f"pose estimators run with random stream {cfg.estimator_stream} (--estimator-stream; the "
                "default and every published table: 0); runs of the active protocol keep their policy's pose and "
                "grasp"]
    return []
