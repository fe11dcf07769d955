"""pybullet simulation of a scene: the world (:mod:`.world`), the gripper (:mod:`.gripper`) and the switchable
effects (:mod:`.effects`). Only this package imports pybullet; :mod:`pipeline.scenes` stays pure data.
"""
import os as _os
import sys as _sys

if "pybullet" not in _sys.modules:
    # `import pybullet` writes a build-time banner straight to file descriptor 2; stages must not chatter
    # on stderr), so the banner is swallowed once here, before any submodule imports pybullet.
    _saved = _os.dup(2)
    try:
        with open(_os.devnull, "w") as _null:
            _os.dup2(_null.fileno(), 2)
            import pybullet  # noqa: F401
    finally:
        _os.dup2(_saved, 2)
        _os.close(_saved)
from pipeline.sim.effects import NO_CONTACT, action_noise, read_contacts
from pipeline.sim.gripper import GRIPPER_EULER, GRIPPER_Z, MAX_FORCE, Gripper, create_gripper
from pipeline.sim.world import MINI_STEPS, STEPS_PER_ACTION, STEPS_PER_MINI, TIME_STEP, ActionTrace, World

__all__ = ["World", "ActionTrace", "Gripper", "create_gripper", "read_contacts", "action_noise", "NO_CONTACT",
           "GRIPPER_Z", "GRIPPER_EULER", "MAX_FORCE", "TIME_STEP", "MINI_STEPS", "STEPS_PER_MINI",
           "STEPS_PER_ACTION"]
