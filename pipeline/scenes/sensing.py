"""The scene's robot as sensed: ``[sensors]`` (tactile fingertips, a noisy wrist wrench) and the settings it was
tuned with, ``[detection]`` and ``[methods.<tracker>]`` (docs/simulation.md, "Tactile fingertips and a noisy
wrench").

The readers are :mod:`pipeline.scenes.parse`'s (passed in, so this module imports nothing of it); every problem is
a :class:`~pipeline.scenes.types.SceneError` naming the file and the dotted key.
"""
from __future__ import annotations

from typing import Any

from pipeline.scenes.types import Hardware, Sensors

__all__ = ["parse_sensors", "parse_hardware", "MAX_PAD_NOISE_MM", "MAX_PAD_THRESHOLD_N", "MAX_WRENCH_NOISE"]

#: Bounds of the sensor keys: beyond them a value is a unit error (metres for millimetres, N for mN).
MAX_PAD_NOISE_MM = 50.0
MAX_PAD_THRESHOLD_N = 1000.0
MAX_WRENCH_NOISE = 100.0
#: Detector keys a scene may override (pipeline.detection.DetectionParams).
_DETECTION_KEYS = {"threshold", "sigma_inv", "min_force_n"}


def parse_sensors(r: Any) -> Sensors:
    """``[sensors]`` -> :class:`Sensors` (all off when the table is absent)."""
    if r is None:
        return Sensors()
    r.check_keys({"fingertips", "pad_threshold_n", "pad_noise_mm", "wrench_noise"})
    d = Sensors()
    noise = r.vector("wrench_noise", 6, d.wrench_noise, maximum=MAX_WRENCH_NOISE)
    if any(s < 0 for s in noise):
        raise r.fail("wrench_noise", f"expected non-negative standard deviations, got {list(noise)}")
    return Sensors(
        fingertips=r.boolean("fingertips", d.fingertips),
        pad_threshold_n=r.number("pad_threshold_n", d.pad_threshold_n, positive=True, maximum=MAX_PAD_THRESHOLD_N),
        pad_noise_mm=r.number("pad_noise_mm", d.pad_noise_mm, nonneg=True, maximum=MAX_PAD_NOISE_MM),
        wrench_noise=tuple(noise),
    )


def parse_hardware(detection: Any, methods: Any) -> Hardware:
    """``[detection]`` and ``[methods.<tracker>]`` -> :class:`Hardware`. Values are checked for type here; the
    method names and parameter names are checked against the registry where they are used (``evaluate``)."""
    det: dict[str, Any] = {}
    if detection is not None:
        detection.check_keys(_DETECTION_KEYS)
        if "threshold" in detection.table:
            det["threshold"] = detection.number("threshold", positive=True, maximum=1e9)
        if "sigma_inv" in detection.table:
            sig = detection.vector("sigma_inv", 6, maximum=1e9)
            if any(s < 0 for s in sig):
                raise detection.fail("sigma_inv", f"expected non-negative weights, got {list(sig)}")
            det["sigma_inv"] = tuple(sig)
        if "min_force_n" in detection.table:
            det["min_force_n"] = detection.number("min_force_n", nonneg=True, maximum=1e4)
    out: dict[str, dict[str, Any]] = {}
    if methods is not None:
        for name in methods.table:
            sub = methods.sub(name)
            params: dict[str, Any] = {}
            for k, v in sub.table.items():
                if isinstance(v, (bool, int, str)):
                    params[k] = v
                else:
                    params[k] = sub.number(k)
            out[str(name)] = params
    return Hardware(detection=det, methods=out)
