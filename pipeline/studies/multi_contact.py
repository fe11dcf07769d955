"""What several contacts per step cost the trackers (``stucco bench contacts``; docs/tracking.md, "Several contacts
per step").

The paper's real robot sensed with two fingertip sensors and the wrench, so a step could give up to three contact
points (§V-E). Each anchor stream (:mod:`pipeline.studies.anchors`: the disc robot, one contact per step) is made a
stream of K contacts per step: every contact point is joined by K - 1 points on the robot's surface, the contact
turned about the robot's centre by ±0.4 rad (two sensors a few centimetres apart), moved by the same displacement.
A stream of T contact steps then holds K·T points. The time per contact point of that stream is set against two
one-contact streams: the same T steps (the same updates, K times fewer points), and the stream of K·T contact
steps (as many points, K times more updates), the issue's "per contact point" ratio.
"""
from __future__ import annotations

import time

import numpy as np

from pipeline.studies.anchors import load_contacts_stream, source_path
from pipeline.studies.trackers import stream_tracker

__all__ = ["ANGLE_RAD", "with_contacts_per_step", "time_stream", "contacts_bench"]

#: Angle (rad) about the robot's centre between a step's contact and each added one (0.4 rad on the 5 cm disc: 2 cm).
ANGLE_RAD = 0.4


def with_contacts_per_step(stream: dict, k: int, angle: float = ANGLE_RAD) -> tuple[np.ndarray, np.ndarray]:
    """The contacts of every step of ``stream`` as K points: arrays ``p`` and ``dx`` of shape (L, K, 2), metres
    (free-space rows carry the stream's NaN or zeros unchanged); the added points alternate +angle, -angle, +2
    angle, ... about the robot's position ``x`` after the step."""
    x = np.asarray(stream["x"], dtype=np.float64)
    p = np.asarray(stream["p"], dtype=np.float64)
    dx = np.asarray(stream["dx"], dtype=np.float64)
    turns = [0.0] + [angle * (j // 2 + 1) * (1 if j % 2 == 0 else -1) for j in range(k - 1)]
    r = p - x
    out = np.empty((len(p), k, 2))
    for j, a in enumerate(turns):  # K turns: a loop over sensors, not over points
        c, s = np.cos(a), np.sin(a)
        out[:, j] = x + np.column_stack([c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1]])
    return out, np.repeat(dx[:, None, :], k, axis=1)


def time_stream(stream: dict, p: np.ndarray, dx: np.ndarray, method: str, n_particles: int, seed: int = 0) -> float:
    """CPU seconds (``time.process_time``) of one replay of ``stream`` with the contacts ``p``, ``dx`` (L, K, 2)."""
    tracker = stream_tracker(method, n_particles, seed, "disc:0.05")
    contact = np.asarray(stream["in_contact"], dtype=bool)
    x = np.asarray(stream["x"], dtype=np.float64)
    t0 = time.process_time()
    for i in range(len(contact)):
        if contact[i]:
            tracker.update(x[i], dx[i], p[i])
        else:
            tracker.update(x[i], None, None)
    return time.process_time() - t0


def _median_time(stream: dict, k: int, method: str, n_particles: int, repeats: int) -> float:
    p, dx = with_contacts_per_step(stream, k)
    return float(np.median([time_stream(stream, p, dx, method, n_particles) for _ in range(repeats)]))


def contacts_bench(T_list=(50, 100, 200), K_list=(1, 2, 3), *, n_particles: int = 100, methods=("stucco",),
                   repeats: int = 3, streams=None, echo=print) -> list[dict]:
    """For each method, T and K: CPU ms per contact point of the K-contact stream, and its ratios to the
    one-contact stream of the same steps and to the one-contact stream with as many points (when the anchors have
    it). Kernels are compiled (or loaded) before anything is timed. Returns one dict per row."""
    rows = []
    echo(f"CONTACTS PER STEP: anchor streams on the disc robot (r = 0.05 m), N = {n_particles}, CPU time, median of "
         f"{repeats}; K - 1 points added per contact at ±{ANGLE_RAD} rad about the robot's centre")
    echo(f"{'method':>8} {'T':>4} {'K':>2} {'points':>6} {'cpu_s':>7} {'ms/point':>8} {'x same steps':>12} "
         f"{'x same points':>13}")
    for method in methods:
        warm = load_contacts_stream(50, streams)
        _median_time(warm, max(K_list), method, 16, 1)  # compile or load every kernel, untimed
        for T in T_list:
            stream = load_contacts_stream(T, streams)
            base = _median_time(stream, 1, method, n_particles, repeats) / T
            for k in K_list:
                t = _median_time(stream, k, method, n_particles, repeats)
                per_point = t / (k * T)
                same_points = None
                if k > 1 and source_path(k * T, streams).exists():
                    big = load_contacts_stream(k * T, streams)
                    same_points = per_point / (_median_time(big, 1, method, n_particles, repeats) / (k * T))
                row = dict(method=method, T=T, K=k, points=k * T, cpu_s=t, ms_per_point=per_point * 1e3,
                           ratio_same_steps=per_point / base, ratio_same_points=same_points)
                rows.append(row)
                sp = "" if same_points is None else f"{same_points:.2f}"
                echo(f"{method:>8} {T:>4} {k:>2} {k * T:>6} {t:>7.3f} {per_point * 1e3:>8.3f} "
                     f"{per_point / base:>12.2f} {sp:>13}")
    return rows
