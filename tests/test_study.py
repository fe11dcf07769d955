"""pipeline/studies/ and its commands: Pareto front, knee, ambiguity, the tuning rule, tiny end-to-end grids."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline.estimators.pushtrack.params import PushTrackParams
from pipeline.studies.accuracy_settings import accuracy_settings
from pipeline.studies.pareto import knee, pareto_front
from pipeline.studies.training import run_ambiguity
from pipeline.studies.tuning import choose_setting
from stucco_cli.main import cli


def test_pareto_front_hand_made_points():
    # (time, error), both minimised: (1, 5), (2, 3), (4, 1) are the front; (3, 4) is dominated by (2, 3),
    # (4, 2) by (4, 1); the NaN row is never on the front.
    pts = np.array([[1, 5], [2, 3], [3, 4], [4, 1], [4, 2], [np.nan, 0]])
    assert pareto_front(pts).tolist() == [True, True, False, True, False, False]


def test_pareto_front_maximised_column():
    # time minimised, FMI maximised: (1, 0.5) and (2, 0.9) on the front, (3, 0.8) dominated.
    pts = np.array([[1, 0.5], [2, 0.9], [3, 0.8]])
    assert pareto_front(pts, [True, False]).tolist() == [True, True, False]


def test_pareto_front_equal_points_both_kept():
    assert pareto_front(np.array([[1.0, 1.0], [1.0, 1.0]])).tolist() == [True, True]


def test_knee_is_cheapest_within_tolerance_of_best():
    cost = [0.1, 0.3, 1.0, 3.0, 10.0]
    error = [3.0, 1.5, 1.05, 1.0, 0.99]
    assert knee(cost, error, tolerance=0.1) == 2  # 1.05 <= 0.99 * 1.1; 1.5 is not


def test_ambiguity_hand_computed():
    # Bodies 0, 1, 2; the run touches 0 and 2 (body 1 is never contacted, so its distance is ignored).
    ids = np.array([-1, 0, 2, -1, 0])
    dist = np.array([[0.30, 0.00, 0.20],   # d2 over {0, 2} = 0.30 -> 0
                     [0.00, 0.00, 0.06],   # 0.06 -> (0.15 - 0.06) / 0.15 = 0.6
                     [0.03, 0.00, 0.00],   # 0.03 -> 0.8
                     [0.50, 0.00, 0.50],   # 0.50 -> 0
                     [0.00, 0.00, 0.15]])  # 0.15 -> 0 (last end never used)
    # prepended 0: actions 0..4 get [0, 0, 0.6, 0.8, 0]; contact at actions 1, 2, 4 -> (0 + 0.6 + 0) / 3 = 0.2
    assert run_ambiguity(ids, dist) == pytest.approx(0.2)


def test_ambiguity_single_object_is_zero():
    assert run_ambiguity(np.array([0, 0, -1]), np.zeros((3, 2))) == 0.0


def test_choose_picks_known_best_of_synthetic_objective():
    # median FMI peaks at value 0.04 (1 - (v - 0.04)^2 * 100), CE is lowest at 0.02 but FMI there is 0.04 lower.
    values = [0.005, 0.01, 0.02, 0.04, 0.08]
    stats = [dict(fmi=1 - (v - 0.04) ** 2 * 100, ce_cm=1 + abs(v - 0.02) * 10) for v in values]
    assert values[choose_setting(stats)] == 0.04


def test_choose_breaks_fmi_near_ties_by_ce():
    stats = [dict(fmi=0.900, ce_cm=2.0), dict(fmi=0.895, ce_cm=1.0), dict(fmi=0.5, ce_cm=0.1)]
    assert choose_setting(stats) == 1


def test_accuracy_settings_have_the_default_once():
    names = [s.name for s in accuracy_settings((10, 100), (5, 30), (1, 2), (16, 32), (5, 10), baselines=("kmeans",),
                                               pushtrack=(("n_particles", (128, 512)), ("n_refine", (128,))))]
    assert names == ["stucco N=10", "stucco N=100", "stucco restarts=5", "stucco sdf=2mm", "stucco hypotheses=16",
                     "stucco free=10mm", "stucco paper estimator", "stucco pushtrack estimator",
                     "stucco pushtrack n_particles=128", "kmeans"]


def test_pushtrack_knobs_override_only_the_estimators_parameters():
    sweep = accuracy_settings((100,), (30,), (1,), (32,), (5,), paper_estimator=False, baselines=(),
                              pushtrack=(("n_particles", (128,)), ("substeps", (1,)), ("starts", (1, 6))))
    mine = [s for s in sweep if s.estimator == "pushtrack"]
    # the default (6 starts) is the estimator's own setting, without parameters of its own
    assert [(s.knob, s.value, s.estimator_params) for s in mine] == [
        ("pushtrack_n_particles", 128.0, (("n_particles", 128),)), ("pushtrack_substeps", 1.0, (("substeps", 1),)),
        ("pushtrack_starts", 1.0, (("starts", 1),)), ("pushtrack_starts", 6.0, ())]
    assert mine[-1].name == "stucco pushtrack estimator"


def test_pushtrack_islands_knob_keeps_the_default_as_the_estimators_own_setting():
    sweep = accuracy_settings((100,), (30,), (1,), (32,), (5,), paper_estimator=False, baselines=(),
                              pushtrack=(("islands", (1, 4)),))
    mine = [s for s in sweep if s.estimator == "pushtrack"]
    assert [(s.knob, s.value, s.estimator_params) for s in mine] == [
        ("pushtrack_islands", 1.0, (("islands", 1),)), ("pushtrack_islands", 4.0, ())]


def test_pushtrack_select_is_a_choice_without_a_value():
    sweep = accuracy_settings((100,), (30,), (1,), (32,), (5,), paper_estimator=False, baselines=(),
                              pushtrack=(("select", ("held_mean", "mode")),))
    mine = [s for s in sweep if s.estimator == "pushtrack"]
    assert [s.name for s in mine] == ["stucco pushtrack estimator", "stucco pushtrack select=mode"]
    assert mine[1].knob == "pushtrack_select" and math.isnan(mine[1].value)
    assert mine[1].estimator_params == (("select", "mode"),)


def test_pushtrack_motion_is_a_choice_the_default_tip_runs_once():
    sweep = accuracy_settings((100,), (30,), (1,), (32,), (5,), paper_estimator=False, baselines=(),
                              pushtrack=(("motion", ("tip", "push", "sweep")),))
    mine = [s for s in sweep if s.estimator == "pushtrack"]
    assert [s.name for s in mine] == ["stucco pushtrack estimator", "stucco pushtrack motion=push",
                                      "stucco pushtrack motion=sweep"]
    assert mine[1].estimator_params == (("motion", "push"),)


def test_pushtrack_free_stretches_and_sweep_substeps_are_knobs():
    own = PushTrackParams()
    other = 15 if own.sweep_substeps != 15 else 8
    sweep = accuracy_settings((100,), (30,), (1,), (32,), (5,), paper_estimator=False, baselines=(),
                              pushtrack=(("free_stretches", (own.free_stretches, not own.free_stretches)),
                                         ("sweep_substeps", (own.sweep_substeps, other))))
    mine = [s for s in sweep if s.estimator == "pushtrack"]
    assert [s.name for s in mine] == ["stucco pushtrack estimator",
                                      f"stucco pushtrack free_stretches={int(not own.free_stretches)}",
                                      f"stucco pushtrack sweep_substeps={other}"]
    assert mine[1].estimator_params == (("free_stretches", not own.free_stretches),)


def test_bench_accuracy_rejects_an_unknown_free_stretches_value(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--pushtrack-free-stretches", "maybe", "--out",
                                   str(tmp_path)])
    assert res.exit_code != 0 and "maybe" in res.output and "Traceback" not in res.output


def test_bench_accuracy_rejects_an_unknown_motion(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--pushtrack-motion", "slide", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--pushtrack-motion" in res.output and "'slide'" in res.output


def test_bench_accuracy_rejects_an_unknown_select(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--pushtrack-select", "best", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--pushtrack-select" in res.output and "'best'" in res.output


def test_bench_accuracy_cli_tiny_grid(tmp_path):
    out = tmp_path / "acc"
    res = CliRunner().invoke(cli, ["-q", "bench", "accuracy", "--scenes", "FB", "--seeds", "0", "--N", "10,100",
                                   "--restarts", "5", "--sdf-mm", "1,4", "--hypotheses", "16",
                                   "--free-mm", "", "--no-paper-estimator", "--pushtrack-particles", "64",
                                   "--pushtrack-refine", "", "--pushtrack-substeps", "", "--pushtrack-starts", "",
                                   "--pushtrack-islands", "", "--pushtrack-select", "", "--pushtrack-motion", "",
                                   "--baselines", "dbscan",
                                   "--out",
                                   str(out)])
    assert res.exit_code == 0, res.output
    assert "knee" in res.output
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [r["setting"] for r in rows] == ["stucco N=10", "stucco N=100", "stucco restarts=5", "stucco sdf=4mm",
                                            "stucco hypotheses=16", "stucco pushtrack n_particles=64", "dbscan"]
    assert (out / "pareto.png").stat().st_size > 0


def test_bench_accuracy_over_estimator_streams(tmp_path):
    # Two streams: one row per (setting, run, stream); the tracking (CE, FMI) shared, GS their mean, runs counted once.
    out = tmp_path / "acc"
    res = CliRunner().invoke(cli, ["-q", "bench", "accuracy", "--scenes", "FB", "--seeds", "0", "--N", "30",
                                   "--restarts", "", "--sdf-mm", "", "--hypotheses", "", "--free-mm", "",
                                   "--no-paper-estimator", "--pushtrack-particles", "64", "--pushtrack-refine", "",
                                   "--pushtrack-substeps", "", "--pushtrack-starts", "", "--pushtrack-islands", "",
                                   "--pushtrack-select", "", "--pushtrack-motion", "", "--baselines", "",
                                   "--streams", "0,1",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "GS: the mean over estimator streams 0, 1" in res.output
    rows = list(csv.DictReader(open(out / "accuracy.csv")))
    assert [(r["setting"], r["stream"]) for r in rows] == [("stucco N=30", "0"), ("stucco N=30", "1"),
                                                          ("stucco pushtrack n_particles=64", "0"),
                                                          ("stucco pushtrack n_particles=64", "1")]
    for a, b in (rows[:2], rows[2:]):
        assert a["contact_error_cm"] == b["contact_error_cm"] and a["fmi"] == b["fmi"]
    assert rows[2]["position_error_m"] != rows[3]["position_error_m"]  # pushtrack's particles redrawn
    summary = {r["setting"]: r for r in csv.DictReader(open(out / "summary.csv"))}
    pt = summary["stucco pushtrack n_particles=64"]
    assert pt["runs"] == "1"
    assert float(pt["gs"]) == sum(r["grasp_success"] == "true" for r in rows[2:]) / 2
    assert {r["grasp_success"] for r in rows} <= {"true", "false"}
    bad = CliRunner().invoke(cli, ["bench", "accuracy", "--streams", "-1", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "--streams" in bad.output


def test_bench_accuracy_rejects_training_scene(tmp_path):
    res = CliRunner().invoke(cli, ["bench", "accuracy", "--scenes", "SELECT1", "--out", str(tmp_path)])
    assert res.exit_code == 2
    assert "training scene" in res.output


@pytest.fixture(scope="module")
def training_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("training")
    res = CliRunner().invoke(cli, ["-q", "study", "training", "--scenes", "SELECT1", "--seeds", "7-9",
                                   "--methods", "stucco,dbscan", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out, res.output


def test_study_training_tiny_grid(training_dir):
    out, output = training_dir
    assert "of 3 trajectories kept by the discard rule" in output
    rows = list(csv.DictReader(open(out / "training.csv")))
    assert {r["method"] for r in rows} == {"stucco", "dbscan"}
    assert all(0.0 <= float(r["ambiguity"]) <= 1.0 for r in rows)
    assert (out / "fig5.png").stat().st_size > 0


def test_study_tune_tiny_grid_reuses_training_runs(training_dir):
    out, _ = training_dir
    res = CliRunner().invoke(cli, ["-q", "study", "tune", "--scenes", "SELECT1", "--seeds", "7-9", "--methods",
                                   "stucco", "--values", '{"stucco": ["length", [0.01, 0.02]]}', "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "stucco: length = " in res.output
    rows = list(csv.DictReader(open(out / "tune.csv")))
    assert [float(r["value"]) for r in rows] == [0.01, 0.02]
    assert sum(r["chosen"].lower() == "true" for r in rows) == 1


def test_study_rejects_retrieval_scene(tmp_path):
    res = CliRunner().invoke(cli, ["study", "training", "--scenes", "FB", "--out", str(tmp_path)])
    assert res.exit_code == 2
    assert "not a training scene" in res.output


def test_evaluate_dask_backend_on_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    from pipeline.evaluate import EvalConfig
    from pipeline.evaluate import evaluate as run_evaluate

    cfg = EvalConfig(max_actions=4, grasp=False, restarts=2)
    local = run_evaluate(tmp_path / "loky", ["FB"], [0], ["stucco", "dbscan"], cfg, jobs=1, progress=True,
                         figures=False)
    # Worker threads in this process: worker processes would each import Open3D and compile numba's kernels
    # (tens of seconds); the scheduler, joblib's Dask backend and the job transport are the same.
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        res = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods",
                                       "stucco,dbscan", "--max-actions", "4", "--restarts", "2", "--no-figures",
                                       "--backend", "dask", "--scheduler", lc.scheduler_address,
                                       "--out", str(tmp_path / "dask")])
    assert res.exit_code == 0, res.output
    from pipeline.evaluate import Job, gather_scores

    jobs = [Job("FB", 0, m) for m in ("dbscan", "stucco")]
    dask_scores = gather_scores(tmp_path / "dask", jobs, cfg.estimators)
    assert dask_scores.num_rows == 2 * len(cfg.estimators)  # two jobs, every registered pose estimator each
    # the same jobs, the same seeds: tracking results do not depend on where a job ran
    assert dask_scores.column("fmi").to_pylist() == local.scores.column("fmi").to_pylist()
    assert dask_scores.column("n_points").to_pylist() == local.scores.column("n_points").to_pylist()


def test_evaluate_backend_errors(tmp_path):
    res = CliRunner().invoke(cli, ["evaluate", "--scenes", "FB", "--seeds", "0", "--backend", "dask",
                                   "--out", str(tmp_path)])
    assert res.exit_code == 1
    assert "needs --scheduler" in res.output


def test_evaluate_suite_training_tiny(tmp_path):
    res = CliRunner().invoke(cli, ["-q", "evaluate", "--suite", "training", "--scenes", "SELECT2", "--seeds", "7",
                                   "--methods", "stucco", "--max-actions", "20", "--out", str(tmp_path)])
    assert res.exit_code in (0, 1), res.output
    assert "trajectories kept" in res.output or "every training run was discarded" in res.output


def test_toppled_cylinder_contact_error_uses_mean_half_extent_circle():
    from pipeline.scenes import load_scene
    from pipeline.studies.training import _training_primitive

    scene = load_scene("SELECT2")
    spec = next(o for o in scene.objects if o.name == "topple_cylinder")
    prim = _training_primitive(spec)
    assert prim.kind == "cylinder" and prim.half == pytest.approx((0.1225,))
    d = prim.signed_distance(np.array([[0.2225, 0.0]]), np.array([0.1, 0.0, 0.3]))
    assert d == pytest.approx([0.0], abs=1e-9)
