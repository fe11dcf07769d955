"""Scene files -> typed, frozen scene objects (no pybullet here).

A scene is one TOML file under ``data/scenes/`` (docs/simulation.md, "Scenes are data"); the files are the
built-in scenes (the retrieval tasks FB, BC, IB, TC and the training scenes SELECT1-4), so no scene is defined in
code. One role per module:

* :mod:`~pipeline.scenes.types`: the frozen dataclasses (:class:`Scene`, :class:`ObjectSpec`, :class:`WallSpec`,
  :class:`Plane`, :class:`Effects`, :class:`Sensors`, :class:`Hardware`, :class:`WalkSpec`) and :class:`SceneError`;
* :mod:`~pipeline.scenes.sensing`: the ``[sensors]``, ``[detection]`` and ``[methods]`` tables;
* :mod:`~pipeline.scenes.parse`: :func:`parse_scene`, a decoded TOML document validated into a :class:`Scene`;
* :mod:`~pipeline.scenes.files`: :data:`SCENE_DIR`, finding a scene by name or path, :func:`load_scene`,
  :func:`load_all`, and :func:`scene_hash` for seeding;
* :mod:`~pipeline.scenes.generate` (knobs and one random draw), :mod:`~pipeline.scenes.catalogue` (the tasks'
  objects and walls), :mod:`~pipeline.scenes.footprint` (outlines on the plane), :mod:`~pipeline.scenes.coverage`
  (a rummage from a region and a start) and :mod:`~pipeline.scenes.generated_toml` (a draw's file): generated
  retrieval scenes, checked after settling in :mod:`pipeline.sim.generate` (docs/scene_generator.md).

Every problem is a :class:`SceneError` whose one-line message names the file and the offending key.
"""
from pipeline.scenes.files import (
    SCENE_DIR,
    load_all,
    load_scene,
    scene_digest,
    scene_from_text,
    scene_hash,
    scene_names,
    scene_path,
)
from pipeline.scenes.parse import parse_scene
from pipeline.scenes.types import (
    DEFAULT_ACTION_SCALE,
    WORKSPACE_M,
    Effects,
    Hardware,
    ObjectSpec,
    Plane,
    Scene,
    SceneError,
    Sensors,
    WalkSpec,
    WallSpec,
    declared_region,
)

__all__ = [
    "SCENE_DIR",
    "SceneError",
    "Plane",
    "ObjectSpec",
    "WallSpec",
    "Effects",
    "Sensors",
    "Hardware",
    "WalkSpec",
    "Scene",
    "scene_names",
    "scene_path",
    "load_scene",
    "load_all",
    "scene_hash",
    "scene_from_text",
    "scene_digest",
    "parse_scene",
    "DEFAULT_ACTION_SCALE",
    "WORKSPACE_M",
    "declared_region",
]
