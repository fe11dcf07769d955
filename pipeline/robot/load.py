"""Robot grids from CLI strings: :func:`load_robot` turns a ``--robot`` value into a :class:`GridSDF`.

The forms are ``"panda"`` (the cached 1 mm Panda grid), ``"panda:RES"`` (the Panda grid at RES metres per cell)
and ``"disc:RADIUS"`` (a disc of RADIUS metres).
"""
from __future__ import annotations

import math

from pipeline.robot.disc import disc_sdf
from pipeline.robot.grid import GridSDF
from pipeline.robot.panda_cache import panda_sdf

__all__ = ["load_robot", "MIN_RESOLUTION", "MAX_RADIUS"]

#: Finest Panda grid (metres per cell): 0.25 mm is 560 x 824 cells (16x the 1 mm grid), the finest
#: `stucco bench accuracy --sdf-mm` takes.
MIN_RESOLUTION = 0.00025
#: Largest disc radius (metres): a 1 m disc's 1 mm grid is 2020 x 2020 cells (33 MB), larger than any gripper.
MAX_RADIUS = 1.0

_ROBOT_FORMS = ("expected 'panda' or 'disc:RADIUS' with RADIUS a positive number of metres (e.g. 'disc:0.05'), "
                "or 'panda:RES' for the Panda grid at RES metres per cell (e.g. 'panda:0.002')")


def load_robot(spec: str) -> GridSDF:
    """Robot grid from a CLI string.

    Parameters
    ----------
    spec : str
        ``"panda"`` -> :func:`panda_sdf` (cached); ``"panda:RES"`` -> :func:`panda_sdf` at RES metres per cell;
        ``"disc:RADIUS"`` (metres, e.g. ``"disc:0.05"``) ->
        :func:`disc_sdf`.

    Returns
    -------
    GridSDF

    Raises
    ------
    ValueError
        Unknown name, or a radius that is not a positive finite number; the one-line message names the
        accepted forms.
    """
    text = str(spec).strip()
    if text == "panda":
        return panda_sdf()
    if text.startswith("panda:"):
        # SDF resolution as an accuracy knob (`stucco bench accuracy`): 'panda:0.002' = 2 mm cells.
        raw = text[len("panda:"):]
        try:
            res = float(raw)
        except ValueError:
            raise ValueError(f"robot {spec!r}: resolution {raw!r} is not a number; {_ROBOT_FORMS}") from None
        if not (MIN_RESOLUTION <= res <= 0.05 and math.isfinite(res)):
            raise ValueError(f"robot {spec!r}: resolution must be in [{MIN_RESOLUTION}, 0.05] metres (finer grids "
                             f"do not fit in memory); {_ROBOT_FORMS}")
        return panda_sdf(resolution=res)
    if text.startswith("disc:"):
        raw = text[len("disc:"):]
        try:
            radius = float(raw)
        except ValueError:
            raise ValueError(f"robot {spec!r}: radius {raw!r} is not a number; {_ROBOT_FORMS}") from None
        if not (radius > 0 and math.isfinite(radius)):
            raise ValueError(f"robot {spec!r}: radius must be positive and finite; {_ROBOT_FORMS}")
        if radius > MAX_RADIUS:
            raise ValueError(f"robot {spec!r}: radius must be at most {MAX_RADIUS} metres (its 1 mm grid grows with "
                             f"its square)")
        return disc_sdf(radius)
    raise ValueError(f"unknown robot {spec!r}; {_ROBOT_FORMS}")
