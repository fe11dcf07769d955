"""Planar geometry shared by the stages: 2-D rotations, angle wrapping, quaternion yaw, primitives and their SDF.

Everything lives on the horizontal plane: points are world or body-frame ``(x, y)`` in metres, poses are
``(x, y, yaw)`` with yaw in radians, counter-clockwise about +z. This is the one place for these facts;
:mod:`pipeline.retrieve`, :mod:`pipeline.grasp`, :mod:`pipeline.isolate`, :mod:`pipeline.collect` and
:mod:`pipeline.sim` import them from here.

Boxes and upright cylinders have one cross-section over their height, so a :class:`Primitive` (the slice at the
gripper plane) is the whole shape for contact purposes (docs/estimators.md). A primitive's pose is the body's
inertial (COM) frame ``(x, y, yaw)``, the frame of the recorded ``obj_pose`` (docs/simulation.md, "Scenes are
data").

Rotations are applied element-wise (:func:`rotate`), never as matrix products: numpy's ``@`` goes through
OpenBLAS, whose kernels (and so whose last bits) change with the CPU (docs/evaluation.md, "Same numbers on every
machine").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["wrap_angle", "wrap_symmetric", "rot2", "rots2", "rotate", "dot2", "apply_pose", "quat_yaw", "quat_tilt",
           "TILTED_RAD", "gripper_yaw",
           "Primitive", "primitive_sdf", "primitive_of", "primitive_pose", "com_pose", "outline_point"]


def wrap_angle(a):
    """Angle(s) in radians, any shape, wrapped to [-pi, pi); returns a float64 ndarray of the same shape."""
    return wrap_symmetric(a, 2.0 * np.pi)


def wrap_symmetric(a, period: float):
    """Angle(s) in radians, any shape, wrapped to [-period/2, period/2): the difference between two yaws of a
    shape that looks the same after a turn of ``period`` (pi for a box, :attr:`Primitive.symmetry`). A float64
    ndarray of the same shape; zeros for ``period`` 0 (a cylinder: every yaw is the same shape)."""
    a = np.asarray(a, dtype=np.float64)
    if period <= 0.0:
        return np.zeros_like(a)
    return (a + period / 2) % period - period / 2


def rot2(yaw: float) -> np.ndarray:
    """The 2-D rotation matrix, shape (2, 2), of one angle ``yaw`` (radians, counter-clockwise).

    Its columns are the rotated frame's x and y axes in the outer frame.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def rots2(yaw: np.ndarray) -> np.ndarray:
    """Rotation matrices, shape (..., 2, 2), of angles (...) in radians (vectorised :func:`rot2`)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotate(v: np.ndarray, yaw, inverse: bool = False) -> np.ndarray:
    """Vectors ``v`` (..., 2) turned by ``yaw`` (radians, counter-clockwise), or by ``-yaw`` with ``inverse``
    (world offsets into a frame at ``yaw``), element-wise: ``yaw`` broadcasts against ``v[..., 0]``, so one angle
    per vector, per batch or for all works without building matrices (the form of :func:`rot2` the batched fits
    use). Returns (..., 2)."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    if inverse:
        return np.stack([c * x + s * y, -s * x + c * y], axis=-1)
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def dot2(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Dot products (...) of 2-vectors along the last axis, broadcast: v_x w_x + v_y w_y (element-wise, not BLAS)."""
    v = np.asarray(v, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    return v[..., 0] * w[..., 0] + v[..., 1] * w[..., 1]


def apply_pose(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World coordinates of frame points: pose (..., 3) as (x, y, yaw), pts (..., N, 2) -> (..., N, 2), metres."""
    pose = np.asarray(pose, dtype=np.float64)
    return rotate(np.asarray(pts, dtype=np.float64), pose[..., None, 2]) + pose[..., None, :2]


#: A body whose vertical axis leans more than this (radians) is knocked over or leaning on another; one at rest
#: upright on the plane leans well under a thousandth of it.
TILTED_RAD = 0.1


def quat_tilt(q) -> float:
    """How far (radians, in [0, pi]) the z axis of a body of xyzw quaternion ``q`` leans from the world's."""
    x, y = q[0], q[1]
    return math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (x * x + y * y))))


def quat_yaw(q) -> float:
    """Yaw (radians, in [-pi, pi]) of an xyzw quaternion (pybullet's order): the z-y-x Euler angle about +z.

    For a body that only turns about the vertical (objects at rest on the plane) this is its heading.
    """
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def gripper_yaw(q) -> float:
    """Yaw of the deviation of an xyzw quaternion from the gripper's fixed Euler (0, pi/2, 0) orientation.

    The gripper's x axis (hand x) points down (-z) at the canonical orientation, so the in-plane rotation is read
    from where the hand's z axis (palm -> fingertips, world +x when canonical) points.
    """
    x, y, z, w = (float(v) for v in q)
    # third column of the rotation matrix = hand z axis in world
    zx = 2.0 * (x * z + w * y)
    zy = 2.0 * (y * z - w * x)
    return math.atan2(zy, zx)


@dataclass(frozen=True)
class Primitive:
    """A box or upright cylinder in its body's inertial (COM) frame: the horizontal slice at contact height.

    Boxes and upright cylinders have the same cross-section at every height they span, so the slice at the
    gripper plane (z = 0.1 m) is the whole shape for contact purposes (docs/estimators.md).

    Attributes
    ----------
    kind : {"box", "cylinder"}
    half : tuple of float, metres
        Box: half extents (hx, hy) along the primitive's axes. Cylinder: (radius,).
    centre : ndarray, shape (2,), metres
        Primitive centre in the COM frame.
    yaw : float, radians
        Primitive axes in the COM frame.
    name : str
    """

    kind: str
    half: tuple[float, ...]
    centre: np.ndarray
    yaw: float = 0.0
    name: str = ""

    @property
    def symmetry(self) -> float:
        """Smallest rotation (rad) about the centre that maps the shape onto itself: pi for a box (pi/2 if
        square), 0 for a cylinder, meaning any rotation."""
        if self.kind == "cylinder":
            return 0.0
        return math.pi / 2 if abs(self.half[0] - self.half[1]) < 1e-9 else math.pi

    def centre_world(self, pose: np.ndarray) -> np.ndarray:
        """World position (..., 2) of the primitive centre for COM poses (..., 3)."""
        pose = np.asarray(pose, dtype=np.float64)
        return rotate(np.broadcast_to(self.centre, pose[..., :2].shape), pose[..., 2]) + pose[..., :2]

    def signed_distance(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Signed distance (m, negative inside) of world points (N, 2) to the primitive at COM pose (3,)."""
        pose = np.asarray(pose, dtype=np.float64)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        q = rotate(pts - self.centre_world(pose), float(pose[2]) + self.yaw, inverse=True)
        return primitive_sdf(self, q)[0]

    def canonical(self, pose: np.ndarray) -> np.ndarray:
        """The representative of a COM pose (3,) under the shape's symmetry.

        Rotations about the primitive centre (not the COM) map the shape onto itself: a box's yaw is brought
        into [-pi/2, pi/2) by a half turn about its centre, a cylinder's yaw is set to 0 keeping its centre.
        """
        pose = np.array(pose, dtype=np.float64)
        c = self.centre_world(pose)
        if self.kind == "cylinder":
            yaw = 0.0
        else:
            yaw = float(wrap_symmetric(pose[2], self.symmetry))
        xy = c - rotate(self.centre, yaw)
        return np.array([xy[0], xy[1], yaw])


def primitive_sdf(prim: Primitive, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (...), metres, and its gradient (..., 2) at points q (..., 2) in the primitive's frame.

    Finite everywhere: at the centre of a cylinder or on a box's medial axis a valid subgradient is used.
    """
    if prim.kind == "cylinder":
        r = np.linalg.norm(q, axis=-1)
        safe = np.where(r > 1e-12, r, 1.0)
        g = np.where((r > 1e-12)[..., None], q / safe[..., None], np.array([1.0, 0.0]))
        return r - prim.half[0], g
    d = np.abs(q) - np.asarray(prim.half[:2])
    sign = np.where(q >= 0.0, 1.0, -1.0)
    pos = np.maximum(d, 0.0)
    out = np.linalg.norm(pos, axis=-1)
    axis = np.argmax(d, axis=-1)
    inside = np.minimum(np.take_along_axis(d, axis[..., None], axis=-1)[..., 0], 0.0)
    g_out = pos * sign / np.where(out > 0.0, out, 1.0)[..., None]
    g_in = np.where(axis[..., None] == np.arange(2), sign, 0.0)
    return out + inside, np.where((out > 0.0)[..., None], g_out, g_in)


def primitive_of(spec) -> Primitive:
    """The :class:`Primitive` of a scene object (:class:`pipeline.scenes.ObjectSpec`) or wall
    (:class:`pipeline.scenes.WallSpec`), in the frame whose pose the run files record.

    Objects: the primitive sits at ``shape_offset``/``shape_yaw`` in the link frame and the recorded frame is the
    inertial one at ``com_offset``/``com_yaw``, so centre = R(-com_yaw) (shape_offset - com_offset_xy) and yaw =
    shape_yaw - com_yaw. Walls have no offsets (their recorded pose is their centre).
    """
    kind = getattr(spec, "shape", "box")
    if kind not in ("box", "cylinder"):
        raise ValueError(f"object {spec.name!r}: shape {kind!r} is not a box or cylinder")
    if getattr(spec, "rp", (0.0, 0.0)) != (0.0, 0.0):
        raise ValueError(f"object {spec.name!r}: only upright primitives have a constant horizontal slice")
    half = (spec.size[0],) if kind == "cylinder" else (spec.size[0] / 2.0, spec.size[1] / 2.0)
    so = np.asarray(getattr(spec, "shape_offset", (0.0, 0.0)), dtype=np.float64)
    com = np.asarray(getattr(spec, "com_offset", (0.0, 0.0, 0.0))[:2], dtype=np.float64)
    com_yaw = float(getattr(spec, "com_yaw", 0.0))
    centre = rotate(so - com, -com_yaw)
    return Primitive(kind=kind, half=tuple(float(h) for h in half), centre=centre,
                     yaw=float(getattr(spec, "shape_yaw", 0.0)) - com_yaw, name=spec.name)


def primitive_pose(prim: Primitive, com: np.ndarray) -> np.ndarray:
    """Primitive (centre x, centre y, axes yaw) (..., 3) of COM poses (..., 3)."""
    com = np.asarray(com, dtype=np.float64)
    return np.concatenate([prim.centre_world(com), (com[..., 2] + prim.yaw)[..., None]], axis=-1)


def com_pose(prim: Primitive, pose: np.ndarray) -> np.ndarray:
    """COM poses (..., 3) of primitive poses (..., 3) (inverse of :func:`primitive_pose`)."""
    pose = np.asarray(pose, dtype=np.float64)
    yaw = pose[..., 2] - prim.yaw
    c = rotate(np.asarray(prim.centre, dtype=np.float64), yaw)
    return np.stack([pose[..., 0] - c[..., 0], pose[..., 1] - c[..., 1], yaw], axis=-1)


def outline_point(s: np.ndarray, hx: float, hy: float) -> np.ndarray:
    """Points (N, 2) at arc lengths s (N,) along the outline of [-hx, hx] x [-hy, hy], counter-clockwise from
    (hx, -hy)."""
    s = np.asarray(s, dtype=np.float64) % (4.0 * (hx + hy))
    edges = np.cumsum([0.0, 2 * hy, 2 * hx, 2 * hy, 2 * hx])
    out = np.empty((len(s), 2))
    for k, (start, (x0, y0), (dx, dy)) in enumerate(zip(
            edges[:4], ((hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)), ((0, 1), (-1, 0), (0, -1), (1, 0)))):
        m = (s >= start) & (s < edges[k + 1])
        u = s[m] - start
        out[m, 0] = x0 + dx * u
        out[m, 1] = y0 + dy * u
    return out
