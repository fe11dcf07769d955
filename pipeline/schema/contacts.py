"""Contacts for the tracker: :class:`RunContacts`, one run of a contacts table grouped by step as numpy arrays.

Positions and displacements are in metres (the contacts table of ``docs/tables.md``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pipeline.schema.specs import validate_contacts
from pipeline.schema.validate import encode_runs

__all__ = ["RunContacts", "contacts_by_run", "step_bounds"]


@dataclass(frozen=True, eq=False)
class RunContacts:
    """The contacts of one run, grouped by step, as read-only numpy arrays.

    S is the number of steps, R the number of rows (free-space steps have one row, in-contact steps K ≥ 1).

    Attributes
    ----------
    run : str
    step : ndarray, shape (S,), int64
    ee : ndarray, shape (S, 2), metres
        End-effector position after each step.
    in_contact : ndarray, shape (S,), bool
    row_start, row_count : ndarray, shape (S,), int64
        Rows ``row_start[s] : row_start[s] + row_count[s]`` of the row-level arrays belong to step s.
    contact : ndarray, shape (R, 2), metres
        Contact point; NaN on free-space rows.
    dx : ndarray, shape (R, 2), metres
        End-effector displacement while in contact; NaN on free-space rows.
    row_index : ndarray, shape (R,), int64
        Row in the original table (to carry its other columns into outputs).
    object_id : ndarray, shape (R,), int64, or None
        Ground truth when the table has it.
    """

    run: str
    step: np.ndarray
    ee: np.ndarray
    in_contact: np.ndarray
    row_start: np.ndarray
    row_count: np.ndarray
    contact: np.ndarray
    dx: np.ndarray
    row_index: np.ndarray
    object_id: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(self.step.shape[0])

    @property
    def n_rows(self) -> int:
        return int(self.row_index.shape[0])

    def rows(self, s: int) -> slice:
        """Slice of the row-level arrays for step `s`."""
        start = int(self.row_start[s])
        return slice(start, start + int(self.row_count[s]))

    def observation(self, s: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Arguments of ``ContactTracker.update`` for step `s`: ``x (2,)``, ``dx (K, 2)``, ``p (K, 2)``,
        the last two None in free space."""
        if not self.in_contact[s]:
            return self.ee[s], None, None
        r = self.rows(s)
        return self.ee[s], self.dx[r], self.contact[r]


def step_bounds(step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``starts[k]:ends[k]`` of each step among one run's rows in order, both (K,): consecutive rows with the
    same ``step`` are that step's simultaneous contacts (several sensors)."""
    step = np.asarray(step)
    starts = np.flatnonzero(np.r_[True, step[1:] != step[:-1]])
    return starts, np.r_[starts[1:], len(step)]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def contacts_by_run(table: pa.Table) -> list[tuple[str, RunContacts]]:
    """Split a contacts table into runs (in order of first appearance), grouped by step.

    The table is validated first (cheap), so any contacts table may be passed.

    Returns
    -------
    list of (run, RunContacts)
    """
    table = validate_contacts(table)
    n = table.num_rows
    if n == 0:
        return []
    codes, names = encode_runs(table.column("run"))

    def f64(name):
        return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)

    step = np.asarray(table.column("step").to_numpy(), dtype=np.int64)
    ee = np.stack([f64("ee_x_m"), f64("ee_y_m")], axis=1)
    inc = np.asarray(table.column("in_contact").to_numpy(zero_copy_only=False), dtype=bool)
    contact = np.stack([f64("contact_x_m"), f64("contact_y_m")], axis=1)
    dx = np.stack([f64("dx_m"), f64("dy_m")], axis=1)
    oid = (np.asarray(table.column("object_id").to_numpy(), dtype=np.int64)
           if "object_id" in table.column_names else None)

    order = np.argsort(codes, kind="stable")
    bounds = np.searchsorted(codes[order], np.arange(len(names) + 1))
    out = []
    for c, name in enumerate(names):
        rows = order[bounds[c]:bounds[c + 1]]
        s = step[rows]
        starts, ends = step_bounds(s)
        counts = ends - starts
        head = rows[starts]
        out.append((name, RunContacts(
            run=name,
            step=_readonly(step[head]),
            ee=_readonly(ee[head]),
            in_contact=_readonly(inc[head]),
            row_start=_readonly(starts.astype(np.int64)),
            row_count=_readonly(counts.astype(np.int64)),
            contact=_readonly(contact[rows]),
            dx=_readonly(dx[rows]),
            row_index=_readonly(rows.astype(np.int64)),
            object_id=None if oid is None else _readonly(oid[rows]),
        )))
    return out
