"""What each simulation effect costs: time one scripted run with all effects on, then with each one off.

Used by ``stucco sim-bench`` and for the figures in docs/simulation.md. Wall-clock figures depend on the
machine and its load; compare variants measured together.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from pipeline.scenes import Scene
from pipeline.sim.effects import action_noise
from pipeline.sim.world import World

__all__ = ["VARIANTS", "time_run", "effect_costs"]

#: (variant name, effect changes, World keyword arguments).
VARIANTS: tuple[tuple[str, dict[str, Any], dict[str, Any]], ...] = (
    ("all effects", {}, {}),
    ("no replay noise", {"noise_mm": 0.0}, {}),
    ("static objects", {"movable": ()}, {}),
    ("no friction overrides", {"friction": False}, {}),
    ("no settling", {"settle_steps": 0}, {}),
    ("no wrench", {"wrench": False}, {}),
    ("no contact truth", {"contact_truth": False}, {}),
    ("no wrench, no truth", {"wrench": False, "contact_truth": False}, {}),
    ("no walls", {"walls": False}, {}),
    ("multibody objects", {}, {"maximal_coordinates": False}),
    ("no sensors", {}, {"sensors": False}),  # only for a scene with [sensors]
)


def time_run(scene: Scene, n_actions: int | None = None, sensors: bool = True, **world_kw: Any) -> dict[str, float]:
    """Seconds spent building the world, settling, and executing the scripted actions (seed-0 noise), the scene's
    ``[sensors]`` simulated unless ``sensors`` is off."""
    eff = scene.effects
    seq = np.asarray(scene.actions, dtype=np.float64)[:n_actions]
    u = np.clip(seq + action_noise(np.random.default_rng(0), len(seq), eff.noise_mm, scene.action_scale), -1, 1)
    t0 = time.perf_counter()
    world = World(scene.with_effects(settle_steps=0), sensor_rng=np.random.default_rng(0) if sensors else None,
                  **world_kw)
    t1 = time.perf_counter()
    try:
        world.settle(eff.settle_steps)
        t2 = time.perf_counter()
        for ux, uy in u:
            world.act(ux * scene.action_scale, uy * scene.action_scale)
        t3 = time.perf_counter()
    finally:
        world.close()
    return {"build_s": t1 - t0, "settle_s": t2 - t1, "actions_s": t3 - t2, "total_s": t3 - t0}


def effect_costs(scene: Scene, n_actions: int | None = None, repeat: int = 3) -> list[dict[str, Any]]:
    """Time every variant of :data:`VARIANTS` (minimum over ``repeat`` interleaved rounds).

    Returns
    -------
    list of dict
        ``variant``, ``build_s``, ``settle_s``, ``actions_s``, ``total_s`` and ``delta_s`` (total minus the
        all-effects total: the negative of what the switched-off effect costs).
    """
    if scene.actions is None:
        raise ValueError(f"{scene.path}: key 'actions': sim-bench needs a scene with a scripted sequence")
    best: dict[str, dict[str, float]] = {}
    variants = [v for v in VARIANTS if v[0] != "no sensors" or scene.sensors.any]
    for _ in range(repeat):
        for name, changes, kw in variants:
            t = time_run(scene.with_effects(**changes), n_actions, **kw)
            if name not in best or t["total_s"] < best[name]["total_s"]:
                best[name] = t
    base = best["all effects"]["total_s"]
    return [{"variant": name, **best[name], "delta_s": best[name]["total_s"] - base} for name, _, _ in variants]
