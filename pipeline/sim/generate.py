"""Generated retrieval scenes that hold up in the simulator: each draw of :mod:`pipeline.scenes.generate` is
built and settled in pybullet, and redrawn (its next draw) if anything overlaps, moves while settling, or the
gripper starts touching something (docs/scene_generator.md).

The check builds the world exactly as ``stucco collect`` does (DIRECT client, the scene's own effects and
``settle_steps``), so a scene that passes starts its runs at rest.
"""
from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pybullet as p

from pipeline.scenes import Scene, scene_from_text
from pipeline.scenes.generate import DrawRejected, GeneratorSpec, Layout, sample_layout
from pipeline.scenes.generated_toml import layout_toml
from pipeline.sim.world import World

__all__ = ["GeneratedScene", "GenerationFailed", "settle_problem", "iter_generated", "generate_scenes",
           "MOVE_TOLERANCE_M", "TURN_TOLERANCE_RAD", "PENETRATION_TOLERANCE_M", "MAX_DRAWS"]

#: An object that moves more than this while settling was pushed by a neighbour (or toppled), metres / radians.
MOVE_TOLERANCE_M = 0.005
TURN_TOLERANCE_RAD = 0.05
#: Deeper contacts than this count as overlap, metres (resting contacts sit within about 0.1 mm).
PENETRATION_TOLERANCE_M = 0.001
#: The gripper must start at least this far from every body, metres.
START_CLEARANCE_M = 0.002
#: Draws tried per scene before giving up (the knobs are then too demanding for the area).
MAX_DRAWS = 1000


class GenerationFailed(ValueError):
    """No draw of a scene passed within :data:`MAX_DRAWS`; the message is one line naming the scene."""


@dataclass(frozen=True)
class GeneratedScene:
    """One scene that passed: its name, file text, layout, how many draws it took and the seconds spent."""

    name: str
    text: str
    layout: Layout
    draws: int
    seconds: float


def settle_problem(scene: Scene) -> str | None:
    """Why ``scene`` is unusable after settling, or None: overlap at spawn (objects, walls, gripper), an object
    that moved more than :data:`MOVE_TOLERANCE_M` / :data:`TURN_TOLERANCE_RAD` while settling, overlap after it,
    or a target no longer in its region."""
    with World(scene, effects=replace(scene.effects, settle_steps=0)) as world:
        c = world.client
        p.performCollisionDetection(physicsClientId=c)
        problem = _overlap(world, "at spawn") or _gripper_touch(world)
        if problem:
            return problem
        before = [_pose(b, c) for i, b in sorted(world.body_of.items()) if i < len(scene.objects)]
        world.settle(scene.effects.settle_steps)
        after = [_pose(b, c) for i, b in sorted(world.body_of.items()) if i < len(scene.objects)]
        for o, (pos0, q0), (pos1, q1) in zip(scene.objects, before, after):
            shift = math.dist(pos0, pos1)
            turn = 2.0 * math.acos(min(1.0, abs(sum(a * b for a, b in zip(q0, q1)))))
            if shift > MOVE_TOLERANCE_M or turn > TURN_TOLERANCE_RAD:
                return f"{o.name} moved {shift * 1000:.1f} mm, turned {turn:.3f} rad while settling"
        problem = _overlap(world, "after settling")
        if problem:
            return problem
        target = next(i for i, o in enumerate(scene.objects) if o.target)
        x, y, _ = world.object_poses()[target]
        (x0, y0), (x1, y1) = scene.target_region
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            return f"target at ({x:.3f}, {y:.3f}) m left its region after settling"
    return None


def _pose(body: int, client: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    return p.getBasePositionAndOrientation(body, physicsClientId=client)


def _overlap(world: World, when: str) -> str | None:
    """The first pair of scene bodies (objects, walls) that penetrate deeper than the tolerance."""
    names = world.scene.body_names
    n_objects = len(world.scene.objects)
    items = sorted(world.body_of.items())
    for k, (i, a) in enumerate(items):
        for j, b in items[k + 1:]:
            if i >= n_objects and j >= n_objects:  # two walls: static, may meet at corners
                continue
            pts = p.getClosestPoints(a, b, 0.0, physicsClientId=world.client)
            depth = -min((pt[8] for pt in pts), default=0.0)
            if depth > PENETRATION_TOLERANCE_M:
                return f"{names[i]} and {names[j]} overlap by {depth * 1000:.1f} mm {when}"
    return None


def _gripper_touch(world: World) -> str | None:
    names = world.scene.body_names
    for i, b in sorted(world.body_of.items()):
        if p.getClosestPoints(world.gripper.body, b, START_CLEARANCE_M, physicsClientId=world.client):
            return f"the gripper starts touching {names[i]}"
    return None


def iter_generated(n: int, seed: int, *, spec: GeneratorSpec, first: int = 0) -> Iterator[GeneratedScene]:
    """Scenes ``first`` .. ``first + n - 1`` of the batch of ``seed``, one at a time, each checked after settling.

    Scene ``i`` depends only on (seed, i): its draws are tried in order 0, 1, 2, ... and the first that passes both
    the layout rules and :func:`settle_problem` is kept.

    Raises
    ------
    ValueError
        ``n`` < 1, ``seed`` or ``first`` negative.
    GenerationFailed
        A scene found no passing draw in :data:`MAX_DRAWS`.
    """
    for what, v, low in (("n", n, 1), ("seed", seed, 0), ("first", first, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise ValueError(f"{what} {v!r}: expected a whole number >= {low}")
    for index in range(first, first + n):
        t0 = time.perf_counter()
        reasons: dict[str, int] = {}
        for draw in range(MAX_DRAWS):
            try:
                layout = sample_layout(seed, index, draw, spec)
            except DrawRejected as e:
                reasons[str(e).split(" (")[0]] = reasons.get(str(e).split(" (")[0], 0) + 1
                continue
            text = layout_toml(layout, spec)
            scene = scene_from_text(text, Path(f"{layout.name}.toml"))
            problem = settle_problem(scene)
            if problem is None:
                yield GeneratedScene(layout.name, text, layout, draw + 1, time.perf_counter() - t0)
                break
            reasons["failed the settling check"] = reasons.get("failed the settling check", 0) + 1
        else:
            common = ", ".join(f"{r} x{k}" for r, k in sorted(reasons.items(), key=lambda kv: -kv[1])[:3])
            raise GenerationFailed(f"scene {index} of seed {seed}: no draw passed in {MAX_DRAWS} ({common}); lower "
                                   "the hiddenness, the clutter density or the distractors, or enlarge the area")


def generate_scenes(n: int, seed: int, *, spec: GeneratorSpec | None = None, first: int = 0
                    ) -> list[tuple[str, str]]:
    """(name, TOML text) of scenes ``first`` .. ``first + n - 1`` of the batch of ``seed`` (see
    :func:`iter_generated`); ``spec`` defaults to :class:`GeneratorSpec`'s defaults."""
    spec = GeneratorSpec() if spec is None else spec
    return [(g.name, g.text) for g in iter_generated(n, seed, spec=spec, first=first)]
