"""Gripper geometry: the robot's signed distance ("pxpen") as a grid, and its isolation surface points.

STUCCO's penetration term pxpen(x, p) is the signed distance of point ``p`` to the robot at configuration ``x``,
negative inside. Because the gripper's orientation is fixed, the robot frame is a pure translation of the world
and ``pxpen(x, p) = sdf(p - x)``, with ``sdf`` a grid cached once per robot (docs/simulation.md, "The gripper's
signed distance grid"). One role per module:

* :mod:`~pipeline.robot.grid`: :class:`GridSDF`, the grid and its nearest-cell queries;
* :mod:`~pipeline.robot.disc`: :func:`disc_sdf`, a disc of given radius, the robot of the anchor benchmark streams;
* :mod:`~pipeline.robot.panda_mesh`: the floating Franka Panda hand (closed fingers) from pybullet's collision
  meshes, sliced at the plane of its origin and gridded with Open3D;
* :mod:`~pipeline.robot.panda_cache`: :func:`panda_sdf`, that grid cached on disk;
* :mod:`~pipeline.robot.surface`: :func:`surface_points`, the candidate contact points and outward normals used by
  isolation, computed on the same grid so isolation and tracking agree on where the surface is;
* :mod:`~pipeline.robot.load`: :func:`load_robot`, a CLI string (``"panda"``, ``"disc:0.05"``) to a grid.

Units are metres throughout.
"""
from pipeline.robot.disc import disc_sdf
from pipeline.robot.grid import GridSDF
from pipeline.robot.load import load_robot
from pipeline.robot.panda_cache import panda_sdf
from pipeline.robot.panda_mesh import BUILDER_VERSION, PYBULLET_COLLISION_MARGIN
from pipeline.robot.surface import surface_points

__all__ = [
    "GridSDF",
    "disc_sdf",
    "panda_sdf",
    "surface_points",
    "load_robot",
    "BUILDER_VERSION",
    "PYBULLET_COLLISION_MARGIN",
]
