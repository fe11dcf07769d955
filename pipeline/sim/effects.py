"""The switchable effects that act while the world runs: replay noise, the contact wrench, ground truth.

Each is built only if the scene's ``[effects]`` asks for it (:class:`pipeline.scenes.Effects`); the world
building effects (movable objects, friction overrides, walls, settling) live in :mod:`pipeline.sim.world`.
"""
from __future__ import annotations

import numpy as np
import pybullet as p

__all__ = ["action_noise", "read_contacts", "NO_CONTACT"]

#: Object id meaning "no contact" (the authors' NO_CONTACT_ID).
NO_CONTACT = -1


def action_noise(rng: np.random.Generator, n: int, noise_mm: float, scale: float) -> np.ndarray:
    """Uniform replay noise for ``n`` actions, in normalised action units.

    The authors add ``(U[0,1) - 0.5) * c`` to each normalised component, drawn once for the whole sequence
    (docs/simulation.md, "Effects: only what a scene calls for"); here ``c`` is expressed as a half-width in
    millimetres of displacement.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Number of actions.
    noise_mm : float, millimetres
        Half-width of the displacement noise per axis; 0 draws nothing and returns zeros.
    scale : float, metres
        Displacement per unit action (0.03).

    Returns
    -------
    ndarray, shape (n, 2)
        Noise to add to the normalised actions (before clipping to [-1, 1]).
    """
    if noise_mm <= 0.0:
        return np.zeros((n, 2))
    half = noise_mm * 1e-3 / scale
    return rng.uniform(-half, half, size=(n, 2))


def read_contacts(client: int, gripper: int, base: tuple[float, float, float], id_of: dict[int, int],
                  wrench: bool, truth: bool) -> tuple[tuple[float, ...] | None, float, float, int, int]:
    """Contact wrench on the gripper and the ground truth of one sim step, from one getContactPoints call.

    As in docs/simulation.md, "Effects: only what a scene calls for": over every contact of any gripper link with a
    scene object or wall (not the plane), force = normalForce * contactNormalOnB + lateralFriction1 * dir1 +
    lateralFriction2 * dir2 (B = the object, so the normal points from the object to the gripper) and torque =
    (positionOnA - base) x force, summed.
    One ``getContactPoints(bodyA=gripper)`` call covers every object, instead of one call per object.

    Parameters
    ----------
    client, gripper : int
        Physics client and gripper body ids.
    base : (float, float, float), metres
        Gripper base position (torque reference point).
    id_of : dict
        pybullet body id -> scene object id, for every touchable body (the plane is absent).
    wrench, truth : bool
        What to compute.

    Returns
    -------
    w : tuple of 6 float or None
        (f_x, f_y, f_z, tau_x, tau_y, tau_z) in N and N m, world frame; None if ``wrench`` is off.
    cx, cy : float, metres
        Position on the gripper of the first contact with the first object (lowest id) in contact;
        NaN without contact or if ``truth`` is off.
    first_id : int
        That object's id (NO_CONTACT if none).
    last_id : int
        Highest object id in contact (the authors' loop keeps the last body found), NO_CONTACT if none.
    """
    nan = float("nan")
    if not (wrench or truth):
        return None, nan, nan, NO_CONTACT, NO_CONTACT
    contacts = p.getContactPoints(bodyA=gripper, physicsClientId=client)
    fx = fy = fz = tx = ty = tz = 0.0
    cx = cy = nan
    first = last = NO_CONTACT
    bx, by, bz = base
    for c in contacts:
        oid = id_of.get(c[2])
        if oid is None:  # the plane
            continue
        if truth:
            if first == NO_CONTACT or oid < first:
                first = oid
                cx, cy = c[5][0], c[5][1]
            if oid > last:
                last = oid
        if wrench:
            n, fn = c[7], c[9]
            d1, f1, d2, f2 = c[11], c[10], c[13], c[12]
            gx = fn * n[0] + f1 * d1[0] + f2 * d2[0]
            gy = fn * n[1] + f1 * d1[1] + f2 * d2[1]
            gz = fn * n[2] + f1 * d1[2] + f2 * d2[2]
            rx, ry, rz = c[5][0] - bx, c[5][1] - by, c[5][2] - bz
            fx += gx
            fy += gy
            fz += gz
            tx += ry * gz - rz * gy
            ty += rz * gx - rx * gz
            tz += rx * gy - ry * gx
    w = (fx, fy, fz, tx, ty, tz) if wrench else None
    return w, cx, cy, first, last
