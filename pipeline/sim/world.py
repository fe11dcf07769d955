"""A pybullet world built from a :class:`pipeline.scenes.Scene`, and the action stepping (docs/simulation.md).

One :class:`World` = one DIRECT physics client (no GUI, no camera), built fresh per run and closed after it (the
client itself is emptied and reused by the next world of the process); every call passes ``physicsClientId``.
Only what the scene's effects ask for is built: walls, friction overrides, movable (dynamic) objects, settling
steps; the per-step contact wrench and ground truth are computed only when asked
(:func:`pipeline.sim.effects.read_contacts`).

Physics (as in the authors' code): time step 1/240 s, gravity (0, 0, -10), a static ground plane (lateral friction
1.0 as in pybullet_data's plane.urdf; the retrieval tasks override it). Objects are primitive boxes and cylinders
(``createCollisionShape`` + ``createMultiBody``, with ``useMaximalCoordinates``: single-link bodies become plain
btRigidBody objects, which the solver handles about 3x faster than the btMultiBody the authors' URDFs gave;
measured in docs/simulation.md) with their link frame at the scene's position, the primitive
and the inertial frame offset from it as the scene says; pybullet reports (and we record) the inertial frame.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pybullet as p

from pipeline.geometry import TILTED_RAD, quat_tilt, quat_yaw
from pipeline.scenes import Effects, ObjectSpec, Scene, WallSpec
from pipeline.sim.effects import NO_CONTACT, PADS, read_contacts, summarize_pads, wrench_noise
from pipeline.sim.gripper import GRIPPER_Z, Gripper, create_gripper

__all__ = ["World", "ActionTrace", "TIME_STEP", "GRAVITY", "MINI_STEPS", "STEPS_PER_MINI", "STEPS_PER_ACTION",
           "PLANE_LATERAL_FRICTION"]

TIME_STEP = 1.0 / 240.0
GRAVITY = -10.0
#: An action is 15 linear interpolation targets (mini steps) of 21 sim steps each (docs/simulation.md, "World,
#: gripper, stepping").
MINI_STEPS = 15
STEPS_PER_MINI = 21
STEPS_PER_ACTION = MINI_STEPS * STEPS_PER_MINI
#: plane.urdf's own lateral friction (not an override).
PLANE_LATERAL_FRICTION = 1.0
#: Where a gripper waits while start positions are being sampled (far from every scene).
_PARKING = (10.0, 10.0)
#: Physics clients of closed worlds, emptied with ``resetSimulation`` and kept for the next :class:`World` of this
#: process: connecting and disconnecting a DIRECT client costs about 12-20 ms, a reset about 0.2 ms, a tenth of a
#: grasp simulation (docs/experiments/reproduce-time.md). A reset client builds and steps the same world to
#: the bit as a fresh one (tests/test_sim_reuse.py).
_SPARE: list[int] = []
_MAX_SPARE = 2


def _connect() -> int:
    """A DIRECT physics client with an empty world: a spare one if this process has one, else a new one."""
    while _SPARE:
        c = _SPARE.pop()
        if p.isConnected(physicsClientId=c):
            return c
    return p.connect(p.DIRECT)


def _release(client: int) -> None:
    """Empty ``client`` and keep it for the next world, or disconnect it if enough are kept."""
    if len(_SPARE) < _MAX_SPARE:
        try:
            p.resetSimulation(physicsClientId=client)
        except p.error:
            return
        _SPARE.append(client)
        return
    try:
        p.disconnect(physicsClientId=client)
    except p.error:
        pass


@dataclass
class ActionTrace:
    """Everything observed during one action, one row per sim step (S = STEPS_PER_ACTION).

    Attributes
    ----------
    start : ndarray, shape (3,), metres
        Gripper base position at the start of the action (the observation before the first step).
    target : ndarray, shape (2,), metres
        Final commanded (x, y): start + displacement.
    pos : ndarray, shape (S, 3), metres
        Gripper base position after each sim step.
    quat : ndarray, shape (S, 4)
        Gripper xyzw quaternion after each sim step.
    wrench : ndarray, shape (S, 6), N and N m
        Contact wrench on the gripper, world frame; NaN if the wrench effect is off.
    truth_xy : ndarray, shape (S, 2), metres
        True contact point (on the gripper) of the first object in contact; NaN without contact/truth.
    truth_first, truth_last : ndarray, shape (S,), int64
        Lowest / highest object id in contact (NO_CONTACT = -1 without contact or truth).
    pads : dict or None
        What the fingertip sensors report of the action (:func:`pipeline.sim.effects.summarize_pads`); None when
        the scene has none.
    """

    start: np.ndarray
    target: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    wrench: np.ndarray
    truth_xy: np.ndarray
    truth_first: np.ndarray
    truth_last: np.ndarray
    pads: dict | None = None


class World:
    """A fresh pybullet DIRECT world for one run of a scene.

    Parameters
    ----------
    scene : Scene
    effects : Effects, optional
        Overrides ``scene.effects``.
    gripper_start : (float, float), optional, metres
        Overrides ``scene.gripper_start``; with neither, the gripper is parked far away until :meth:`place`.
    maximal_coordinates : bool
        Build the plane, objects and walls as maximal-coordinate rigid bodies (default; ~3x faster to solve)
        instead of btMultiBody as the authors' URDFs were (kept for comparison; trajectories differ).
    sensor_rng : numpy.random.Generator, optional
        Draws the noise of the scene's ``[sensors]`` (the fingertips' points, the wrench's noise). The sensors are
        simulated only when it is given (collection gives it; a world built only to reach a state, as the grasp's,
        needs no sensing).

    Attributes
    ----------
    client : int
    gripper : Gripper
    body_of : dict
        Scene object id (position in ``scene.body_names``) -> pybullet body id, for the bodies built.
    id_of : dict
        The inverse map.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, scene: Scene, effects: Effects | None = None,
                 gripper_start: tuple[float, float] | None = None, *, maximal_coordinates: bool = True,
                 sensor_rng: np.random.Generator | None = None) -> None:
        self.scene = scene
        self._sensor_rng = sensor_rng if scene.sensors.any else None
        self._maximal = bool(maximal_coordinates)
        self.effects = effects if effects is not None else scene.effects
        self.client = _connect()
        if self.client < 0:
            raise RuntimeError("pybullet: could not connect a DIRECT physics client")
        try:
            self._build(gripper_start if gripper_start is not None else scene.gripper_start)
        except BaseException:
            self.close()
            raise

    # -- building -------------------------------------------------------------------------------------------

    def _build(self, start: tuple[float, float] | None) -> None:
        c = self.client
        eff = self.effects
        p.setTimeStep(TIME_STEP, physicsClientId=c)
        p.setGravity(0.0, 0.0, GRAVITY, physicsClientId=c)
        plane_shape = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
        self.plane = p.createMultiBody(0.0, plane_shape, -1, useMaximalCoordinates=self._maximal, physicsClientId=c)
        p.changeDynamics(self.plane, -1, lateralFriction=PLANE_LATERAL_FRICTION, physicsClientId=c)
        if eff.friction:
            kw = {}
            if self.scene.plane.lateral_friction is not None:
                kw["lateralFriction"] = self.scene.plane.lateral_friction
            if self.scene.plane.spinning_friction is not None:
                kw["spinningFriction"] = self.scene.plane.spinning_friction
            if kw:
                p.changeDynamics(self.plane, -1, physicsClientId=c, **kw)
        self.body_of: dict[int, int] = {}
        movable = eff.movable
        for i, spec in enumerate(self.scene.objects):
            dynamic = movable is None or spec.name in movable
            self.body_of[i] = self._make_object(spec, dynamic)
        if eff.walls:
            n = len(self.scene.objects)
            for j, wall in enumerate(self.scene.walls):
                self.body_of[n + j] = self._make_wall(wall)
        self.id_of = {b: i for i, b in self.body_of.items()}
        x, y = start if start is not None else _PARKING
        self.gripper: Gripper = create_gripper(c, x, y, friction=eff.friction)
        if start is not None:
            self.settle()

    def _make_object(self, o: ObjectSpec, dynamic: bool) -> int:
        c = self.client
        frame = dict(collisionFramePosition=(o.shape_offset[0], o.shape_offset[1], 0.0),
                     collisionFrameOrientation=p.getQuaternionFromEuler((0.0, 0.0, o.shape_yaw)))
        if o.shape == "box":
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[s / 2.0 for s in o.size], physicsClientId=c,
                                           **frame)
        else:
            shape = p.createCollisionShape(p.GEOM_CYLINDER, radius=o.size[0], height=o.size[1], physicsClientId=c,
                                           **frame)
        body = p.createMultiBody(
            baseMass=o.mass if dynamic else 0.0, baseCollisionShapeIndex=shape, baseVisualShapeIndex=-1,
            basePosition=(o.position[0], o.position[1], o.spawn_z),
            baseOrientation=p.getQuaternionFromEuler((o.rp[0], o.rp[1], o.yaw)),
            baseInertialFramePosition=o.com_offset,
            baseInertialFrameOrientation=p.getQuaternionFromEuler((0.0, 0.0, o.com_yaw)),
            useMaximalCoordinates=self._maximal, physicsClientId=c)
        if self.effects.friction:
            kw = {k: v for k, v in (("lateralFriction", o.lateral_friction), ("spinningFriction", o.spinning_friction),
                                    ("rollingFriction", o.rolling_friction)) if v is not None}
            if kw:
                p.changeDynamics(body, -1, physicsClientId=c, **kw)
        return body

    def _make_wall(self, w: WallSpec) -> int:
        c = self.client
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[s / 2.0 for s in w.size], physicsClientId=c)
        body = p.createMultiBody(0.0, shape, -1, basePosition=(w.position[0], w.position[1], w.z),
                                 baseOrientation=p.getQuaternionFromEuler((0.0, 0.0, w.yaw)),
                                 useMaximalCoordinates=self._maximal, physicsClientId=c)
        if self.effects.friction and w.lateral_friction is not None:
            p.changeDynamics(body, -1, lateralFriction=w.lateral_friction, physicsClientId=c)
        return body

    # -- running --------------------------------------------------------------------------------------------

    def settle(self, steps: int | None = None) -> None:
        """Step at rest (default: the scene's ``settle_steps``); objects spawned overlapping are pushed apart."""
        n = self.effects.settle_steps if steps is None else steps
        c = self.client
        for _ in range(n):
            p.stepSimulation(physicsClientId=c)

    def place(self, x: float, y: float, *, settle: bool = True) -> None:
        """Teleport the gripper to (x, y) and settle the world there."""
        self.gripper.place(x, y)
        if settle:
            self.settle()

    def touches(self, x: float, y: float) -> bool:
        """Whether the gripper placed at (x, y) would touch any object or wall (collision detection only)."""
        c = self.client
        g = self.gripper
        saved = g.pose()
        p.resetBasePositionAndOrientation(g.body, (x, y, GRIPPER_Z), g.orientation, physicsClientId=c)
        p.performCollisionDetection(physicsClientId=c)
        hit = any(ct[2] in self.id_of for ct in p.getContactPoints(bodyA=g.body, physicsClientId=c))
        p.resetBasePositionAndOrientation(g.body, saved[0], saved[1], physicsClientId=c)
        return hit

    def gripper_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Base position (3,) m and xyzw quaternion (4,)."""
        pos, q = self.gripper.pose()
        return np.array(pos), np.array(q)

    def act(self, dx: float, dy: float) -> ActionTrace:
        """Execute one displacement of the gripper (docs/simulation.md, "World, gripper, stepping").

        The start is the observed base position; the pivot goes to start + f (dx, dy) for f = 1/15 .. 15/15,
        each held for 21 sim steps, and the gripper is observed after every sim step (315 in all).

        Parameters
        ----------
        dx, dy : float, metres
            Commanded displacement (the action times 0.03 m, noise included).
        """
        c = self.client
        gb = self.gripper.body
        eff = self.effects
        want_w, want_t = eff.wrench, eff.contact_truth
        sensors, rng = self.scene.sensors, self._sensor_rng
        want_p = rng is not None and sensors.fingertips
        id_of = self.id_of
        pose = p.getBasePositionAndOrientation
        (sx, sy, sz), _ = pose(gb, physicsClientId=c)
        pos, quat, wr, txy, tf, tl, pads = [], [], [], [], [], [], []
        nan6 = (math.nan,) * 6
        for _ in self._steps(sx, sy, dx, dy):
            bp, bq = pose(gb, physicsClientId=c)
            w, cx, cy, first, last, pad = read_contacts(c, gb, bp, id_of, want_w, want_t, want_p)
            pos.append(bp)
            quat.append(bq)
            wr.append(w if w is not None else nan6)
            txy.append((cx, cy))
            tf.append(first)
            tl.append(last)
            pads.append(pad)
        wrench = np.array(wr, dtype=np.float64)
        start, pos_a = np.array((sx, sy, sz)), np.array(pos)
        pad_report = None
        if rng is not None:
            # one draw per action, in a fixed order (wrench, then pads), so the draws never depend on the contacts
            if want_w and any(s > 0.0 for s in sensors.wrench_noise):
                wrench = wrench + wrench_noise(rng, len(wrench), sensors.wrench_noise)
            if want_p:
                readings = np.array(pads, dtype=np.float64).reshape(len(pads), len(PADS), 4)
                pad_report = summarize_pads(readings, start, pos_a, sensors.pad_threshold_n,
                                            sensors.pad_noise_mm * 1e-3, rng)
                if not want_t:  # the pads' object is ground truth: recorded only with the contact_truth effect
                    pad_report["object"][:] = NO_CONTACT
        return ActionTrace(start=start, target=np.array((sx + dx, sy + dy)), pos=pos_a,
                           quat=np.array(quat), wrench=wrench, truth_xy=np.array(txy),
                           truth_first=np.array(tf, dtype=np.int64), truth_last=np.array(tl, dtype=np.int64),
                           pads=pad_report)

    def advance(self, dx: float, dy: float) -> None:
        """:meth:`act` without observing: the same targets and sim steps (reading the pose and contacts does not
        change the simulation), for scripts that need only the state it ends in (the grasp,
        :mod:`pipeline.grasp`)."""
        (sx, sy, _), _ = p.getBasePositionAndOrientation(self.gripper.body, physicsClientId=self.client)
        for _ in self._steps(sx, sy, dx, dy):
            pass

    def _steps(self, sx: float, sy: float, dx: float, dy: float) -> Iterator[None]:
        """The sim steps of one displacement from the base position (sx, sy), metres: the pivot goes to
        start + f (dx, dy) for f = 1/15 .. 15/15, each held for 21 sim steps; yields after every sim step."""
        c = self.client
        g = self.gripper
        step = p.stepSimulation
        for k in range(MINI_STEPS):
            f = (k + 1) / MINI_STEPS
            g.move_to(sx + f * dx, sy + f * dy)
            for _ in range(STEPS_PER_MINI):
                step(physicsClientId=c)
                yield

    # -- state ----------------------------------------------------------------------------------------------

    def object_poses(self) -> np.ndarray:
        """Inertial-frame (x, y, yaw) of every scene body, shape (B, 3) in ``scene.body_names`` order.

        Metres and radians; rows of bodies that were not built (walls switched off) are NaN.
        """
        out = np.full((len(self.scene.body_names), 3), np.nan)
        for i, b in self.body_of.items():
            pos, q = p.getBasePositionAndOrientation(b, physicsClientId=self.client)
            out[i] = (pos[0], pos[1], quat_yaw(q))
        return out

    def tilted_poses(self, min_tilt_rad: float = TILTED_RAD) -> dict[str, list[float]]:
        """The full pose of every scene body whose vertical axis leans more than ``min_tilt_rad`` (a body knocked
        over or leaning on another): name -> [x, y, z, qx, qy, qz, qw] (inertial frame, metres, pybullet's
        quaternion order). What :meth:`object_poses` does not keep; the grasp's restored state needs it."""
        out = {}
        for i, b in self.body_of.items():
            pos, q = p.getBasePositionAndOrientation(b, physicsClientId=self.client)
            if quat_tilt(q) > min_tilt_rad:
                out[self.scene.body_names[i]] = [float(v) for v in (*pos, *q)]
        return out

    def object_distances(self) -> np.ndarray:
        """Minimum distance (m) of every scene body to the gripper, shape (B,); NaN for bodies not built."""
        out = np.full(len(self.scene.body_names), np.nan)
        gb = self.gripper.body
        for i, b in self.body_of.items():
            pts = p.getClosestPoints(b, gb, 100000.0, physicsClientId=self.client)
            if pts:
                out[i] = min(pt[8] for pt in pts)
        return out

    def close(self) -> None:
        """Give the client back: emptied and kept for the next world of this process, or disconnected
        (idempotent)."""
        if getattr(self, "client", -1) >= 0:
            _release(self.client)
            self.client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
