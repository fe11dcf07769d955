"""The authors' benchmark streams (``data/anchors/stream_T*.npz``) as contacts tables, and their metrics.

The streams come from ``../shared/anchors/ref_tracker_bench.py``: a disc end-effector (r = 0.05 m) pushing three
axis-aligned squares, T contact steps among free-space steps. Each stream file holds, per step i:
``x`` (L, 2) end-effector position after the step, ``dx`` (L, 2) motion of the step, ``p`` (L, 2) contact point
(NaN in free space), ``obj_id`` (L,) true object (-1 in free space), ``in_contact`` (L,), ``obj_centers``
(L, n_obj, 2) true square centres after the step, plus ``obj_sizes`` (n_obj,) side lengths and ``robot_radius``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.safe_open import optional_file, regular_file

ANCHOR_DIR = Path(__file__).resolve().parents[2] / "data" / "anchors"


def load_stream(path: str | Path) -> dict[str, np.ndarray]:
    """Load one stream file into a dict of arrays."""
    with np.load(regular_file(path, "the stream file"), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def stream_path(T: int, directory: str | Path | None = None) -> Path:
    return Path(directory or ANCHOR_DIR) / f"stream_T{T}.npz"


def source_path(T: int, directory: str | Path | None = None) -> Path:
    """The file that holds the stream of T contacts: ``stream_T{T}.npz``, or else the shortest longer stream in the
    folder (the streams are prefixes of one trajectory, so its first T contacts are that stream); the path of
    the missing file when there is neither."""
    path = stream_path(T, directory)
    longer = sorted(t for t in _stream_counts(path.parent) if t > T)
    return path if optional_file(path, "the stream file") is not None or not longer else \
        stream_path(longer[0], directory)


def _stream_counts(folder: Path) -> list[int]:
    return sorted(int(f.stem[len("stream_T"):]) for f in folder.glob("stream_T*.npz")
                  if f.stem[len("stream_T"):].isdigit())


def load_contacts_stream(T: int, directory: str | Path | None = None) -> dict[str, np.ndarray]:
    """The stream of T contacts (:func:`source_path`), cut just after its T-th contact step when it comes from a
    longer file; the per-step arrays are cut, the rest (object sizes, grid, parameters) kept."""
    stream = load_stream(source_path(T, directory))
    c = stream["in_contact"].astype(bool)
    if c.sum() == T:
        return stream
    steps = int(np.flatnonzero(c)[T - 1]) + 1
    return {k: (v[:steps] if getattr(v, "ndim", 0) and len(v) == len(c) else v) for k, v in stream.items()}


#: Arrays every stream file must hold, with their dimensionality.
STREAM_ARRAYS = {"x": 2, "dx": 2, "p": 2, "obj_id": 1, "in_contact": 1, "obj_centers": 3, "obj_sizes": 1,
                 "robot_radius": 0}


def check_streams(ts: list[int] | tuple[int, ...], directory: str | Path | None = None) -> list[Path]:
    """The stream files for contact counts `ts` (a longer stream stands for a missing count), each checked to load
    (no pickles) with the arrays a replay needs.

    Raises
    ------
    ValueError
        One line naming the missing or unreadable file, or the missing array, and the counts available.
    """
    paths = []
    for T in ts:
        path = source_path(T, directory)
        if optional_file(path, "the stream file") is None:  # a FIFO there is refused, never opened
            have = _stream_counts(path.parent)
            raise ValueError(f"{path}: no stream for T={T} (nor a longer one to cut); streams in {path.parent}: "
                             f"{', '.join(f'T={t}' for t in have) or 'none'}")
        try:
            with np.load(path, allow_pickle=False) as z:
                shapes = {k: z[k].ndim for k in z.files if k in STREAM_ARRAYS}
        except (ValueError, OSError, EOFError) as e:
            raise ValueError(f"{path}: not a stream file ({' '.join(str(e).split())[:200]})") from None
        for name, ndim in STREAM_ARRAYS.items():
            if shapes.get(name) != ndim:
                raise ValueError(f"{path}: array {name!r} " + ("missing" if name not in shapes else
                                 f"has {shapes[name]} dimensions") + f"; expected {ndim} (a stream file "
                                 "of the authors' benchmark)")
        paths.append(path)
    return paths


def stream_to_contacts(stream: dict[str, np.ndarray], run: str) -> pa.Table:
    """The stream as a contacts table (one row per step; ``object_id`` -1 in free space)."""
    c = stream["in_contact"].astype(bool)
    n = len(c)

    def maybe(values: np.ndarray) -> pa.Array:
        return pa.array(np.where(c, values, 0.0), pa.float64(), mask=~c)

    return pa.table({
        "run": pa.array([run] * n, pa.string()),
        "step": pa.array(np.arange(n), pa.int64()),
        "ee_x_m": pa.array(stream["x"][:, 0], pa.float64()),
        "ee_y_m": pa.array(stream["x"][:, 1], pa.float64()),
        "in_contact": pa.array(c),
        "contact_x_m": maybe(stream["p"][:, 0]),
        "contact_y_m": maybe(stream["p"][:, 1]),
        "dx_m": maybe(stream["dx"][:, 0]),
        "dy_m": maybe(stream["dx"][:, 1]),
        "object_id": pa.array(stream["obj_id"].astype(np.int64)),
    })


def square_surface_distance(points: np.ndarray, centers: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Unsigned distance of each point to the boundary of each axis-aligned square.

    Parameters
    ----------
    points : ndarray, shape (M, 2)
    centers : ndarray, shape (n_obj, 2)
    sizes : ndarray, shape (n_obj,)
        Side lengths (metres).

    Returns
    -------
    ndarray, shape (M, n_obj), metres
    """
    rel = np.abs(points[:, None, :] - centers[None, :, :]) - (np.asarray(sizes) / 2)[None, :, None]
    outside = np.linalg.norm(np.maximum(rel, 0.0), axis=-1)
    inside = -np.max(rel, axis=-1)
    return np.where(np.all(rel <= 0, axis=-1), inside, outside)


def contact_error_cm(points: np.ndarray, stream: dict[str, np.ndarray]) -> float:
    """The paper's contact error: mean over points of the distance to the nearest true object surface at the end
    of the stream, in centimetres."""
    if len(points) == 0:
        return float("nan")
    d = square_surface_distance(points, stream["obj_centers"][-1], stream["obj_sizes"])
    return float(d.min(axis=1).mean() * 100)


def untracked_contact_error_cm(stream: dict[str, np.ndarray]) -> float:
    """Contact error if the observed points were never moved (what tracking has to beat)."""
    c = stream["in_contact"].astype(bool)
    return contact_error_cm(stream["p"][c], stream)
