"""The switchable effects that act while the world runs: replay noise, the contact wrench, ground truth, the
fingertip sensors and the wrench's noise (the scene's ``[sensors]``).

Each is built only if the scene's ``[effects]`` asks for it (:class:`pipeline.scenes.Effects`); the world
building effects (movable objects, friction overrides, walls, settling) live in :mod:`pipeline.sim.world`.
"""
from __future__ import annotations

import numpy as np
import pybullet as p

__all__ = ["action_noise", "read_contacts", "wrench_noise", "summarize_pads", "NO_CONTACT", "PADS", "NO_PADS"]

#: Object id meaning "no contact" (the authors' NO_CONTACT_ID).
NO_CONTACT = -1
#: The gripper links that carry a fingertip sensor (the two finger pads of :mod:`pipeline.sim.gripper`).
PADS = (0, 1)
#: The pad reading of a sim step without pads: per pad (normal force N, x m, y m, object id).
NO_PADS: tuple = ()


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
                  wrench: bool, truth: bool, pads: bool = False
                  ) -> tuple[tuple[float, ...] | None, float, float, int, int, tuple]:
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
    wrench, truth, pads : bool
        What to compute (``pads``: the fingertip sensors' reading, docs/simulation.md, "Tactile fingertips and a
        noisy wrench").

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
    pad : tuple
        :data:`NO_PADS` if ``pads`` is off; else per pad of :data:`PADS` the summed normal force (N), the
        force-weighted mean contact point on it (x, y in metres; NaN without contact) and the object pressing it
        hardest (NO_CONTACT if none), flattened: (f_0, x_0, y_0, id_0, f_1, ...).
    """
    nan = float("nan")
    if not (wrench or truth or pads):
        return None, nan, nan, NO_CONTACT, NO_CONTACT, NO_PADS
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
    return w, cx, cy, first, last, (_pad_reading(contacts, id_of) if pads else NO_PADS)


def _pad_reading(contacts, id_of: dict[int, int]) -> tuple:
    """Per pad of :data:`PADS`: (summed normal force N, force-weighted mean contact x and y m, the object id with
    the largest normal force), from one sim step's ``getContactPoints`` list (see :func:`read_contacts`)."""
    out: list = []
    for link in PADS:
        f = sx = sy = best = 0.0
        oid_best = NO_CONTACT
        for c in contacts:
            oid = id_of.get(c[2])
            if oid is None or c[3] != link or c[9] <= 0.0:
                continue
            fn = c[9]
            f += fn
            sx += fn * c[5][0]
            sy += fn * c[5][1]
            if fn > best:
                best, oid_best = fn, oid
        out += [f, sx / f, sy / f, oid_best] if f > 0.0 else [0.0, float("nan"), float("nan"), NO_CONTACT]
    return tuple(out)


def wrench_noise(rng: np.random.Generator, n_steps: int, sigma: tuple[float, ...]) -> np.ndarray:
    """Gaussian noise for the wrist wrench of ``n_steps`` sim steps, shape (n_steps, 6), N and N m: the error of a
    wrench estimated from joint torques (docs/simulation.md, "Tactile fingertips and a noisy wrench")."""
    return rng.normal(0.0, 1.0, size=(n_steps, 6)) * np.asarray(sigma, dtype=np.float64)


def summarize_pads(readings: np.ndarray, start: np.ndarray, pos: np.ndarray, threshold_n: float, noise_m: float,
                   rng: np.random.Generator) -> dict[str, np.ndarray]:
    """What each fingertip sensor reports of one action (docs/simulation.md, "Tactile fingertips and a noisy
    wrench").

    A pad fires at the sim steps its normal force exceeds ``threshold_n``; it reports the contact point of its last
    firing step plus Gaussian noise of ``noise_m`` per axis, and, as the wrench detector does for its contact, the
    gripper's displacement summed over its firing steps (the points of two pads may have moved differently: they
    touched at different times of the action, paper §V-E).

    Parameters
    ----------
    readings : ndarray, shape (S, P, 4)
        Per sim step and pad: (normal force N, x m, y m, object id), as :func:`read_contacts` gives it.
    start : ndarray, shape (2,) or (3,), metres
        Gripper base position before the first sim step.
    pos : ndarray, shape (S, 2) or (S, 3), metres
        Gripper base position after each sim step.
    rng : numpy.random.Generator
        Draws the point noise: one (P, 2) draw per action whether or not a pad fired, so a run's draws do not
        depend on its contacts.

    Returns
    -------
    dict with ``point`` (P, 2) m and ``dx`` (P, 2) m (NaN for a pad that did not fire), ``object`` (P,) int64
    (the ground truth of the reported point, NO_CONTACT if none) and ``force`` (P,) N (the largest normal force
    of the action).
    """
    readings = np.asarray(readings, dtype=np.float64)
    n_pads = readings.shape[1]
    noise = rng.normal(0.0, 1.0, size=(n_pads, 2)) * noise_m
    steps = np.diff(np.vstack([np.asarray(start)[None, :2], np.asarray(pos)[:, :2]]), axis=0)  # (S, 2)
    fired = readings[:, :, 0] > threshold_n  # (S, P)
    point = np.full((n_pads, 2), np.nan)
    dx = np.full((n_pads, 2), np.nan)
    obj = np.full(n_pads, NO_CONTACT, dtype=np.int64)
    for j in range(n_pads):  # two pads: a loop over sensors, not over points
        hit = np.flatnonzero(fired[:, j])
        if len(hit):
            last = hit[-1]
            point[j] = readings[last, j, 1:3] + noise[j]
            dx[j] = steps[hit].sum(axis=0)
            obj[j] = int(readings[last, j, 3])
    return {"point": point, "dx": dx, "object": obj, "force": readings[:, :, 0].max(axis=0)}
