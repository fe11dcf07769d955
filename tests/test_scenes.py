"""Scene files: every shipped scene loads and builds; malformed files fail with one line naming file and key."""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.scenes import SCENE_DIR, Effects, SceneError, load_scene, scene_hash, scene_names

ALL = scene_names()
BOR_LENGTHS = {"FB": 54, "BC": 102, "IB": 44, "TC": 40}
# Net commanded displacement of each hand-made sequence (docs/simulation.md, "`stucco collect`").
BOR_NET = {"FB": (0.396, -0.132), "BC": (0.15, 0.0), "IB": (0.09, -0.12), "TC": (0.15, -0.12)}


def test_all_expected_scenes_are_shipped():
    assert set(ALL) == {"FB", "BC", "IB", "TC", "REAL", "SELECT1", "SELECT2", "SELECT3", "SELECT4"}


@pytest.mark.parametrize("name", ALL)
def test_scene_loads_with_consistent_fields(name):
    s = load_scene(name)
    assert s.name == name and s.description and "\n" not in s.description
    assert len(set(s.body_names)) == len(s.body_names)
    if s.kind == "retrieval":
        assert s.target is not None and s.gripper_start is not None and len(s.walls) == 3
        assert s.effects.noise_mm == 0.5  # the paper's figure, not the code's 0.075 mm
    else:
        assert s.walk is not None and s.actions is None and s.effects.noise_mm == 0.0


@pytest.mark.parametrize("name", sorted(BOR_LENGTHS))
def test_retrieval_sequences_match_the_reference(name):
    s = load_scene(name)
    a = np.asarray(s.actions)
    assert len(a) == BOR_LENGTHS[name]
    np.testing.assert_allclose(a.sum(axis=0) * s.action_scale, BOR_NET[name], atol=1e-9)
    assert np.all(np.abs(a) <= 1.0)


def test_task_targets_and_masses():
    assert load_scene("FB").target.mass == 10.0 and load_scene("FB").target.name == "cracker_box"
    tc = load_scene("TC")
    assert tc.target.name == "tomato_can" and tc.target.mass == 2.0 and tc.target.size == (0.039, 0.122)
    assert next(o for o in tc.objects if o.name == "cracker_box").mass == 0.411


@pytest.mark.parametrize("name", ALL)
def test_scene_builds_in_pybullet(name):
    from pipeline.sim import World

    s = load_scene(name).with_effects(settle_steps=0)
    with World(s, gripper_start=s.gripper_start or (5.0, 5.0)) as w:
        poses = w.object_poses()
        assert poses.shape == (len(s.body_names), 3) and np.all(np.isfinite(poses))
        # spawned where the file says: the inertial frame is the link frame plus the rotated COM offset
        for o, (x, y, _) in zip(s.objects, poses):
            c, sn = math.cos(o.yaw), math.sin(o.yaw)
            cx, cy = o.com_offset[0], o.com_offset[1]
            if o.rp == (0.0, 0.0):
                assert (x, y) == pytest.approx((o.position[0] + c * cx - sn * cy, o.position[1] + sn * cx + c * cy),
                                               abs=1e-9)


def test_scene_hash_is_stable():
    # pinned: changing it silently changes every job's random stream
    assert scene_hash("FB") == 1906274663 != scene_hash("BC")


def test_with_effects_replaces_only_named_effects():
    s = load_scene("FB").with_effects(noise_mm=0.0, walls=False)
    assert s.effects == Effects(noise_mm=0.0, walls=False)
    with pytest.raises(SceneError, match=r"FB\.toml: \[effects\]"):
        load_scene("FB").with_effects(gravity=0)


def test_unknown_scene_names_file_and_known_scenes():
    with pytest.raises(SceneError, match=r"XX\.toml: unknown scene 'XX' \(known: BC, FB"):
        load_scene("XX")


GOOD = """
name = "T"
kind = "retrieval"
description = "test"
[gripper]
start = [0.0, 0.0]
[actions]
sequence = [[1, 0]]
[[objects]]
name = "a"
shape = "box"
size = [0.1, 0.1, 0.1]
position = [0.2, 0.0]
mass = 1.0
target = true
"""


@pytest.mark.parametrize("edit, match", [
    (lambda t: t + "\n[broken", r"bad\.toml: not valid TOML"),
    (lambda t: t.replace('mass = 1.0', 'mass = -1.0'), r"bad\.toml: key 'objects\[0\]\.mass': expected a positive"),
    (lambda t: t.replace('mass = 1.0', 'mass = "heavy"'), r"key 'objects\[0\]\.mass': expected a finite number"),
    (lambda t: t.replace('shape = "box"', 'shape = "sphere"'), r"key 'objects\[0\]\.shape': expected one of box"),
    (lambda t: t.replace('size = [0.1, 0.1, 0.1]', 'size = [0.1, 0.1]'),
     r"key 'objects\[0\]\.size': expected a list of 3"),
    (lambda t: t.replace('position = [0.2, 0.0]\n', ''), r"key 'objects\[0\]\.position': missing"),
    (lambda t: t.replace('sequence = [[1, 0]]', 'sequence = [[2, 0]]'),
     r"key 'actions\.sequence\[0\]': expected \[u_x, u_y\]"),
    (lambda t: t.replace('kind = "retrieval"', 'kind = "retrieval"\ncolour = 3'), r"key 'colour': unknown key"),
    (lambda t: t + '[effects]\nmovable = ["b"]\n', r"key 'effects\.movable': no object named 'b'"),
    (lambda t: t + '[effects]\nwrench = 1\n', r"key 'effects\.wrench': expected true or false"),
    (lambda t: t.replace('target = true', 'target = false'), r"key 'objects': a retrieval scene needs exactly one"),
    (lambda t: t.replace('sequence = [[1, 0]]', 'sequence = [[1, 0]]\nstop_force_n = 10.0'),
     r"key 'actions\.stop_force_n': a force limit needs replay = \"guarded\""),
    (lambda t: t.replace('sequence = [[1, 0]]', 'sequence = [[1, 0]]\nreplay = "guarded"\nstop_force_n = -1'),
     r"key 'actions\.stop_force_n': expected a positive number"),
])
def test_malformed_scene_file_names_file_and_key(tmp_path, edit, match):
    path = tmp_path / "bad.toml"
    path.write_text(edit(GOOD))
    with pytest.raises(SceneError, match=match) as info:
        load_scene(path)
    assert "\n" not in str(info.value)


def test_good_minimal_scene_parses_with_default_effects(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text(GOOD)
    s = load_scene(path)
    assert s.effects == Effects() and s.objects[0].spawn_z == pytest.approx(0.05)


def _cli():
    import stucco_cli.sim  # noqa: F401  (registered by main's _register once wired)
    from stucco_cli.main import cli

    return cli


def test_cli_scenes_lists_every_scene_with_description():
    res = CliRunner().invoke(_cli(), ["scenes"])
    assert res.exit_code == 0, res.output
    lines = res.stdout.strip().splitlines()
    assert [ln.split()[0] for ln in lines] == ALL
    assert all(len(ln.split()) > 3 for ln in lines)


def test_cli_unknown_scene_is_a_one_line_error(tmp_path):
    res = CliRunner().invoke(_cli(), ["collect", "--scene", "NOPE", "--out", str(tmp_path)])
    assert res.exit_code == 1
    assert "NOPE.toml: unknown scene 'NOPE'" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_cli_malformed_scene_file_is_a_one_line_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace("mass = 1.0", "mass = 0"))
    res = CliRunner().invoke(_cli(), ["collect", "--scene", str(path), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert f"{path}: key 'objects[0].mass': expected a positive number" in res.stderr


def test_scene_dir_is_inside_the_repository():
    assert (SCENE_DIR / "FB.toml").is_file()
