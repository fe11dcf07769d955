"""collect: short scripted runs touch the expected objects, each effect switches off, runs are deterministic."""
from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import schema
from pipeline.collect import (
    RUN_KIND,
    action_label,
    collect,
    collect_run,
    discard_reason,
    output_path,
    parse_seeds,
    representative_force,
)
from pipeline.scenes import load_scene
from pipeline.schema import read_metadata

N = 3  # actions per short run: ~0.1 s each


def _run(name="FB", seed=0, n=N, policy="scripted", **effects):
    scene = load_scene(name)
    if effects:
        scene = scene.with_effects(**effects)
    return collect_run(scene, seed, policy=policy, max_actions=n)


@pytest.fixture(scope="module")
def fb():
    return _run()


# ------------------------------------------------------------------------------------------------ kernels


@pytest.mark.parametrize("text, seeds", [("0-3", [0, 1, 2, 3]), ("7", [7]), ("5,1-2,5", [1, 2, 5])])
def test_parse_seeds(text, seeds):
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["", "a", "3-1", "1-", "-2"])
def test_parse_seeds_rejects_bad_ranges(text):
    with pytest.raises(ValueError, match="seed range"):
        parse_seeds(text)


def test_action_label_ties_go_to_no_contact():
    ids = np.full(315, -1)
    ids[:160] = 2  # 8 buckets with contact, 8 without: a tie -> -1
    assert action_label(ids) == -1
    ids[:180] = 2  # 9 buckets
    assert action_label(ids) == 2


def test_action_label_uses_last_contact_of_each_bucket():
    ids = np.full(315, 1)
    ids[19::20] = 3  # the last step of every bucket sees object 3
    assert action_label(ids) == 3


def test_representative_force_is_the_median_bucket_sample():
    w = np.zeros((315, 6))
    mags = np.arange(16.0)
    w[5::20, 0] = mags
    np.testing.assert_array_equal(representative_force(w), [8.0, 0.0])  # upper median of 16


@pytest.mark.parametrize("labels, force, reason", [
    ([-1, -1, -1], 1.0, "fewer than 2 distinct labels"),
    ([0] + [-1] * 40, 1.0, "in contact less than 5%"),
    ([0, -1, -1], 1.0, "fewer than 2 in-contact actions"),
    ([0, 0, -1], 0.05, "fewer than 2 distinct labels"),  # weak forces do not count as contact
    ([0, 1, -1], 1.0, None),
])
def test_discard_rule(labels, force, reason):
    fr = np.column_stack([np.full(len(labels), force), np.zeros(len(labels))])
    got = discard_reason(np.array(labels), fr)
    assert (got is None) if reason is None else reason in got


# ------------------------------------------------------------------------------------------------ runs


@pytest.mark.parametrize("name, touched", [
    ("FB", {"cracker_box"}),
    ("BC", {"tomato_can", "master_chef_can"}),
    ("IB", {"cracker_box", "tomato_can"}),
    ("TC", {"master_chef_can"}),
])
def test_short_scripted_run_touches_expected_objects(name, touched):
    table, params, res = _run(name, n=5)
    assert set(res.touched) == touched
    assert table.column("in_contact").to_numpy(zero_copy_only=False).any()


def test_run_table_columns_and_shapes(fb):
    table, params, res = fb
    assert tuple(table.column_names) == schema.SIM_RUN.required_names  # no probe column
    assert table.num_rows == N == res.n_actions
    assert table.column("step").to_pylist() == list(range(N))
    assert table.schema.field("win_wrench").type.list_size == 8
    assert params["bodies"][0] == "cracker_box" and params["bodies"][-1] == "wall_left"
    # executed + start = end, commanded = action * 0.03 (noise included)
    t = table.to_pydict()
    np.testing.assert_allclose(np.add(t["ee_start_x_m"], t["exec_dx_m"]), t["ee_x_m"])
    np.testing.assert_allclose(np.multiply(t["cmd_ux"], 0.03), t["cmd_dx_m"])
    # contact displacement exactly when in contact
    for inc, cdx in zip(t["in_contact"], t["contact_dx_m"]):
        assert (cdx is not None) == inc


def test_noise_is_within_the_amplitude_and_differs_between_seeds():
    a, _, _ = _run(seed=0, n=N)
    b, _, _ = _run(seed=1, n=N)
    seq = np.asarray(load_scene("FB").actions[:N])
    for t in (a, b):
        u = np.column_stack([t.column("cmd_ux").to_numpy(), t.column("cmd_uy").to_numpy()])
        assert np.all(np.abs(u - seq) <= 0.5e-3 / 0.03 + 1e-12)
    assert not np.array_equal(a.column("cmd_ux").to_numpy(), b.column("cmd_ux").to_numpy())


def _physical(table) -> bytes:
    """The table's bytes without the columns naming the run (bit-identity, NaN included)."""
    import pyarrow as pa

    sink = pa.BufferOutputStream()
    t = table.drop_columns(["run", "seed"])
    with pa.ipc.new_stream(sink, t.schema) as w:
        w.write_table(t)
    return sink.getvalue().to_pybytes()


def test_scene_without_noise_replays_bit_identically():
    a, _, _ = _run(seed=0, noise_mm=0.0)
    b, _, _ = _run(seed=1, noise_mm=0.0)
    assert _physical(a) == _physical(b)
    np.testing.assert_array_equal(a.column("cmd_ux").to_numpy(),
                                  np.asarray(load_scene("FB").actions[:N])[:, 0])


def test_same_seed_gives_byte_identical_parquet_serial_and_parallel(tmp_path):
    scene = load_scene("FB")
    collect(scene, [4, 5], tmp_path / "a", max_actions=2, jobs=1, progress=True)
    collect(scene, [4, 5], tmp_path / "b", max_actions=2, jobs=2, progress=True)
    for s in (4, 5):
        fa = output_path(tmp_path / "a", "FB", s).read_bytes()
        assert fa == output_path(tmp_path / "b", "FB", s).read_bytes()
    meta = read_metadata(output_path(tmp_path / "a", "FB", 4))
    assert meta["schema"] == RUN_KIND and meta["stage"] == "collect"
    assert meta["params"]["seed_sequence"][2] == 4 and meta["params"]["effects"]["noise_mm"] == 0.5


# ------------------------------------------------------------------------------------------------ effects


def test_effect_off_static_objects_never_move():
    table, params, _ = _run(movable=())
    poses = np.asarray(table.column("obj_pose").to_pylist())
    init = np.asarray(params["initial"]["obj_pose"])
    np.testing.assert_allclose(poses, np.broadcast_to(init, poses.shape), atol=1e-12)


def test_effect_on_movable_objects_are_pushed(fb):
    table, params, _ = fb
    poses = np.asarray(table.column("obj_pose").to_pylist())
    init = np.asarray(params["initial"]["obj_pose"])
    assert np.abs(poses[-1, 0] - init[0]).max() > 1e-3  # the cracker box moved


def test_effect_off_wrench_means_no_detection(fb):
    table, _, _ = _run(wrench=False)
    assert np.all(np.isnan(np.asarray(table.column("win_wrench").to_pylist())))
    assert not table.column("in_contact").to_numpy(zero_copy_only=False).any()
    # ground truth is still recorded, and the motion is the same (sensing does not act on physics)
    assert table.column("object_id").to_pylist() == fb[0].column("object_id").to_pylist()
    assert table.column("ee_x_m").equals(fb[0].column("ee_x_m"))


def test_effect_off_contact_truth_means_no_labels(fb):
    table, _, _ = _run(contact_truth=False)
    assert set(table.column("object_id").to_pylist()) == {-1}
    assert table.column("true_contact_x_m").null_count == table.num_rows
    assert table.column("in_contact").equals(fb[0].column("in_contact"))


def test_effect_off_walls_are_not_built():
    table, params, _ = _run(walls=False, n=1)
    poses = np.asarray(table.column("obj_pose").to_pylist())[0]
    walls = [i for i, b in enumerate(params["bodies"]) if b.startswith("wall")]
    assert len(walls) == 3 and np.all(np.isnan(poses[walls])) and np.all(np.isfinite(poses[:walls[0]]))


def test_effect_off_settling_leaves_spawn_poses():
    from pipeline.sim import World

    scene = load_scene("FB")
    with World(scene.with_effects(settle_steps=0)) as w:
        spawn = w.object_poses()
    with World(scene) as w:
        settled = w.object_poses()
    # spawned overlapping, the tomato can is pushed away from the box while settling (as in the authors' scene)
    assert np.hypot(*(settled[1, :2] - spawn[1, :2])) > 5e-3


def test_effect_off_friction_keeps_defaults():
    import pybullet as p

    from pipeline.sim import World

    scene = load_scene("FB").with_effects(settle_steps=0)
    for friction, plane, finger, _box in ((True, 0.6, 2.0, 0.5), (False, 1.0, 1.0, 0.5)):
        with World(scene.with_effects(friction=friction)) as w:
            c = w.client
            assert p.getDynamicsInfo(w.plane, -1, physicsClientId=c)[1] == pytest.approx(plane)
            assert p.getDynamicsInfo(w.gripper.body, 0, physicsClientId=c)[1] == pytest.approx(finger)
            spin = p.getDynamicsInfo(w.plane, -1, physicsClientId=c)[7]
            assert spin == pytest.approx(0.01 if friction else 0.0)


def test_world_uses_its_own_direct_client_and_closes_it():
    """Each open world has its own DIRECT client; closing empties it (kept as a spare for the next world of the
    process, at most _MAX_SPARE of them) or disconnects it, and a closed world's client id is -1."""
    import pybullet as p

    from pipeline.sim import World
    from pipeline.sim import world as world_module

    scene = load_scene("FB").with_effects(settle_steps=0)
    worlds = [World(scene) for _ in range(world_module._MAX_SPARE + 1)]
    clients = [w.client for w in worlds]
    assert len(set(clients)) == len(clients)
    assert all(p.getConnectionInfo(c)["connectionMethod"] == p.DIRECT for c in clients)
    assert all(p.getNumBodies(physicsClientId=c) > 0 for c in clients)
    for w in worlds:
        w.close()
        w.close()  # idempotent
        assert w.client == -1
    kept = [c for c in clients if p.isConnected(c)]
    assert 0 < len(kept) <= world_module._MAX_SPARE
    assert all(p.getNumBodies(physicsClientId=c) == 0 for c in kept)
    with World(scene) as again:
        assert again.client in kept  # a spare client is reused
        assert p.getNumBodies(physicsClientId=again.client) == len(again.body_of) + 2  # + plane, gripper


# ------------------------------------------------------------------------------------------------ greedy walk


def test_greedy_walk_short_run_respects_the_start_goal_rule():
    table, params, res = _run("SELECT4", seed=7, n=4, policy="greedy-walk")
    start = np.asarray(params["initial"]["ee_xy_m"])
    goal = np.asarray(params["goal_xy_m"])
    assert np.linalg.norm(goal - start) >= 0.7 and np.all(np.abs(goal) <= 0.7)
    assert 1 <= table.num_rows <= 4
    u = np.column_stack([table.column("cmd_ux").to_numpy(), table.column("cmd_uy").to_numpy()])
    assert np.all(np.abs(u) <= 1.0)
    # free space at first: the greedy choice heads toward the goal
    d0 = np.linalg.norm(goal - start)
    d1 = np.linalg.norm(goal - np.array([table.column("ee_x_m")[0].as_py(), table.column("ee_y_m")[0].as_py()]))
    assert d1 < d0 - 0.02
    again, _, _ = _run("SELECT4", seed=7, n=4, policy="greedy-walk")
    assert _physical(again) == _physical(table)


def test_scripted_policy_needs_a_sequence():
    from pipeline.scenes import SceneError

    with pytest.raises(SceneError, match=r"SELECT1\.toml: key 'actions'"):
        _run("SELECT1", n=1)


# ------------------------------------------------------------------------------------------------ CLI


def _cli():
    import stucco_cli.sim  # noqa: F401
    from stucco_cli.main import cli

    return cli


def test_cli_collect_writes_one_file_per_seed_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "runs"
    args = ["-q", "collect", "--scene", "FB", "--seeds", "0-1", "--max-actions", "1", "--out", str(out)]
    res = CliRunner().invoke(_cli(), args)
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["FB-000.parquet", "FB-001.parquet"]
    assert pq.read_table(out / "FB-000.parquet").num_rows == 1
    res = CliRunner().invoke(_cli(), args)
    assert res.exit_code == 1 and "FB-000.parquet: exists (--out); pass --force-overwrite" in res.stderr
    res = CliRunner().invoke(_cli(), args + ["--force-overwrite"])
    assert res.exit_code == 0


def test_cli_collect_bad_seeds_is_a_usage_error(tmp_path):
    res = CliRunner().invoke(_cli(), ["collect", "--scene", "FB", "--seeds", "9-1", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--seeds" in res.stderr


def test_cli_collect_wrong_policy_for_scene_names_file_and_key(tmp_path):
    res = CliRunner().invoke(_cli(), ["collect", "--scene", "SELECT1", "--policy", "scripted", "--out",
                                      str(tmp_path)])
    assert res.exit_code == 1 and "SELECT1.toml: key 'actions'" in res.stderr


def test_advance_ends_where_act_ends():
    """World.advance (the grasp's unobserved action) steps exactly as act: the same gripper and object states,
    to the bit, after pushing the box (reading poses and contacts does not change the simulation)."""
    from pipeline.sim import World

    scene = load_scene("FB")
    states = []
    for observed in (True, False):
        with World(scene) as w:
            for dx, dy in [(0.03, 0.0)] * 6 + [(0.0, 0.03), (-0.02, 0.01)]:
                (w.act if observed else w.advance)(dx, dy)
            states.append((w.gripper_pose()[0], w.object_poses()))
    np.testing.assert_array_equal(states[0][0], states[1][0])
    np.testing.assert_array_equal(states[0][1], states[1][1])
    with World(scene) as w:
        assert np.any(states[0][1] != w.object_poses())  # the actions did push something
