"""The floating Franka Panda hand: pybullet's own collision meshes, assembled with createMultiBody.

As in docs/simulation.md, "World, gripper, stepping": hand (0.81 kg) plus two prismatic fingers (0.1 kg each) at z =
0.0584 in the hand frame, the right finger mesh turned by pi about z; orientation Euler (0, pi/2, 0) so the fingers
point along world +x and open along world y; the base is held by a fixed constraint (max force 30 N) at z = 0.1 m;
fingers are kept closed by position control (target 0, force 30); finger contacts are compliant (stiffness 30000,
damping 1000, spinning friction 0.1) with lateral friction 2 (the authors' override of the URDF's 1.0).

Assembling the body from the two OBJ files with ``createMultiBody`` (instead of writing a URDF) needs no files
of our own; pybullet collides with each mesh's convex hull either way, and computes the link inertias from the
hulls as it does for a URDF loaded without ``URDF_USE_INERTIA_FROM_FILE``. The hand's inertial frame is the
link frame, so the pose pybullet reports is the gripper base, the frame of :mod:`pipeline.robot`'s grid.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pybullet as p

# The hand's collision meshes, their orientation and the finger joints' height are the same facts as the grid's
# (one place: pipeline.robot.panda_mesh), so the simulated gripper and pxpen cannot drift apart.
from pipeline.robot.panda_mesh import FINGER_JOINT_Z, GRIPPER_EULER, mesh_paths

__all__ = ["Gripper", "create_gripper", "GRIPPER_Z", "GRIPPER_EULER", "MAX_FORCE", "mesh_paths"]

#: Height of the gripper base, m (FIXED_Z).
GRIPPER_Z = 0.1
#: Maximum force of the holding constraint, N (FloatingGripperEnv.MAX_FORCE).
MAX_FORCE = 30.0
#: Finger position-control force, N (MAX_GRIPPER_FORCE), and target opening, m (CLOSE_ANGLE).
FINGER_FORCE = 30.0
FINGER_CLOSED = 0.0
#: Finger lateral friction set by the authors' _setup_gripper (URDF value 1.0).
FINGER_FRICTION = 2.0
_FINGER_URDF_FRICTION = 1.0
_HAND_MASS = 0.81
_FINGER_MASS = 0.1


@dataclass
class Gripper:
    """Handle on the gripper body in one physics client.

    Attributes
    ----------
    client : int
        pybullet physics client id.
    body : int
        Body id (base = hand, links 0 and 1 = left and right finger).
    constraint : int
        Fixed constraint holding the base.
    orientation : tuple of 4 float
        The fixed xyzw quaternion.
    """

    client: int
    body: int
    constraint: int
    orientation: tuple[float, float, float, float]

    def move_to(self, x: float, y: float) -> None:
        """Move the constraint pivot to (x, y, GRIPPER_Z) with the fixed orientation (one control command)."""
        p.changeConstraint(self.constraint, (x, y, GRIPPER_Z), self.orientation, maxForce=MAX_FORCE,
                           physicsClientId=self.client)

    def place(self, x: float, y: float) -> None:
        """Teleport the gripper (base and closed fingers, at rest) and its pivot to (x, y)."""
        p.resetBasePositionAndOrientation(self.body, (x, y, GRIPPER_Z), self.orientation,
                                          physicsClientId=self.client)
        p.resetBaseVelocity(self.body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=self.client)
        for j in (0, 1):
            p.resetJointState(self.body, j, FINGER_CLOSED, 0.0, physicsClientId=self.client)
        self.move_to(x, y)

    def pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Base position (m) and xyzw quaternion."""
        return p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)


def create_gripper(client: int, x: float, y: float, *, friction: bool = True) -> Gripper:
    """Build the closed Panda hand at (x, y, GRIPPER_Z) held by its constraint.

    Parameters
    ----------
    client : int
        pybullet physics client id.
    x, y : float, metres
        Base position.
    friction : bool
        Apply the finger lateral friction override (2); off keeps the URDF's 1.0.
    """
    hand_obj, finger_obj = mesh_paths()
    q = p.getQuaternionFromEuler(GRIPPER_EULER)
    hand = p.createCollisionShape(p.GEOM_MESH, fileName=str(hand_obj), physicsClientId=client)
    left = p.createCollisionShape(p.GEOM_MESH, fileName=str(finger_obj), physicsClientId=client)
    right = p.createCollisionShape(p.GEOM_MESH, fileName=str(finger_obj),
                                   collisionFrameOrientation=p.getQuaternionFromEuler((0.0, 0.0, math.pi)),
                                   physicsClientId=client)
    ident = (0.0, 0.0, 0.0, 1.0)
    body = p.createMultiBody(
        baseMass=_HAND_MASS, baseCollisionShapeIndex=hand, baseVisualShapeIndex=-1,
        basePosition=(x, y, GRIPPER_Z), baseOrientation=q,
        linkMasses=[_FINGER_MASS, _FINGER_MASS], linkCollisionShapeIndices=[left, right],
        linkVisualShapeIndices=[-1, -1], linkPositions=[(0.0, 0.0, FINGER_JOINT_Z)] * 2,
        linkOrientations=[ident, ident], linkInertialFramePositions=[(0.0, 0.0, 0.0)] * 2,
        linkInertialFrameOrientations=[ident, ident], linkParentIndices=[0, 0],
        linkJointTypes=[p.JOINT_PRISMATIC, p.JOINT_PRISMATIC], linkJointAxis=[(0.0, 1.0, 0.0), (0.0, -1.0, 0.0)],
        physicsClientId=client,
    )
    finger_friction = FINGER_FRICTION if friction else _FINGER_URDF_FRICTION
    for j in (0, 1):
        # The URDF <contact> block of the fingers: compliant contact, friction anchor.
        p.changeDynamics(body, j, lateralFriction=finger_friction, spinningFriction=0.1, contactStiffness=30000.0,
                         contactDamping=1000.0, frictionAnchor=1, physicsClientId=client)
        p.setJointMotorControl2(body, j, p.POSITION_CONTROL, targetPosition=FINGER_CLOSED, force=FINGER_FORCE,
                                physicsClientId=client)
    cid = p.createConstraint(body, -1, -1, -1, p.JOINT_FIXED, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0),
                             (x, y, GRIPPER_Z), childFrameOrientation=q, physicsClientId=client)
    grip = Gripper(client=client, body=body, constraint=cid, orientation=tuple(q))
    grip.move_to(x, y)
    return grip
