"""Probes that push light clutter aside (ProbeParams.push_through; docs/active.md, "Pushing light clutter aside"):
the guarded move goes on through light contacts, the carried object's later contacts are no probe contacts, and
the contact that stops a push where the carried object touched the gripper is that object's, pinned."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline import schema
from pipeline.probe.belief import Sensing
from pipeline.probe.carry import Carried, carry_verdict
from pipeline.probe.moves import guarded_move
from pipeline.probe.params import ProbeParams

REG = Path(__file__).resolve().parents[1] / "data" / "regression"


class ClutterArm:
    """Moves exactly as told along x; a light object from ``light_from`` (it gives way) until ``slips_at`` (it slid
    aside), a heavy one from ``wall``. Rows carry the force the move met."""

    def __init__(self, light_from: float, wall: float, slips_at: float = np.inf):
        self.pos, self.moves = np.zeros(2), []
        self.light_from, self.wall, self.slips_at = light_from, wall, slips_at

    def __call__(self, dx, dy):
        self.pos = self.pos + [dx, dy]
        self.moves.append((dx, dy))
        x = self.pos[0]
        force = 20.0 if x >= self.wall else 2.0 if self.light_from <= x < self.slips_at else np.nan
        return {"ee_x_m": x, "ee_y_m": self.pos[1], "in_contact": bool(np.isfinite(force)), "force": force}


def _light(row):
    return bool(row["force"] < 5.0)


def _move(arm, push_through, predicted=(0.3,)):
    p = ProbeParams(push_through=push_through)
    return guarded_move(arm, np.zeros(2), np.array([1.0, 0.0]), np.asarray(predicted, dtype=float), p, _light), p


def test_without_push_through_the_move_stops_at_the_first_light_contact():
    arm = ClutterArm(light_from=0.1, wall=0.2)
    (here, n, contact, travel), p = _move(arm, 0.0)
    assert contact and 0.1 <= travel <= 0.1 + p.coarse_step and here[0] < 0.1 + p.coarse_step
    assert arm.moves[-1][0] == pytest.approx(-p.backoff)


def test_push_through_goes_on_through_light_contacts_and_stops_at_the_heavy_one():
    arm = ClutterArm(light_from=0.1, wall=0.2)
    (here, n, contact, travel), p = _move(arm, 0.15)
    assert contact and 0.1 <= travel <= 0.1 + p.coarse_step  # the travel is to the first contact
    assert 0.2 <= arm.pos[0] + p.backoff <= 0.2 + p.fine_step + 1e-9  # stopped at the wall, backed off
    pushing = [m[0] for m in arm.moves[:-1] if m[0] > 0][-10:]
    assert pushing == pytest.approx([p.fine_step] * 10)  # fine steps while pushing


def test_push_through_stops_after_its_length_in_contact():
    arm = ClutterArm(light_from=0.1, wall=5.0)
    (here, n, contact, travel), p = _move(arm, 0.05, predicted=(2.0,))
    assert contact and arm.pos[0] + p.backoff == pytest.approx(travel + 0.05, abs=p.fine_step + 1e-9)


def test_push_through_goes_on_past_an_object_that_slid_aside():
    arm = ClutterArm(light_from=0.1, slips_at=0.14, wall=0.25)
    (here, n, contact, travel), p = _move(arm, 0.2)
    assert contact and arm.pos[0] + p.backoff >= 0.25  # it reached the heavy object behind


@pytest.mark.parametrize("light, command, offsets, within, expected", [
    (True, [0.004, 0.0], [[0.05, 0.0]], 0.015, (True, False)),  # carried on
    (False, [0.004, 0.0], [[0.051, 0.001]], 0.015, (False, True)),  # stopped where it touched: pinned
    (False, [0.004, 0.0], [[0.05, 0.06]], 0.015, (False, False)),  # stopped elsewhere on the gripper: another object
    (False, [0.0, 0.004], [[0.05, 0.0]], 0.015, (False, False)),  # another way: another push
    (True, [0.0, 0.004], [[0.05, 0.0]], 0.015, (False, False)),  # a new push's first contact
])
def test_carry_verdict(light, command, offsets, within, expected):
    last = Carried(np.array([1.0, 0.0]), np.array([[0.05, 0.0]]))
    verdict = carry_verdict(last, light, np.array(command), np.array(offsets), within)
    assert (verdict.carried, verdict.pinned) == expected
    assert (verdict.last is not None) == light


def test_carry_verdict_without_a_light_contact_before_is_a_plain_contact():
    verdict = carry_verdict(None, False, np.array([0.004, 0.0]), np.array([[0.05, 0.0]]), 1.0)
    assert not verdict.carried and not verdict.pinned and verdict.last is None
    assert not carry_verdict(None, True, np.zeros(2), np.zeros((0, 2)), 1.0).pinned  # no move, no contacts


def _sensing(table, carry, within):
    sensing = Sensing("TC/0", 0, np.zeros(2), 36)
    sensing.light_n, sensing.pushes.on, sensing.pushes.within = 5.0, carry, within
    sensing.observe(table)
    return sensing


def _pushed_on(table):
    """The stored TC run with action 38 commanded as action 37 was (the same push): actions 36 and 37 met 2.4 and
    2.1 N, action 38 10.8 N."""
    cols = {name: table.column(name).to_pylist() for name in ("cmd_dx_m", "cmd_dy_m")}
    for name, values in cols.items():
        values[38] = values[37]
        table = table.set_column(table.column_names.index(name), name, pa.array(values, pa.float64()))
    return table


@pytest.mark.parametrize("within, pinned", [(1.0, True), (0.0, False)])
def test_sensing_keeps_a_pushs_first_contact_drops_the_carried_ones_and_marks_the_pinned_one(within, pinned):
    table = _pushed_on(schema.read_run(REG / "TC-000.parquet"))
    sensing = _sensing(table, True, within)
    assert sorted(set(sensing.probe_steps)) == [36, 38]  # 37 carried the object met at 36
    assert len(sensing.probe_pinned) == len(sensing.probe_steps)
    assert [p for p, s in zip(sensing.probe_pinned, sensing.probe_steps) if s == 38][0] is pinned
    assert not sensing.touching[-3]  # the carried object moved on: its position stays free for transit
    plain = _sensing(table, False, within)  # without push_through every contact is a probe contact
    assert sorted(set(plain.probe_steps)) == [36, 37, 38] and not any(plain.probe_pinned)



def test_a_transit_pushes_a_light_object_on_and_stops_at_a_heavy_one():
    from pipeline.probe.moves import retrace

    path = np.array([[0.3, 0.0]])
    arm = ClutterArm(light_from=0.05, wall=0.2)
    here, n, contact = retrace(arm, np.zeros(2), path, 0.03, 0.015, _light, 0.3)
    assert contact and 0.2 <= arm.pos[0] + 0.015 <= 0.23 + 1e-9 and arm.moves[-1][0] == pytest.approx(-0.015)
    arm = ClutterArm(light_from=0.05, wall=0.2)
    here, n, contact = retrace(arm, np.zeros(2), path, 0.03, 0.015)  # without: it stops at the light object
    assert contact and arm.pos[0] + 0.015 < 0.09
    arm = ClutterArm(light_from=0.05, slips_at=0.12, wall=5.0)
    here, n, contact = retrace(arm, np.zeros(2), path, 0.03, 0.015, _light, 0.3)
    assert not contact and here[0] == pytest.approx(0.3)  # the object slid aside: the transit reached its end


def test_a_push_still_under_way_at_the_moves_limit_is_a_contact_and_backs_off():
    arm = ClutterArm(light_from=0.1, wall=5.0)
    (here, n, contact, travel), p = _move(arm, 0.15, predicted=(0.15,))  # gives up 4 cm past 0.15 m
    assert contact and 0.1 <= travel <= 0.1 + p.coarse_step
    assert arm.moves[-1][0] == pytest.approx(-p.backoff) and arm.pos[0] + p.backoff <= 0.19 + p.fine_step + 1e-9
