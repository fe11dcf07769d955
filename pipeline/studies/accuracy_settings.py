"""The settings of the accuracy sweep (``stucco bench accuracy``): one method with its knobs per setting."""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pipeline import registry

__all__ = ["Setting", "accuracy_settings"]


@dataclass(frozen=True)
class Setting:
    """One point of the accuracy sweep: a method with its tracker parameters, ICP restarts, robot grid and pose
    estimator (with the plausible estimator's hypotheses and free-space lattice spacing in metres, or another
    estimator's own parameter overrides ``estimator_params``, e.g. the pushtrack estimator's particles).

    ``knob`` names what the setting varies and ``value`` its value (NaN for a method or estimator choice).
    """

    name: str
    method: str
    knob: str
    value: float
    params: tuple[tuple[str, Any], ...] = ()
    restarts: int = 30
    robot: str = "panda"
    estimator: str = registry.DEFAULT_ESTIMATOR
    hypotheses: int = 32
    free_resolution: float = 0.005
    estimator_params: tuple[tuple[str, Any], ...] = ()


def accuracy_settings(n_list: Sequence[int] = (10, 30, 100, 300, 1000), restarts: Sequence[int] = (5, 10, 30),
                      sdf_mm: Sequence[float] = (1, 2, 4), hypotheses: Sequence[int] = (16, 32, 64, 128),
                      free_mm: Sequence[float] = (2.5, 5, 10), paper_estimator: bool = True,
                      baselines: Sequence[str] | None = None,
                      pushtrack: Sequence[tuple[str, Sequence[float]]] = (
                          ("n_particles", (128, 256, 512, 1024)), ("n_refine", (0, 32, 128)),
                          ("substeps", (1, 4, 8)), ("starts", (1, 6)), ("islands", (1, 4)),
                          ("motion", ("tip", "push", "sweep")), ("select", ("held_mean", "grasp")))) -> list[Setting]:
    """The sweep: STUCCO's N (other knobs at their defaults), then restarts and SDF resolution (N = 100, Table I), the
    plausible estimator's hypotheses and free-space lattice spacing, the other estimators (the paper's), the pushtrack
    estimator's knobs ``pushtrack`` ((parameter, values) pairs of
    :class:`~pipeline.estimators.pushtrack.params.PushTrackParams`: particles, refined particles, push integration
    steps, the contacts its filter may start from, the independent filters it pools, the pushing model, the choice of
    the estimate among the refined particles; the default values run as "stucco pushtrack estimator"), then the
    baselines at their defaults (None: :func:`pipeline.registry.baseline_names`). The default STUCCO setting appears
    once."""
    out: list[Setting] = []
    seen: set[tuple] = set()

    def add(s: Setting) -> None:
        key = (s.method, s.params, s.restarts, s.robot, s.estimator, s.hypotheses, s.free_resolution,
               s.estimator_params)
        if key not in seen:
            seen.add(key)
            out.append(s)

    for n in n_list:
        add(Setting(f"stucco N={n}", "stucco", "n_particles", n, (("n_particles", int(n)),) if n != 100 else ()))
    for r in restarts:
        add(Setting(f"stucco restarts={r}", "stucco", "restarts", r, (), restarts=int(r)))
    for mm in sdf_mm:
        spec = "panda" if float(mm) == 1.0 else f"panda:{float(mm) / 1000:g}"
        add(Setting(f"stucco sdf={mm:g}mm", "stucco", "sdf_mm", float(mm), (), robot=spec))
    for h in hypotheses:
        add(Setting(f"stucco hypotheses={h}", "stucco", "hypotheses", h, (), hypotheses=int(h)))
    for mm in free_mm:
        add(Setting(f"stucco free={mm:g}mm", "stucco", "free_mm", float(mm), (), free_resolution=float(mm) / 1000))
    if paper_estimator:
        for e in registry.estimator_names()[1:]:  # the paper's, and any other registered
            add(Setting(f"stucco {e} estimator", "stucco", "estimator", math.nan, (), estimator=e))
    if "pushtrack" in registry.estimator_names():
        defaults = registry.build_params(registry.estimator("pushtrack"))
        for knob, values in pushtrack:
            for v in values:
                v = type(getattr(defaults, knob))(v)
                own = () if v == getattr(defaults, knob) else ((knob, v),)
                text = v if isinstance(v, str) else f"{v:g}"  # a choice (select) has no numeric value
                add(Setting(f"stucco pushtrack {knob}={text}" if own else "stucco pushtrack estimator", "stucco",
                            f"pushtrack_{knob}", math.nan if isinstance(v, str) else float(v), (),
                            estimator="pushtrack", estimator_params=own))
    for b in (registry.baseline_names() if baselines is None else baselines):
        add(Setting(b, b, "method", math.nan))
    return out
