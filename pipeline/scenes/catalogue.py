"""The YCB primitives and walls of the shipped retrieval tasks, as the scene generator draws them.

Sizes, shape and centre-of-mass offsets, spinning and rolling friction are copied from data/scenes/{FB,BC,IB,TC}.toml
(docs/simulation.md, "Scenes are data": primitives at the effective sizes of the YCB collision hulls);
tests/test_scene_generator.py checks that they still match those files. Masses and lateral friction are drawn
within the ranges the tasks use (:data:`TARGET_MASS_KG`, :data:`DISTRACTOR_MASS_KG`, :data:`LATERAL_FRICTION`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pipeline.scenes.types import WallSpec

__all__ = ["Model", "MODELS", "MODEL_BY_KEY", "TARGET_KEYS", "TARGET_MASS_KG", "DISTRACTOR_MASS_KG",
           "LATERAL_FRICTION", "PLANE_LATERAL_FRICTION", "PLANE_SPINNING_FRICTION", "TASK_WALLS"]


@dataclass(frozen=True)
class Model:
    """One YCB object as a primitive (the fields of :class:`pipeline.scenes.ObjectSpec` that do not vary).

    Attributes
    ----------
    key : str
        Object name in generated scenes (the tasks' name; a repeat gets ``_2``, ``_3``).
    model : str
        What the primitive stands for, as the task files say.
    shape : {"box", "cylinder"}
    size : tuple of float, metres
        Box: full extents (x, y, z); cylinder: (radius, height).
    shape_offset : (float, float), metres
    shape_yaw : float, radians
    com_offset : (float, float, float), metres
    com_yaw : float, radians
    spinning_friction, rolling_friction : float or None
    """

    key: str
    model: str
    shape: str
    size: tuple[float, ...]
    shape_offset: tuple[float, float]
    shape_yaw: float
    com_offset: tuple[float, float, float]
    com_yaw: float
    spinning_friction: float | None
    rolling_friction: float | None


MODELS: tuple[Model, ...] = (
    Model("cracker_box", "YcbCrackerBox x1.0", "box", (0.0616, 0.1575, 0.207), (0.0275, -0.0108), 0.0,
          (0.03, -0.01, -0.02), 0.0, None, None),
    Model("tomato_can", "YcbTomatoSoupCan x1.2", "cylinder", (0.039, 0.122), (0.0055, 0.0094), 0.0,
          (0.0, 0.0, -0.024), 0.0, 0.001, 0.001),
    Model("tomato_can_large", "YcbTomatoSoupCan x2.0", "cylinder", (0.065, 0.204), (0.0092, 0.0157), 0.0,
          (0.0, 0.0, -0.04), 0.0, 0.001, 0.001),
    Model("mustard", "YcbMustardBottle x1.0 (rough: min-area rectangle of the slice at z = 0.1)", "box",
          (0.0505, 0.0897, 0.19), (0.0085, 0.0051), 0.0, (0.005, 0.005, -0.015), 0.1, 0.001, 0.001),
    Model("master_chef_can", "YcbMasterChefCan x0.7 (URDF) x2.0", "cylinder", (0.0695, 0.197), (-0.0109, 0.0203),
          0.0, (-0.007, 0.0182, 0.0), 0.0, 0.001, 0.001),
    Model("potted_meat_can", "YcbPottedMeatCan x1.5 (rounded box as a box)", "box", (0.152, 0.082, 0.126),
          (0.0014, 0.0181), -0.6, (0.0, 0.018, -0.015), -0.5, None, 0.0),
)
MODEL_BY_KEY = {m.key: m for m in MODELS}
#: The targets of the tasks by kind: the cracker box (FB, BC, IB) and the small tomato can (TC).
TARGET_KEYS = {"box": "cracker_box", "can": "tomato_can"}
#: Mass ranges, kg: the tasks' targets weigh 2 (TC) to 10 kg (FB, BC, IB), so pushes move the distractors first
#: (paper §V-D); their distractors 0.349 to 0.603 kg.
TARGET_MASS_KG = (2.0, 10.0)
DISTRACTOR_MASS_KG = (0.349, 0.603)
#: Lateral friction range of the tasks' objects.
LATERAL_FRICTION = (0.5, 0.8)
#: The tasks' ground plane.
PLANE_LATERAL_FRICTION = 0.6
PLANE_SPINNING_FRICTION = 0.01
#: The tasks' three walls (every task declares the same three).
TASK_WALLS: tuple[WallSpec, ...] = (
    WallSpec("wall_far", (1.4, 0.2, 0.3), (1.1, 0.0), -math.pi / 2, 0.1, 0.7),
    WallSpec("wall_right", (1.4, 0.2, 0.3), (0.5, -0.7), 0.0, 0.1, 0.7),
    WallSpec("wall_left", (1.4, 0.2, 0.3), (0.5, 0.7), 0.0, 0.1, 0.7),
)
