"""The ``explore`` policy (pipeline.probe.explore): no action list, a guarded search of the target region made from
the region and the start, then the probes; its budget, its region, its determinism, and that it never reads the
simulation's ground truth."""
from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipeline import registry, schema
from pipeline.collect import collect_file, collect_run
from pipeline.probe.explore import (
    BUDGET_SPENT,
    REGION_UNREACHABLE,
    ExploreParams,
    region_reachable,
    search_actions,
)
from pipeline.scenes import SceneError, WallSpec, load_scene
from pipeline.scenes.coverage import SIDES

#: A small region round TC's target: a short search (one poke from the front, 8 actions), then a few probes.
SMALL_REGION = ((0.12, -0.02), (0.26, 0.12))
#: The columns the policy's actions are read from.
MOTION = ("cmd_dx_m", "cmd_dy_m", "ee_x_m", "ee_y_m", "in_contact", "probe")


def _small_tc():
    return replace(load_scene("TC"), target_region=SMALL_REGION)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("explore") / "TC-000.parquet"
    collect_file(_small_tc(), 0, path, policy="explore")
    return path


def test_explore_is_registered_with_the_active_protocols_retrieval():
    spec = registry.policy("explore")
    assert spec.retrieval == registry.policy("scripted+probe").retrieval
    assert spec.side_files == registry.policy("scripted+probe").side_files


def test_the_search_then_the_probes_are_recorded_and_marked(small_run):
    table = schema.read_run(small_run)
    meta = schema.read_metadata(small_run)["params"]
    probe = meta["probe"]
    flags = np.asarray(table.column("probe").to_numpy(zero_copy_only=False), dtype=bool)
    search = probe["search"]
    assert meta["policy"] == "explore"
    assert 0 < search["actions"] <= search["planned_actions"] * 2
    assert not flags[:search["actions"]].any() and flags[search["actions"]:].all()
    assert probe["probes"] >= 1 and probe["actions"] == table.num_rows - search["actions"]
    assert search["region_m"] == [list(SMALL_REGION[0]), list(SMALL_REGION[1])]


def test_the_same_command_writes_the_same_file(small_run, tmp_path):
    again = tmp_path / "TC-000.parquet"
    collect_file(_small_tc(), 0, again, policy="explore")
    assert again.read_bytes() == Path(small_run).read_bytes()


def test_the_policy_never_reads_the_ground_truth(small_run, monkeypatch):
    # Scrambled object poses and distances, and no contact labels: the recorded truth changes, the moves do not.
    from pipeline.sim import World

    rng = np.random.default_rng(7)
    poses, distances = World.object_poses, World.object_distances
    monkeypatch.setattr(World, "object_poses", lambda self: poses(self) + rng.normal(0.0, 0.1, (3,)))
    monkeypatch.setattr(World, "object_distances", lambda self: distances(self) + 1.0)
    blind, _, _ = collect_run(_small_tc().with_effects(contact_truth=False), 0, policy="explore")
    seen = schema.read_run(small_run)
    assert set(blind.column("object_id").to_pylist()) == {-1}
    assert not np.allclose(np.asarray(blind.column("obj_pose").to_pylist()),
                           np.asarray(seen.column("obj_pose").to_pylist()))
    for col in MOTION:
        assert blind.column(col).equals(seen.column(col)), col


def test_a_budget_of_zero_ends_the_run_at_once():
    table, meta, _ = collect_run(_small_tc(), 0, policy="explore", policy_params=ExploreParams(action_budget=0))
    assert table.num_rows == 0
    assert meta["probe"]["flagged"] == BUDGET_SPENT and meta["probe"]["probes"] == 0


def test_no_probe_starts_once_the_budget_is_spent():
    table, meta, _ = collect_run(_small_tc(), 0, policy="explore", policy_params=ExploreParams(action_budget=4))
    assert meta["probe"]["search"]["actions"] == 4 and not meta["probe"]["search"]["completed"]
    assert meta["probe"]["probes"] == 0 and table.num_rows == 4
    assert meta["probe"]["flagged"] == BUDGET_SPENT


def test_max_actions_caps_the_budget():
    table, meta, _ = collect_run(_small_tc(), 0, policy="explore", max_actions=3)
    assert table.num_rows == 3 and meta["probe"]["probes"] == 0


def test_a_walled_off_region_ends_the_run_at_once_with_its_note():
    tc = _small_tc()
    (x0, y0), (x1, y1) = SMALL_REGION
    block = WallSpec("block", (x1 - x0 + 0.02, y1 - y0 + 0.02, 0.3), ((x0 + x1) / 2, (y0 + y1) / 2))
    scene = replace(tc, walls=tc.walls + (block,))
    assert not region_reachable(SMALL_REGION, scene.walls)
    table, meta, _ = collect_run(scene, 0, policy="explore")
    assert table.num_rows == 0 and meta["probe"]["flagged"] == REGION_UNREACHABLE


def test_a_region_without_the_target_is_searched_without_error():
    # The target lies at x = 0.18; the region is off to the far left: the run is made, the grasp will miss.
    scene = replace(load_scene("TC"), target_region=((0.05, 0.35), (0.25, 0.5)))
    table, meta, _ = collect_run(scene, 0, policy="explore", policy_params=ExploreParams(action_budget=60))
    search = meta["probe"]["search"]
    assert 0 < search["actions"] <= table.num_rows and (search["completed"] or search["actions"] == 60)
    assert meta["probe"]["probes"] == 0 or table.num_rows - search["actions"] == meta["probe"]["actions"]


def test_a_scene_without_a_region_is_refused_with_the_key_named():
    from pipeline.scenes.types import WORKSPACE_M

    scene = replace(load_scene("TC"), target_region=WORKSPACE_M)
    with pytest.raises(SceneError, match="target_region"):
        collect_run(scene, 0, policy="explore")


def test_region_reachable_on_a_grid():
    wall = WallSpec("w", (0.2, 0.2, 0.3), (0.5, 0.5))
    assert not region_reachable(((0.45, 0.45), (0.55, 0.55)), [wall])
    assert region_reachable(((0.45, 0.45), (0.65, 0.55)), [wall])  # partly outside the wall
    turned = WallSpec("t", (0.2, 0.02, 0.3), (0.5, 0.5), yaw=np.pi / 2)
    assert region_reachable(((0.45, 0.45), (0.55, 0.55)), [turned])


def test_the_search_is_the_generated_scenes_rummage(tmp_path):
    # A generated scene's action list is the same search, made by the generator from the region, start and walls.
    from pipeline.sim.generate import generate_scenes

    name, text = generate_scenes(1, 0)[0]
    (tmp_path / f"{name}.toml").write_text(text)
    scene = load_scene(tmp_path / f"{name}.toml")
    path = search_actions(scene.target_region, scene.gripper_start, scene.walls, scene.action_scale,
                          ExploreParams().lane_spacing, sides=SIDES)
    assert np.array_equal(path, np.asarray(scene.actions, dtype=np.float64))


def test_params_refuse_a_negative_budget_and_round_trip():
    with pytest.raises(ValueError, match="action_budget"):
        ExploreParams(action_budget=-1)
    with pytest.raises(ValueError, match="stall_actions"):
        ExploreParams(stall_actions=0)
    p = ExploreParams(action_budget=300, budget=5)
    assert ExploreParams.from_dict(p.to_dict()) == p


def _small_tc_file(tmp_path: Path) -> Path:
    """TC's file, renamed, with the small region (a scene file of its own, as `stucco scenes generate` writes)."""
    (x0, y0), (x1, y1) = SMALL_REGION
    text = re.sub(r"\[target_region\][^\n]*\nmin = [^\n]*\nmax = [^\n]*\n",
                  f"[target_region]\nmin = [{x0}, {y0}]\nmax = [{x1}, {y1}]\n", load_scene("TC").source)
    path = tmp_path / "TCSMALL.toml"
    path.write_text(text.replace('name = "TC"', 'name = "TCSMALL"', 1))
    return path


def test_bench_explore_from_the_cli_gives_gs_against_the_budget(tmp_path):
    from click.testing import CliRunner

    from stucco_cli.main import cli

    scene = _small_tc_file(tmp_path)
    out = tmp_path / "bench"
    args = ["-q", "--seed", "0", "bench", "explore", "--scenes", str(scene), "--seeds", "0", "--budgets", "3,400",
            "--runs", str(out / "runs"), "--out", str(out)]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    import csv

    rows = list(csv.DictReader((out / "explore_budget.csv").open()))
    assert [int(row["budget"]) for row in rows] == [3, 400]
    assert int(rows[0]["actions"]) == 3 and rows[0]["flagged"] == "budget_spent"
    assert int(rows[1]["probes"]) >= 1 and int(rows[1]["actions"]) < 400
    assert (out / "explore_budget.png").stat().st_size > 0 and (out / "runs" / "b400" / "TCSMALL-000.parquet").is_file()
    first = (out / "explore_budget.csv").read_text()
    again = CliRunner().invoke(cli, args)  # the runs are read back, not collected again
    assert again.exit_code == 0 and (out / "explore_budget.csv").read_text() == first
    bad = CliRunner().invoke(cli, args[:-4] + ["--budgets", "0", "--out", str(out)])
    assert bad.exit_code != 0 and "--budgets" in bad.output and "Traceback" not in bad.output
    other = CliRunner().invoke(cli, ["--seed", "1"] + args[3:])  # the runs of root seed 0 are not read as seed 1's
    assert other.exit_code != 0 and "TCSMALL-000.parquet" in other.output and "Traceback" not in other.output
    assert "--runs" in other.output
    assert (out / "explore_budget.csv").read_text() == first


def test_evaluate_runs_the_explore_policy_end_to_end(tmp_path):
    from click.testing import CliRunner

    from stucco_cli.main import cli

    scene = _small_tc_file(tmp_path)
    out = tmp_path / "ev"
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", "evaluate", "--policy", "explore", "--scenes", str(scene),
                                 "--seeds", "0", "--methods", "stucco", "--estimators", "plausible", "--no-figures",
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    report = (out / "report.md").read_text()
    row = next(line for line in report.splitlines() if line.startswith("| other scenes, can target"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "1" and cells[2] in ("0", "100")  # one run, graded at the first attempt
    scores = [schema.read_table(f, "scores") for f in (out / "scores").rglob("*.parquet")]
    assert sum(t.num_rows for t in scores) == 1
    assert scores[0].column("grasp_attempts")[0].as_py() >= 1


def _without_actions(path: Path) -> Path:
    """The scene file at ``path`` with its [actions] table removed (what the explore policy needs is left)."""
    text = re.sub(r"\[actions\].*?\]\n(?=\n|\[)", "", path.read_text(), flags=re.S)
    assert "[actions]" not in text
    out = path.with_name("NOACT.toml")
    out.write_text(text.replace('name = "TCSMALL"', 'name = "NOACT"', 1))
    return out


def test_a_scene_without_an_action_list_is_explored_and_refused_by_the_scripted_policy(tmp_path):
    from click.testing import CliRunner

    from stucco_cli.main import cli

    path = _without_actions(_small_tc_file(tmp_path))
    scene = load_scene(path)
    assert scene.actions is None and scene.kind == "retrieval"
    table, meta, _ = collect_run(scene, 0, policy="explore", policy_params=ExploreParams(action_budget=3))
    assert table.num_rows == 3 and meta["probe"]["search"]["actions"] == 3
    with pytest.raises(SceneError, match="'actions'"):
        collect_run(scene, 0, policy="scripted")
    r = CliRunner().invoke(cli, ["-q", "--seed", "0", "evaluate", "--scenes", str(path), "--seeds", "0",
                                 "--methods", "stucco", "--estimators", "plausible", "--no-figures",
                                 "--out", str(tmp_path / "ev")])
    assert r.exit_code != 0 and "Traceback" not in r.output
    last = [line for line in r.output.splitlines() if line.strip()][-1]
    assert str(path) in last and "'actions'" in last and "--policy explore" in last


def test_a_retrieval_scene_without_actions_needs_a_region(tmp_path):
    path = _without_actions(_small_tc_file(tmp_path))
    text = re.sub(r"\[target_region\][^\n]*\nmin = [^\n]*\nmax = [^\n]*\n", "", path.read_text())
    path.write_text(text)
    with pytest.raises(SceneError, match="target_region"):
        load_scene(path)


def test_policy_params_from_the_cli_reach_the_run_and_bad_ones_are_one_line(tmp_path):
    from click.testing import CliRunner

    from stucco_cli.main import cli

    scene = _small_tc_file(tmp_path)
    ok = CliRunner().invoke(cli, ["-q", "--seed", "0", "collect", "--scene", str(scene), "--seeds", "0", "--policy",
                                  "explore", "--policy-param", "action_budget=3", "--policy-param",
                                  'search_sides=["front", "far"]', "--out", str(tmp_path / "runs")])
    assert ok.exit_code == 0, ok.output
    probe = schema.read_metadata(tmp_path / "runs" / "TCSMALL-000.parquet")["params"]["probe"]
    assert probe["params"]["action_budget"] == 3 and probe["params"]["search_sides"] == ["front", "far"]
    assert probe["search"]["actions"] == 3
    for bad, says in (("budgett=3", "unknown parameter"), ("action_budget=-1", "action_budget"),
                      ("search_stop=push", "stall or touch"), ("action_budget", "NAME=VALUE")):
        r = CliRunner().invoke(cli, ["-q", "collect", "--scene", str(scene), "--seeds", "0", "--policy", "explore",
                                     "--policy-param", bad, "--out", str(tmp_path / "bad")])
        assert r.exit_code == 2 and says in r.output and "Traceback" not in r.output, bad
    scripted = CliRunner().invoke(cli, ["-q", "collect", "--scene", "TC", "--seeds", "0", "--policy-param",
                                        "action_budget=3", "--out", str(tmp_path / "bad")])
    assert scripted.exit_code == 2 and "takes no parameters" in scripted.output


def test_evaluate_records_the_policy_params_and_refuses_other_ones_on_resume(tmp_path):
    import json

    from click.testing import CliRunner

    from stucco_cli.main import cli

    scene = _small_tc_file(tmp_path)
    out = tmp_path / "ev"
    args = ["-q", "--seed", "0", "evaluate", "--policy", "explore", "--scenes", str(scene), "--seeds", "0",
            "--methods", "stucco", "--estimators", "plausible", "--no-figures", "--out", str(out)]
    r = CliRunner().invoke(cli, args + ["--policy-param", "action_budget=3"])
    assert r.exit_code == 0, r.output
    assert json.loads((out / "evaluation.json").read_text())["policy_params"] == [["action_budget", 3]]
    run = next((out / "runs").rglob("TCSMALL-000.parquet"))
    assert schema.read_run(run).num_rows == 3
    again = CliRunner().invoke(cli, args + ["--policy-param", "action_budget=4"])
    assert again.exit_code != 0 and "policy_params" in again.output and "Traceback" not in again.output


def test_an_edited_scene_under_a_tasks_name_is_reported_with_other_scenes():
    from pipeline.probe.summary import group_of

    text = load_scene("FB").source
    assert group_of("FB", "box", text) == "FB" == group_of("FB", "box")
    assert group_of("FB", "box", text.replace("mass = ", "mass = 1")) == "other scenes, box target"
    assert group_of("GEN_00001", "cylinder", "anything") == "other scenes, can target"
