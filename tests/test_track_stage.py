"""The `track` stage on tables (pipeline/track/stage.py): rows, carried columns, per-run random streams, jobs."""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from pipeline import schema
from pipeline.seeds import run_key, run_rng
from pipeline.track.soft import SoftTracker, SoftTrackingParams
from pipeline.track.stage import TrackConfig, track_table

DISC = "disc:0.05"
CONFIG = TrackConfig(robot=DISC, params=dict(n_particles=16))


def contacts(rows, **extra):
    """rows: (run, step, ee_x, ee_y, contact (x, y) or None, d (dx, dy) or None, object_id); extra columns as
    lists."""
    def opt(i, k):
        return pa.array([None if r[i] is None else float(r[i][k]) for r in rows], pa.float64())

    cols = {
        "run": pa.array([r[0] for r in rows], pa.string()),
        "step": pa.array([r[1] for r in rows], pa.int64()),
        "ee_x_m": pa.array([float(r[2]) for r in rows]),
        "ee_y_m": pa.array([float(r[3]) for r in rows]),
        "in_contact": pa.array([r[4] is not None for r in rows]),
        "contact_x_m": opt(4, 0), "contact_y_m": opt(4, 1), "dx_m": opt(5, 0), "dy_m": opt(5, 1),
        "object_id": pa.array([r[6] for r in rows], pa.int64()),
    }
    cols.update({k: pa.array(v) for k, v in extra.items()})
    return schema.validate_contacts(pa.table(cols))


def push_run(run, x0=0.0, n=4, free_every=2):
    """The disc pushing one object in +x, 1 cm per step, touching it at (x + 0.05, y); free steps in between."""
    rows, x, step = [], x0, 0
    for i in range(n):
        x += 0.01
        rows.append((run, step, x, 0.0, (x + 0.05, 0.002 * i), (0.01, 0.0), 0))
        step += 1
        if (i + 1) % free_every == 0:
            rows.append((run, step, x - 0.1, 0.3, None, None, -1))
            step += 1
    return rows


def rows_of(table, run):
    return table.filter(pc.equal(table["run"], run))


# ------------------------------------------------------------------------------------------------ rows
def test_tracks_and_diagnostics_rows_validate_and_follow_the_contacts():
    t = contacts(push_run("a") + push_run("b", x0=1.0))
    tracks, diag = track_table(t, CONFIG, seed=0)
    schema.validate_tracks(tracks)
    schema.validate_diagnostics(diag)
    assert tracks.num_rows == 8 and diag.num_rows == t.num_rows
    assert tracks.column("run").to_pylist() == ["a"] * 4 + ["b"] * 4
    np.testing.assert_array_equal(tracks.column("step").to_numpy(), [0, 1, 3, 4] * 2)
    np.testing.assert_array_equal(tracks.column("estimate_step").to_numpy(), [5] * 8)  # the run's last step
    np.testing.assert_array_equal(diag.column("n_contacts").to_numpy(),
                                  t.column("in_contact").to_numpy(zero_copy_only=False).astype(int))
    assert diag.column("in_contact").equals(t.column("in_contact"))


def test_stage_output_is_the_map_particle_of_a_tracker_fed_the_same_stream(disc):
    t = contacts(push_run("only", n=6))
    tracks, _ = track_table(t, CONFIG, seed=4)
    tracker = SoftTracker(disc, SoftTrackingParams(n_particles=16), rng=run_rng(4, "only"))
    for r in t.to_pylist():
        if r["in_contact"]:
            tracker.update([r["ee_x_m"], r["ee_y_m"]], [[r["dx_m"], r["dy_m"]]], [[r["contact_x_m"], r["contact_y_m"]]])
        else:
            tracker.update([r["ee_x_m"], r["ee_y_m"]])
    np.testing.assert_array_equal(np.c_[tracks.column("x_m").to_numpy(), tracks.column("y_m").to_numpy()],
                                  tracker.points_)
    np.testing.assert_array_equal(tracks.column("tracker_label").to_numpy(), tracker.labels())


def test_several_contacts_per_step_get_contact_index_0_to_k_minus_1():
    rows = [
        ("r", 0, 0.0, 0.0, (0.05, 0.0), (0.01, 0.0), 0),
        ("r", 0, 0.0, 0.0, (0.0, 0.05), (0.01, 0.0), 1),
        ("r", 0, 0.0, 0.0, (-0.05, 0.0), (0.01, 0.0), 2),
        ("r", 1, 0.5, 0.5, None, None, -1),
        ("r", 2, 0.5, 0.5, (0.55, 0.5), (0.0, 0.01), 0),
        ("r", 2, 0.5, 0.5, (0.5, 0.55), (0.0, 0.01), 1),
    ]
    tracks, diag = track_table(contacts(rows), CONFIG, seed=1)
    np.testing.assert_array_equal(tracks.column("step").to_numpy(), [0, 0, 0, 2, 2])
    np.testing.assert_array_equal(tracks.column("contact_index").to_numpy(), [0, 1, 2, 0, 1])
    np.testing.assert_array_equal(tracks.column("object_id").to_numpy(), [0, 1, 2, 0, 1])
    np.testing.assert_array_equal(diag.column("step").to_numpy(), [0, 1, 2])
    np.testing.assert_array_equal(diag.column("n_contacts").to_numpy(), [3, 0, 2])


def test_extra_columns_are_carried_to_the_matching_contact_rows():
    # rows of the two runs interleave, so a carried value must follow its row, not its position
    a, b = push_run("a"), push_run("b", x0=1.0)
    rows = [r for pair in zip(a, b) for r in pair]
    tag = [f"{r[0]}-{r[1]}" for r in rows]
    weight = [float(i) for i in range(len(rows))]
    t = contacts(rows, tag=tag, weight_kg=weight)
    tracks, _ = track_table(t, CONFIG, seed=0)
    assert tracks.column_names[-3:] == ["object_id", "tag", "weight_kg"]
    for r in tracks.to_pylist():
        assert r["tag"] == f"{r['run']}-{r['step']}"
        src = rows.index(next(x for x in rows if x[0] == r["run"] and x[1] == r["step"]))
        assert r["weight_kg"] == weight[src]
        assert r["object_id"] == rows[src][6]
    # the consumed contact columns are not carried
    assert not {"ee_x_m", "contact_x_m", "dx_m", "in_contact"} & set(tracks.column_names)


def test_extra_column_named_like_a_tracks_column_is_refused():
    # A carried column named x_m would silently replace the tracked positions: refuse it by name instead.
    t = contacts(push_run("a"))
    clash = t.append_column("x_m", pa.array(np.full(t.num_rows, 123.0)))
    with pytest.raises(ValueError, match="'x_m'.*rename"):
        track_table(clash, CONFIG, seed=0)


def test_run_without_contacts_gives_no_track_rows_but_diagnostics_rows():
    free = [("idle", s, 0.1 * s, 0.0, None, None, -1) for s in range(5)]
    tracks, diag = track_table(contacts(free + push_run("busy")), CONFIG, seed=0)
    assert set(tracks.column("run").to_pylist()) == {"busy"}
    idle = rows_of(diag, "idle")
    np.testing.assert_array_equal(idle.column("step").to_numpy(), np.arange(5))
    assert not any(idle.column("in_contact").to_pylist()) and all(x == 1.0 for x in idle.column("ess").to_pylist())
    # only free-space runs: an empty but valid tracks table
    tracks, diag = track_table(contacts(free), CONFIG, seed=0)
    assert tracks.num_rows == 0 and diag.num_rows == 5
    schema.validate_tracks(tracks)


def test_empty_contacts_table():
    t = contacts(push_run("a")).slice(0, 0)
    tracks, diag = track_table(t, CONFIG, seed=0)
    assert tracks.num_rows == 0 and diag.num_rows == 0
    schema.validate_tracks(tracks)


def test_every_step_writes_an_estimate_after_each_step_once_there_are_points():
    t = contacts([("f", 0, 0.3, 0.3, None, None, -1)] + [(r[0], r[1] + 1, *r[2:]) for r in push_run("f")])
    config = TrackConfig(robot=DISC, params=dict(n_particles=16), every_step=True)
    tracks, _ = track_table(t, config, seed=0)
    schema.validate_tracks(tracks)
    est = tracks.column("estimate_step").to_numpy()
    # step 0 is free space with no points yet: no estimate; after step s, one row per contact observed so far
    assert sorted(set(est)) == [1, 2, 3, 4, 5, 6]
    np.testing.assert_array_equal([np.sum(est == s) for s in range(1, 7)], [1, 2, 2, 3, 4, 4])
    final = tracks.filter(pc.equal(tracks["estimate_step"], 6))
    last_only, _ = track_table(t, TrackConfig(robot=DISC, params=dict(n_particles=16)), seed=0)
    assert final.equals(last_only)


# ------------------------------------------------------------------------------------------------ random streams
def test_run_rng_is_per_run_and_stable():
    assert run_key("a") == run_key("a") != run_key("b")
    assert 0 <= run_key("scene-1/seed-3") < 2**64
    assert run_rng(3, "a").random() == run_rng(3, "a").random()
    assert run_rng(3, "a").random() != run_rng(3, "b").random()
    assert run_rng(3, "a").random() != run_rng(4, "a").random()


def test_results_do_not_depend_on_run_order():
    a, b = push_run("a", n=6), push_run("b", x0=1.0, n=6)
    ab, _ = track_table(contacts(a + b), CONFIG, seed=5)
    ba, _ = track_table(contacts(b + a), CONFIG, seed=5)
    assert rows_of(ab, "a").equals(rows_of(ba, "a")) and rows_of(ab, "b").equals(rows_of(ba, "b"))


def test_jobs_one_and_two_give_equal_tables():
    t = contacts(push_run("a", n=6) + push_run("b", x0=1.0, n=6))
    one, d1 = track_table(t, CONFIG, seed=9, jobs=1)
    two, d2 = track_table(t, CONFIG, seed=9, jobs=2)
    assert one.equals(two)
    # diagnostics hold wall times: equal apart from update_ms
    assert d1.drop_columns(["update_ms"]).equals(d2.drop_columns(["update_ms"]))


def test_unknown_method_is_refused():
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        TrackConfig(method="nope")


def test_bad_tracker_params_surface_as_value_error():
    with pytest.raises(ValueError, match="n_particles must be a positive integer"):
        track_table(contacts(push_run("a")), TrackConfig(robot=DISC, params=dict(n_particles=0)), seed=0)


def test_warm_up_loads_the_kernels_once_per_process_and_changes_no_result(tmp_path):
    """Kernel compilation or cache loading happens before the timed updates (issue 12), once per process and
    (method, robot), with its own random stream: the tracks of a run are the same with or without it."""
    from pipeline import schema
    from pipeline.robot import load_robot
    from pipeline.track import stage

    config = stage.TrackConfig(method="stucco", robot="disc:0.05")
    robot = load_robot(config.robot)
    (run, contacts), = schema.contacts_by_run(schema.read_contacts(stage.WARM_UP_LOG))
    stage._WARM.discard(("stucco", "disc:0.05"))
    warm = stage.track_run(run, contacts, config, robot, seed=3)
    assert ("stucco", "disc:0.05") in stage._WARM
    assert stage.warm_up(config, robot) == 0.0  # already warm
    again = stage.track_run(run, contacts, config, robot, seed=3)
    for k in warm.tracks:
        np.testing.assert_array_equal(warm.tracks[k], again.tracks[k])
    assert stage.warm_up(stage.TrackConfig(method="birch", robot="disc:0.05"), robot) == 0.0  # no kernels
