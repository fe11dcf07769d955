"""The retrieval scene generator (docs/scene_generator.md) and the ``[target_region]`` scene key.

Deterministic from (seed, index); scenes at rest after settling; the target region holds the target; the rummage is
made from the region, the gripper start and the walls only, and pokes from every side the walls leave open; bad
knobs refused in one line; a generated file collects.
pybullet work is kept to a handful of scenes (a settle is about 0.05 s, a collected action about 0.04 s).
"""
from __future__ import annotations

import inspect
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
from click.testing import CliRunner

from pipeline.scenes import WORKSPACE_M, SceneError, load_scene, scene_from_text
from pipeline.scenes.catalogue import MODEL_BY_KEY, MODELS, TASK_WALLS
from pipeline.scenes.coverage import FAR_SLACK_M, SIDE_CLEARANCE_M, SIDES, coverage_passes, coverage_waypoints, lanes
from pipeline.scenes.footprint import GRIPPER_OUTLINE_M, hidden_fraction, object_outline, separation, wall_outline
from pipeline.scenes.generate import GAP_MIN_M, DrawRejected, GeneratorSpec, GeneratorSpecError, sample_layout
from pipeline.scenes.generated_toml import STOP_FORCE_N, layout_actions
from pipeline.sim import World
from pipeline.sim.generate import generate_scenes, iter_generated, settle_problem
from stucco_cli.main import cli

SPEC = GeneratorSpec()


def _first_layouts(seed: int, indices, spec: GeneratorSpec = SPEC):
    """The first draw of each index that keeps the layout rules (no pybullet)."""
    out = []
    for i in indices:
        for d in range(200):
            try:
                out.append(sample_layout(seed, i, d, spec))
                break
            except DrawRejected:
                continue
    return out


@pytest.fixture(scope="module")
def batch():
    """Scenes 0-3 of seed 11, checked after settling (the handful the pybullet tests share)."""
    return list(iter_generated(4, 11, spec=SPEC))


# -- determinism ------------------------------------------------------------------------------------------------


def test_same_seed_gives_byte_identical_files(batch):
    again = generate_scenes(4, 11, spec=SPEC)
    assert again == [(g.name, g.text) for g in batch]
    assert [n for n, _ in again] == ["GEN_00000", "GEN_00001", "GEN_00002", "GEN_00003"]
    assert generate_scenes(1, 12, spec=SPEC)[0][1] != batch[0].text


def test_a_scene_does_not_depend_on_where_its_batch_starts(batch):
    assert generate_scenes(1, 11, spec=SPEC, first=3) == [(batch[3].name, batch[3].text)]
    assert generate_scenes(2, 11, spec=SPEC, first=2)[1] == (batch[3].name, batch[3].text)


# -- at rest after settling ----------------------------------------------------------------------------------------


def _com_xy(o) -> np.ndarray:
    """Where pybullet reports an object spawned at rest: its link frame plus the turned COM offset, metres."""
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    x, y = o.com_offset[:2]
    return np.array([o.position[0] + c * x - s * y, o.position[1] + s * x + c * y])


def test_generated_scenes_are_at_rest_and_apart_after_settling(batch):
    for g in batch:
        scene = scene_from_text(g.text, Path(f"{g.name}.toml"))
        with World(scene) as world:  # settles as collect does
            poses = world.object_poses()
            for i, o in enumerate(scene.objects):
                assert np.linalg.norm(poses[i, :2] - _com_xy(o)) < 0.005, (g.name, o.name)
            bodies = sorted(world.body_of.items())
            for k, (i, a) in enumerate(bodies):
                for j, b in bodies[k + 1:]:
                    if min(i, j) >= len(scene.objects):  # the tasks' walls meet at the corners
                        continue
                    pts = p.getClosestPoints(a, b, 0.0, physicsClientId=world.client)
                    assert min((pt[8] for pt in pts), default=0.0) > -0.001, (g.name, i, j)
            assert not any(p.getClosestPoints(world.gripper.body, b, 0.0, physicsClientId=world.client)
                           for b in world.body_of.values()), g.name


def test_the_settling_check_finds_overlap_motion_and_a_blocked_start(batch):
    assert "overlap" in settle_problem(load_scene("FB"))  # FB's box and can are spawned overlapping
    scene = scene_from_text(batch[0].text, Path("x.toml"))
    floating = replace(scene, objects=(replace(scene.objects[0], z=0.3),) + scene.objects[1:])
    assert "moved" in settle_problem(floating)
    blocked = replace(scene, gripper_start=scene.objects[1].centre_xy)
    assert "gripper starts touching" in settle_problem(blocked)
    assert settle_problem(scene) is None


def test_layouts_keep_their_rules():
    spec = GeneratorSpec(hiddenness=0.6, clutter_density=0.8)
    layouts = _first_layouts(3, range(12), spec)
    assert len(layouts) == 12
    for lay in layouts:
        polys = [object_outline(o) for o in lay.objects]
        assert lay.hidden >= 0.6 and hidden_fraction(lay.start, polys[0], polys[1:]) == lay.hidden
        assert 2 <= len(lay.objects) - 1 <= 6 and lay.placement in ("behind", "between", "beside")
        assert all(separation(a, b) >= GAP_MIN_M - 1e-3 for k, a in enumerate(polys) for b in polys[k + 1:])
        # The gripper starts in front of the clutter: its fingertips before every object.
        assert lay.start[0] + GRIPPER_OUTLINE_M[1][0] < min(q[:, 0].min() for q in polys)
    kinds = [lay.objects[0].name for lay in layouts]
    assert kinds == ["cracker_box", "tomato_can"] * 6  # mix: box for even indices, can for odd


# -- the target region --------------------------------------------------------------------------------------------


def test_the_region_holds_the_target_and_comes_from_the_clutter(batch):
    for g in batch:
        scene = scene_from_text(g.text, Path("x.toml"))
        (x0, y0), (x1, y1) = scene.target_region
        outlines = [object_outline(o) for o in scene.objects]
        target = outlines[0]
        assert scene.objects[0].target
        assert (target >= (x0, y0)).all() and (target <= (x1, y1)).all()
        # Grown from the whole clutter's box (coarse knowledge), not fitted to the target.
        every = np.concatenate(outlines)
        assert (every.min(axis=0) >= (x0, y0)).all() and (every.max(axis=0) <= (x1, y1)).all()
        assert all(round(v * 100, 6) == round(v * 100) for v in (x0, y0, x1, y1))  # centimetres


def test_a_scene_without_a_region_gets_the_workspace():
    assert load_scene("SELECT1").target_region == WORKSPACE_M  # a training scene declares none


@pytest.mark.parametrize("region, key, match", [
    ("min = [-1.5, 0.0]\nmax = [0.5, 0.3]", "target_region.min", "outside the workspace"),
    ("min = [0.5, 0.0]\nmax = [0.1, 0.3]", "target_region.min", "expected min < max"),
    ("min = [0.15, -0.1]\nmax = [0.19, 0.3]", "target_region.max", "does not fit in the region"),
    ("min = [0.5, 0.0]\nmax = [0.9, 0.5]", "target_region.min", "lies outside the region"),
    ("min = [0.0, 0.0]\nmax = [0.5, 0.5]\nmid = [0.1, 0.1]", "target_region.mid", "unknown key"),
])
def test_a_bad_region_is_one_line_naming_file_and_key(tmp_path, region, key, match):
    path = tmp_path / "bad.toml"
    text = re.sub(r"\[target_region\][^\n]*\n(min|max) = [^\n]*\n(min|max) = [^\n]*\n", "",
                  Path(load_scene("FB").path).read_text())  # FB's own region, replaced by the bad one
    path.write_text(text + f"\n[target_region]\n{region}\n")
    with pytest.raises(SceneError, match=match) as info:
        load_scene(path)
    assert str(path) in str(info.value) and f"'{key}'" in str(info.value) and "\n" not in str(info.value)


# -- the rummage ----------------------------------------------------------------------------------------------------


def test_the_rummage_is_made_from_region_start_and_walls_only(batch):
    params = list(inspect.signature(coverage_passes).parameters)
    assert params == ["region_m", "start_m", "scale_m", "lane_spacing_m", "sides", "walls"]
    lay = batch[0].layout
    rng = np.random.default_rng(0)
    moved = tuple(replace(o, position=tuple(np.add(o.position, rng.uniform(-0.2, 0.2, 2))), yaw=o.yaw + 1.0)
                  for o in lay.objects)
    assert layout_actions(replace(lay, objects=moved), SPEC) == layout_actions(lay, SPEC)
    scene = scene_from_text(batch[0].text, Path("x.toml"))
    assert scene.actions == coverage_passes(scene.target_region, scene.gripper_start, sides=SIDES,
                                            walls=[wall_outline(w) for w in scene.walls])
    assert scene.replay == "guarded" and scene.stop_force_n == STOP_FORCE_N
    assert scene.action_scale == 0.03 and all(abs(u) <= 1.0 for a in scene.actions for u in a)


def _poke_directions(points: np.ndarray) -> set[tuple[int, int]]:
    """Unit axis directions (sign x, sign y) of the moves that enter the region and come straight back."""
    out = set()
    for a, b, c in zip(points, points[1:], points[2:]):
        if np.allclose(a, c) and not np.allclose(a, b):
            out.add(tuple(int(v) for v in np.sign(np.round(b - a, 9))))
    return out


def test_the_rummage_pokes_from_every_open_side_to_the_middle_and_keeps_off_the_walls():
    region, start = ((0.2, -0.2), (0.6, 0.2)), (-0.05, 0.0)
    points = np.array(coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES))
    assert _poke_directions(points) == {(1, 0), (0, 1), (-1, 0), (0, -1)}
    (gx0, gy0), (gx1, gy1) = GRIPPER_OUTLINE_M
    # the side lines keep the hand the clearance off the region; the side pokes' leading edges reach its middle
    xs, ys, c = points[:, 0], points[:, 1], SIDE_CLEARANCE_M
    assert (ys + gy1).min() == pytest.approx(-0.2 - c) and (ys + gy0).max() == pytest.approx(0.2 + c)
    assert (xs + gx0).max() == pytest.approx(0.6 + c)
    assert np.isclose(ys + gy1, 0.0).any() and np.isclose(ys + gy0, 0.0).any() and np.isclose(xs + gx0, 0.4).any()
    assert not ((ys + gy1 > 0.0 + 1e-9) & (xs > 0.2)).any() or not ((ys + gy0 < -1e-9) & (ys > 0.2)).any()
    assert points[-1][0] == pytest.approx(points[1][0])  # back on the approach line
    # a wall close beside the region's -y side bars that side's line and the far line's -y end, which starts on it:
    # the front, the +y side and the far line's lanes the hand reaches from the +y side remain, and no move of the
    # hand comes within the clearance of the wall
    wall = np.array([[1.0, -0.45], [1.0, -0.25], [-0.3, -0.25], [-0.3, -0.45]])
    barred = np.array(coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES, walls=[wall]))
    assert _poke_directions(barred) == {(1, 0), (-1, 0), (0, -1)}
    assert (barred[:, 1] + gy0).min() >= -0.25 + SIDE_CLEARANCE_M - 1e-9
    assert all(separation(_hand_sweep(a, b), wall) >= SIDE_CLEARANCE_M - 1e-9 for a, b in zip(barred, barred[1:]))
    # walls on every side: the front pokes only; the same arguments, the same waypoints
    walls = [wall, wall * [1, -1], np.array([[0.9, -1.0], [0.9, 1.0], [0.7, 1.0], [0.7, -1.0]])]
    front = coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES, walls=walls)
    assert _poke_directions(np.array(front)) == {(1, 0)}
    assert front == coverage_waypoints(region, start, lane_spacing_m=0.2)
    again = np.array(coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES, walls=[wall]))
    assert np.array_equal(again, barred)


def _hand_sweep(a, b) -> np.ndarray:
    """Outline (4, 2) of the hand's swept rectangle moving straight (along an axis) from base a to base b."""
    (gx0, gy0), (gx1, gy1) = GRIPPER_OUTLINE_M
    x0, x1 = min(a[0], b[0]) + gx0, max(a[0], b[0]) + gx1
    y0, y1 = min(a[1], b[1]) + gy0, max(a[1], b[1]) + gy1
    return np.array([[x1, y0], [x1, y1], [x0, y1], [x0, y0]])


def test_a_wall_near_a_corner_of_the_round_costs_the_pokes_near_it_not_the_whole_side():
    # A far wall just beyond the far line bars the far side and the corners where the side lines meet it: the -y and
    # +y sides are still poked along their whole length, reached from the front line, each lane once, and no move of
    # the hand comes within the clearance of the wall.
    region, start = ((0.2, -0.2), (0.6, 0.2)), (-0.05, 0.0)
    far_wall = np.array([[0.9, -1.0], [0.9, 1.0], [0.7, 1.0], [0.7, -1.0]])
    points = np.array(coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES, walls=[far_wall]))
    assert _poke_directions(points) == {(1, 0), (0, 1), (0, -1)}
    assert all(separation(_hand_sweep(a, b), far_wall) >= SIDE_CLEARANCE_M - 1e-9 for a, b in zip(points, points[1:]))
    # every strip of the region's length poked from each side, to the middle line, once per round
    side_lanes = [sorted({round(a[0], 6) for a, b, c in zip(points, points[1:], points[2:])
                          if np.allclose(a, c) and np.sign(b[1] - a[1]) == s and a[0] == b[0]}) for s in (1, -1)]
    assert side_lanes[0] == side_lanes[1] and len(side_lanes[0]) == 3
    assert points[-1][0] == pytest.approx(points[1][0])  # back on the approach line
    # the same wall moved away bars nothing: the whole round, far side included
    away = coverage_waypoints(region, start, lane_spacing_m=0.2, sides=SIDES, walls=[far_wall + [0.3, 0.0]])
    assert _poke_directions(np.array(away)) == {(1, 0), (0, 1), (-1, 0), (0, -1)}


def test_the_pokes_reach_across_and_into_the_region_and_come_back():
    region, start = ((0.1, -0.2), (0.7, 0.3)), (-0.05, 0.0)
    actions = np.array(coverage_passes(region, start, scale_m=0.03, lane_spacing_m=0.2))
    path = np.asarray(start) + np.cumsum(actions * 0.03, axis=0)
    points = np.array(coverage_waypoints(region, start, lane_spacing_m=0.2))
    assert np.allclose(path[-1], points[-1], atol=1e-3)
    assert np.abs(actions).max() <= 1.0
    reach = GRIPPER_OUTLINE_M[1][0]
    line = min(start[0], 0.1 - reach)
    tips = path[:, 0] + reach
    assert tips.max() == pytest.approx(0.7 - FAR_SLACK_M, abs=1e-3)  # the deepest pokes, just short of the far edge
    assert path[:, 0].min() == pytest.approx(line, abs=1e-3)  # the approach line, before the region
    # Three lanes over 0.5 m (at most 0.2 m apart), the nearest the start's y first; the hand (0.2 m) spans them all.
    ys = lanes(region, start, 0.2)
    assert len(ys) == 3 and ys[0] == pytest.approx(0.05) and sorted(ys) == pytest.approx([-0.2 + 0.5 * (k + 0.5) / 3
                                                                                           for k in range(3)])
    # Every poke is a straight move along +x from the line and the same move back; each round goes deeper.
    depths = []
    for a, b, c in zip(points[1:], points[2:], points[3:]):
        if a[0] == pytest.approx(line) and c[0] == pytest.approx(line) and b[0] > line:
            assert a[1] == b[1] == c[1]
            depths.append(b[0])
    rounds = sorted(set(np.round(depths, 6)))
    assert len(depths) == 3 * len(rounds) and len(rounds) >= 2
    assert depths == sorted(depths)
    # Only the region and the start matter, and the same arguments give the same actions.
    assert coverage_passes(region, start, scale_m=0.03, lane_spacing_m=0.2) == tuple(map(tuple, actions))


# -- knobs and the command line -------------------------------------------------------------------------------------


@pytest.mark.parametrize("knobs, knob", [
    (dict(min_distractors=-1), "min_distractors"), (dict(min_distractors=3, max_distractors=2), "max_distractors"),
    (dict(hiddenness=1.5), "hiddenness"), (dict(clutter_density=float("nan")), "clutter_density"),
    (dict(target="sphere"), "target"), (dict(area_m=((-2.0, 0.0), (1.0, 1.0))), "area_m"),
    (dict(area_m=((0.5, 0.0), (0.55, 0.3))), "area_m"), (dict(max_distractors=12), "max_distractors"),
    (dict(min_distractors=True), "min_distractors"), (dict(max_distractors=0, min_distractors=0), "hiddenness"),
])
def test_the_spec_is_checked_on_construction(knobs, knob):
    with pytest.raises(GeneratorSpecError) as info:
        GeneratorSpec(**knobs)
    assert info.value.knob == knob and "\n" not in str(info.value)


@pytest.mark.parametrize("args, culprit", [
    (["--n", "0"], "--n 0"), (["--n", "-3"], "--n -3"), (["--min-distractors", "-1"], "--min-distractors -1"),
    (["--area", "-2,0,1,1"], "--area -2,0,1,1: lies outside the workspace"),
    (["--area", "0.5,0,0.55,0.3"], "smaller than the target"),
    (["--area", "0.5,0,0.8,0.3", "--max-distractors", "8"], "--max-distractors 8"),
    (["--area", "1,2"], "--area '1,2'"), (["--hiddenness", "2"], "--hiddenness 2.0"),
    (["--target", "sphere"], "--target sphere"), (["--seed", "-1"], "--seed -1"),
])
def test_the_command_refuses_bad_specs_in_one_line(tmp_path, args, culprit):
    out = tmp_path / "gen"
    r = CliRunner().invoke(cli, ["scenes", "generate", "--out", str(out), *(["--n", "2"] if "--n" not in args
                                                                             else []), *args])
    assert r.exit_code != 0 and isinstance(r.exception, SystemExit)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error:") and culprit in lines[0], r.output
    assert "Traceback" not in r.output and not out.exists()


def test_the_command_writes_the_files_and_a_generated_scene_collects(tmp_path, batch):
    out = tmp_path / "gen"
    r = CliRunner().invoke(cli, ["scenes", "generate", "--n", "2", "--seed", "11", "--first", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert sorted(f.name for f in out.iterdir()) == ["GEN_00002.toml", "GEN_00003.toml"]
    assert (out / "GEN_00003.toml").read_text() == batch[3].text
    assert r.output.count("wrote ") == 2
    again = CliRunner().invoke(cli, ["scenes", "generate", "--n", "1", "--seed", "11", "--first", "2", "--out",
                                     str(out)])
    assert again.exit_code == 1 and "exists; pass --force-overwrite" in again.output
    scene = load_scene(out / "GEN_00002.toml")
    assert scene.kind == "retrieval" and scene.target is not None and scene.target_region != WORKSPACE_M
    runs = tmp_path / "runs"
    r = CliRunner().invoke(cli, ["-q", "collect", "--scene", str(out / "GEN_00002.toml"), "--seeds", "0",
                                 "--policy", "scripted", "--max-actions", "3", "--out", str(runs)])
    assert r.exit_code == 0, r.output
    assert (runs / "GEN_00002-000.parquet").is_file()
    assert CliRunner().invoke(cli, ["scenes"]).output.startswith("BC ")  # the list still works


# -- the catalogue -------------------------------------------------------------------------------------------------


def test_the_catalogue_matches_the_shipped_tasks():
    seen = set()
    for name in ("FB", "BC", "IB", "TC"):
        scene = load_scene(name)
        for o in scene.objects:
            m = next(m for m in MODELS if m.model == o.model)
            seen.add(m.key)
            assert (m.shape, m.size, m.shape_offset, m.shape_yaw, m.com_offset, m.com_yaw) == (
                o.shape, o.size, o.shape_offset, o.shape_yaw, o.com_offset, o.com_yaw), (name, o.name)
            assert (m.spinning_friction, m.rolling_friction) == (o.spinning_friction, o.rolling_friction)
        assert scene.walls == TASK_WALLS
    assert seen == set(MODEL_BY_KEY)


def test_a_scene_without_a_passing_draw_is_one_line(tmp_path, monkeypatch):
    import pipeline.sim.generate as checked

    monkeypatch.setattr(checked, "MAX_DRAWS", 3)
    monkeypatch.setattr(checked, "settle_problem", lambda scene: "a and b overlap by 2.0 mm at spawn")
    out = tmp_path / "gen"
    r = CliRunner().invoke(cli, ["scenes", "generate", "--n", "1", "--seed", "4", "--out", str(out)])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and "Traceback" not in r.output, r.output
    assert "scene 0 of seed 4: no draw passed in 3 (failed the settling check x" in lines[0]
    assert not list(out.glob("*.toml"))


def test_an_unknown_side_is_refused():
    with pytest.raises(ValueError, match="sides"):
        coverage_waypoints(((0.2, -0.2), (0.6, 0.2)), (0.0, 0.0), sides=("front", "back"))
