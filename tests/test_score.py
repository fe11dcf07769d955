"""score: contact error and FMI on hand-made inputs with hand-computed answers, the stage, and its CLI."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.retrieve import primitive_of, retrieval_table
from pipeline.scenes import load_scene, scene_digest
from pipeline.schema import SchemaError, read_metadata, write_table
from pipeline.score import (
    SCORES_COLUMNS,
    contact_error_cm,
    fmi,
    read_scores,
    scene_signed_distance,
    score,
    validate_scores,
)

SCENE = load_scene("FB")
BOX = primitive_of(SCENE.objects[0])
CAN = primitive_of(SCENE.objects[1])


def _poses() -> np.ndarray:
    """FB bodies: box COM at (0.3, 0, 0), tomato can COM at (0.6, 0.3, 0), the other objects far away, walls
    where the scene puts them."""
    poses = [[0.3, 0.0, 0.0], [0.6, 0.3, 0.0], [-3.0, -3.0, 0.0], [-4.0, -3.0, 0.0], [-5.0, -3.0, 0.0]]
    poses += [[w.position[0], w.position[1], w.yaw] for w in SCENE.walls]
    return np.array(poses)


def _points():
    """Points at hand-known distances from the nearest surface, their true objects, and the distances."""
    box_c = BOX.centre_world(_poses()[0])
    can_c = CAN.centre_world(_poses()[1])
    hx, hy = BOX.half
    pts = np.array([
        box_c + [hx + 0.01, 0.0],     # 1 cm outside the box's long face
        box_c,                        # at the box centre: 3.08 cm inside (nearest face is a long one)
        can_c + [0.065 + 0.02, 0.0],  # 2 cm outside the can
        [0.5, 0.55],                  # 5 cm from the left wall (y from 0.6)
        box_c + [0.0, hy + 0.004],    # 4 mm beyond the box's short face, object unknown
    ])
    truth = np.array([0, 0, 1, 7, -1])
    dist = np.array([0.01, -0.0308, 0.02, 0.05, 0.004])
    return pts, truth, dist


def test_scene_signed_distance_by_hand():
    pts, _, dist = _points()
    np.testing.assert_allclose(scene_signed_distance(pts, SCENE, _poses()), dist, atol=1e-12)


def test_scene_signed_distance_skips_bodies_not_built():
    poses = _poses()
    poses[7] = np.nan  # left wall not built: the 5 cm point is now nearest to the can
    pts, _, _ = _points()
    d = scene_signed_distance(pts[3:4], SCENE, poses)[0]
    assert d == pytest.approx(np.linalg.norm(pts[3] - CAN.centre_world(poses[1])) - 0.065)


def test_contact_error_cm_by_hand():
    pts, _, _ = _points()
    # (1 + 3.08 + 2 + 5 + 0.4) / 5 cm
    assert contact_error_cm(pts, SCENE, _poses()) == pytest.approx(11.48 / 5)
    assert contact_error_cm(np.zeros((0, 2)), SCENE, _poses()) is None


def test_fmi_by_hand():
    # Pairs together in truth: (0,1); in the segmentation: (0,1), (0,2), (1,2). TP 1, FP 2, FN 0.
    assert fmi([0, 0, 1, 7], [0, 0, 0, 1]) == pytest.approx(1 / math.sqrt(3))
    # Unknown objects (-1) are left out; perfect agreement up to label names.
    assert fmi([3, 3, 5, -1], [1, 1, 0, 0]) == pytest.approx(1.0)
    # An unassigned point is its own cluster: truth pairs (0,1),(0,2),(1,2); predicted only (0,1) -> 1/sqrt(3).
    assert fmi([2, 2, 2], [0, 0, -1]) == pytest.approx(1 / math.sqrt(3))
    assert fmi([-1, -1], [0, 1]) is None


# ------------------------------------------------------------------------------------------------ stage


def _run_file(path: Path, run="FB/4", seed=4):
    """The stored FB run (data/regression, a valid ``sim_run`` file) as run ``run``, with the bodies at
    :func:`_poses` after every action."""
    stored = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
    t = pq.read_table(stored)
    n = t.num_rows
    over = {"run": pa.array([run] * n), "seed": pa.array([seed] * n, pa.int64()),
            "obj_pose": pa.array([_poses().tolist()] * n, t.schema.field("obj_pose").type)}
    for name, values in over.items():
        t = t.set_column(t.column_names.index(name), name, values)
    params = dict(read_metadata(stored)["params"], run_seed=seed)  # the metadata names the run its rows hold
    write_table(t.replace_schema_metadata(None), path, stage="collect", params=params, seed=0, kind="sim_run")


def _segments(run="FB/4"):
    pts, truth, _ = _points()
    n = len(pts)
    return pa.table({"run": [run] * n, "step": pa.array(np.arange(n), pa.int64()),
                     "contact_index": pa.array(np.zeros(n, np.int64)),
                     "estimate_step": pa.array(np.full(n, 9, np.int64)), "x_m": pts[:, 0], "y_m": pts[:, 1],
                     "tracker_label": pa.array(np.zeros(n, np.int64)), "object_id": pa.array(truth, pa.int64()),
                     "segment": pa.array([0, 0, 0, 1, 1], pa.int64())})


def _retrieval(run="FB/4", seed=4, **over):
    row = dict(run=run, scene="FB", seed=seed, method="stucco", estimator="plausible", target="cracker_box", x_m=0.3,
               y_m=0.004, yaw_rad=0.05, segment=0, n_points=3, n_segments=2, position_var_m2=1e-4, icp_rmse_m=0.002,
               penetration_m=0.0, low_confidence=False, notes="", true_x_m=0.3, true_y_m=0.0, true_yaw_rad=0.0,
               position_error_m=0.004, yaw_error_rad=0.05, grasp_success=True, grasp_outcome="ok", grasp_attempts=None,
               grasp_success_any=None, icp_s=0.1,
               grasp_s=0.5)
    row.update(over)
    return retrieval_table([row])


def _diagnostics(run="FB/4"):
    return pa.table({"run": [run, run], "step": pa.array([0, 1], pa.int64()), "in_contact": [False, True],
                     "n_contacts": pa.array([0, 1], pa.int64()), "ess": [1.0, 0.9], "resampled": [False, False],
                     "n_replaced": pa.array([0, 0], pa.int64()), "update_ms": [100.0, 200.0]})


def test_score_by_hand(tmp_path):
    runs = tmp_path / "runs"
    _run_file(runs / "FB-004.parquet")
    t = score(_segments(), _retrieval(), runs, diagnostics=_diagnostics())
    assert t.column_names == [c.name for c in SCORES_COLUMNS]
    row = t.to_pylist()[0]
    # FMI over the 4 points with a known object: truth [0, 0, 1, 7], segments [0, 0, 0, 1].
    assert row["fmi"] == pytest.approx(1 / math.sqrt(3))
    assert row["contact_error_cm"] == pytest.approx(11.48 / 5)
    assert (row["scene"], row["seed"], row["method"], row["run"]) == ("FB", 4, "stucco", "FB/4")
    assert row["grasp_success"] is True
    assert row["position_error_cm"] == 0.004 * 100.0 and row["yaw_error_rad"] == 0.05  # cm, like the CE
    assert row["scene_sha256"] == scene_digest(load_scene("FB").source)
    assert row["n_points"] == 5 and row["n_segments"] == 2
    assert row["track_s"] == pytest.approx(0.3) and row["retrieve_s"] == 0.1 and row["grasp_s"] == 0.5
    assert row["wall_s"] == pytest.approx(0.9)


def test_score_run_without_points_and_without_grasp(tmp_path):
    runs = tmp_path / "runs"
    _run_file(runs / "FB-004.parquet")
    empty = _segments().slice(0, 0)
    t = score(empty, _retrieval(grasp_success=None, grasp_s=None, grasp_outcome="", n_segments=0, segment=-1,
                                n_points=0), runs)
    row = t.to_pylist()[0]
    assert row["fmi"] is None and row["contact_error_cm"] is None and row["n_points"] == 0
    assert row["grasp_success"] is None and row["track_s"] is None
    assert row["wall_s"] == pytest.approx(0.1)


def test_scores_one_row_per_scene_seed_method():
    t = pa.table({c.name: pa.array([None], type=c.type) for c in SCORES_COLUMNS})
    t = t.set_column(0, "scene", pa.array(["FB"])).set_column(1, "seed", pa.array([1], pa.int64()))
    vals = dict(method="stucco", estimator="plausible", run="FB/1", position_error_cm=0.0, yaw_error_rad=0.0,
                low_confidence=False, n_points=0, n_segments=0, retrieve_s=0.0, wall_s=0.0)
    for k, v in vals.items():
        i = t.column_names.index(k)
        t = t.set_column(i, k, pa.array([v], type=t.schema.field(k).type))
    validate_scores(t)
    with pytest.raises(SchemaError, match=r"column 'seed', row 1: \(scene, seed, method, estimator\) = "
                                          r"\('FB', 1, 'stucco', 'plausible'\) repeats row 0"):
        validate_scores(pa.concat_tables([t, t]))


# ------------------------------------------------------------------------------------------------ CLI


@pytest.fixture()
def cli_inputs(tmp_path):
    runs = tmp_path / "runs"
    _run_file(runs / "FB-004.parquet")
    write_table(_diagnostics(), tmp_path / "t.diagnostics.parquet", stage="track", params={}, seed=0,
                kind="diagnostics")
    (tmp_path / "t.parquet").write_bytes(b"tracks stand-in")  # only its name is recorded in the segments' inputs
    write_table(_segments(), tmp_path / "seg.parquet", stage="segment", params={"method": "stucco"}, seed=0,
                inputs={"tracks": tmp_path / "t.parquet"}, kind="segments")
    write_table(_retrieval(), tmp_path / "ret.parquet", stage="retrieve", params={}, seed=0, kind="retrieval")
    return tmp_path


def _invoke(args):
    import stucco_cli.score  # noqa: F401  (registers the commands)
    from stucco_cli.main import cli

    return CliRunner().invoke(cli, args)


def test_cli_score_writes_scores_and_finds_the_diagnostics(cli_inputs):
    d = cli_inputs
    r = _invoke(["score", "--retrieval", str(d / "ret.parquet"), "--segments", str(d / "seg.parquet"), "--runs",
                 str(d / "runs"), "--out", str(d / "scores.parquet"), "--print"])
    assert r.exit_code == 0, r.output
    t = read_scores(d / "scores.parquet")
    row = t.to_pylist()[0]
    assert row["track_s"] == pytest.approx(0.3) and row["wall_s"] == pytest.approx(0.9)
    assert row["contact_error_cm"] == pytest.approx(11.48 / 5)
    meta = read_metadata(d / "scores.parquet")
    assert meta["stage"] == "score" and meta["schema"] == "scores"
    assert set(meta["inputs"]) == {"retrieval", "segments", "diagnostics"}
    assert "FB     stucco" in r.output and "GS 100 %" in r.output


@pytest.mark.parametrize("case, pattern", [
    ("missing_retrieval", r"nope\.parquet: file not found"),
    ("not_retrieval", r"is a segments table \(written by stucco segment\); expected a retrieval table"),
    ("run_not_retrieved", r"run 'FB/9' has no row in"),
    ("no_run_file", r"run 'FB/4' has no collected run file"),
])
def test_cli_score_bad_inputs_fail_with_one_line(cli_inputs, case, pattern):
    import re

    d = cli_inputs
    args = ["score", "--retrieval", str(d / "ret.parquet"), "--segments", str(d / "seg.parquet"), "--runs",
            str(d / "runs"), "--out", str(d / "scores.parquet")]
    if case == "missing_retrieval":
        args[2] = str(d / "nope.parquet")
    elif case == "not_retrieval":
        args[2] = str(d / "seg.parquet")
    elif case == "run_not_retrieved":
        write_table(_segments("FB/9"), d / "seg9.parquet", stage="segment", params={}, seed=0, kind="segments")
        args[4] = str(d / "seg9.parquet")
    else:
        (d / "empty_runs").mkdir()
        args[6] = str(d / "empty_runs")
    r = _invoke(args)
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.output
    assert re.search(pattern, lines[0]), lines[0]
    assert not (d / "scores.parquet").exists()
