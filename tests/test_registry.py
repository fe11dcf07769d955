"""The registry (pipeline/registry.py): one list of trackers, estimators and policies, and the proof that a new
tracker and a new pose estimator plug in from outside the package (this file alone) and run through the CLI."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import registry
from pipeline.estimators.paper.choice import Estimate
from pipeline.schema.retrieval import CANDIDATE_FIELDS, run_candidates
from pipeline.track.base import StepResult

ROOT = Path(__file__).resolve().parents[1]
REGRESSION = ROOT / "data" / "regression"


# --------------------------------------------------------------------------------------------- the registry itself
def test_builtin_names_in_report_order_with_the_default_first():
    assert registry.tracker_names() == ("stucco", "birch", "dbscan", "kmeans", "gmphd")
    assert registry.baseline_names() == ("birch", "dbscan", "kmeans", "gmphd")
    assert registry.estimator_names() == ("plausible", "paper", "pushtrack")
    assert registry.DEFAULT_ESTIMATOR == "plausible" and registry.estimator("paper").needs == ("every_step",)
    assert registry.policy_names() == ("scripted", "greedy-walk", "scripted+probe", "explore", "rummage")
    assert registry.default_policy("retrieval") == "scripted" and registry.default_policy("training") == "greedy-walk"
    assert registry.method_title("stucco") == "ours (STUCCO)"
    assert registry.method_title("unregistered") == "unregistered"


def test_every_builtin_spec_resolves_to_its_factory_and_parameter_class():
    for spec in registry.trackers():
        assert callable(registry.resolve(spec.factory))
        params = registry.build_params(spec)
        assert type(params) is registry.resolve(spec.params)
        if spec.tune is not None:  # the tuned parameter exists and its default is on the grid
            assert getattr(params, spec.tune[0]) in spec.tune[1]
    for spec in (*registry.estimators(), *registry.policies()):
        assert callable(registry.resolve(spec.factory))


def test_unknown_names_are_refused_with_the_known_ones_listed():
    with pytest.raises(ValueError, match=r"unknown method 'nope'; expected one of stucco, birch"):
        registry.tracker("nope")
    with pytest.raises(ValueError, match=r"unknown estimator 'icp'; expected one of plausible, paper"):
        registry.estimator("icp")
    with pytest.raises(ValueError, match=r"unknown policy 'walk'; expected one of scripted, greedy-walk"):
        registry.policy("walk")


def test_a_taken_or_malformed_name_is_refused():
    spec = registry.tracker("birch")
    with pytest.raises(ValueError, match="tracker 'birch' is already registered"):
        registry.register(spec)
    for bad in ("", "all", "a,b"):
        with pytest.raises(ValueError, match="invalid tracker name"):
            registry.register(registry.TrackerSpec(bad, "t", None, lambda p, r, g: None))


def test_build_params_refuses_unknown_fields_and_parameters_for_a_spec_without_any():
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) 'foo' for method 'dbscan'"):
        registry.build_params(registry.tracker("dbscan"), {"foo": 1})
    with pytest.raises(ValueError, match="estimator 'paper' takes no parameters"):
        registry.build_params(registry.estimator("paper"), {"n_hypotheses": 3})
    assert registry.build_params(registry.estimator("paper")) is None


def test_importing_the_registry_imports_no_stage():
    code = "import sys, pipeline.registry; print(' '.join(sorted(m for m in sys.modules if m.startswith('pipeline'))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.split() == ["pipeline", "pipeline.registry"]


def test_cli_choices_are_read_when_the_command_runs():
    choice = registry.choices("estimator")
    assert "later" not in choice.choices
    registry.register(registry.EstimatorSpec("later", "registered after the choice", lambda *a: None))
    try:
        assert list(choice.choices) == [*registry.estimator_names()] and "later" in choice.choices
    finally:
        registry.unregister("estimator", "later")


def test_run_candidates_checks_the_columns_against_the_candidates_spec():
    ok = _toy_candidates(np.array([0, 1]), np.zeros((2, 2)), np.array([3, 4]), chosen=0)
    assert tuple(ok) == CANDIDATE_FIELDS
    with pytest.raises(ValueError, match=r"missing column\(s\) \['chosen'\]"):
        run_candidates(**{k: v for k, v in ok.items() if k != "chosen"})
    with pytest.raises(ValueError, match="different lengths"):
        run_candidates(**dict(ok, rank=np.zeros(5)))


# --------------------------------------------------------------------- a toy tracker and estimator, from here only
@dataclass(frozen=True)
class ToyParams:
    """Every point is reported where it was observed, shifted by ``shift`` metres in x; all points one object."""

    shift: float = 0.0


class ToyTracker:
    """Keeps the observed contact points; one object. Implements pipeline.track.base.ContactTracker."""

    def __init__(self, params: ToyParams) -> None:
        self.params = params
        self._points = np.zeros((0, 2))

    def update(self, x, dx, p) -> StepResult:
        if p is not None:
            self._points = np.vstack([self._points, np.asarray(p, float) + [self.params.shift, 0.0]])
        return StepResult()

    @property
    def points_(self) -> np.ndarray:
        return self._points.copy()

    def labels(self) -> np.ndarray:
        return np.zeros(len(self._points), dtype=np.int64)


def _toy_candidates(ids, centres, sizes, chosen):
    n = len(ids)
    return run_candidates(segment=ids, restart=np.zeros(n, np.int64), n_points=sizes, x_m=centres[:, 0],
                          y_m=centres[:, 1], yaw_rad=np.zeros(n), icp_rmse_m=np.zeros(n),
                          penetration_m=np.zeros(n), valid=np.ones(n, bool), position_var_m2=np.full(n, np.nan),
                          rank=np.zeros(n, np.int64), segment_chosen=np.arange(n) == chosen,
                          chosen=np.arange(n) == chosen)


def toy_estimator(segments, info, sdf, rngs, params, own) -> Estimate:
    """The centroid of the largest segment, yaw 0 (the last gripper position without points)."""
    if not segments:
        ee = np.asarray(info.ee).reshape(-1, 2)
        return Estimate(np.array([ee[-1, 0], ee[-1, 1], 0.0]), -1, 0, 0, np.inf, np.nan, 0.0, ["no_points"],
                        _toy_candidates(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, np.int64), -1), 0.0)
    sizes = np.array([len(s.points) for s in segments])
    best = int(np.argmax(sizes))
    centres = np.array([np.mean(s.points, axis=0) for s in segments])
    return Estimate(info.target.canonical(np.array([*centres[best], 0.0])), segments[best].id, int(sizes[best]),
                    len(segments), np.inf, np.nan, 0.0, [],
                    _toy_candidates(np.array([s.id for s in segments]), centres, sizes, best), 0.0)


@pytest.fixture
def toy():
    """Register the toy tracker and estimator for one test, from this file alone."""
    registry.register(registry.TrackerSpec("toy", "Toy tracker", ToyParams, lambda prm, robot, rng: ToyTracker(prm),
                                           tune=("shift", (0.0, 0.01))))
    registry.registers(registry.EstimatorSpec, "toy", "Toy centroid")(toy_estimator)  # the decorator form
    yield
    registry.unregister("tracker", "toy")
    registry.unregister("estimator", "toy")


def _cli(*args: str):
    from stucco_cli.main import cli

    res = CliRunner().invoke(cli, ["-q", *args])
    assert res.exit_code == 0, res.output
    return res


def test_a_tracker_and_an_estimator_registered_here_run_through_the_cli(toy, tmp_path):
    # stucco evaluate on a stored run: track, segment, retrieve (with the grasp) and score with both toys.
    ev = tmp_path / "ev"
    _cli("evaluate", "--from-runs", str(REGRESSION), "--scenes", "FB", "--seeds", "0", "--methods", "toy",
         "--estimators", "toy", "--no-figures", "--out", str(ev))
    scores = pq.read_table(ev / "scores").to_pylist()
    assert [(r["method"], r["estimator"]) for r in scores] == [("toy", "toy")]
    assert scores[0]["fmi"] is not None and 0.0 <= scores[0]["fmi"] <= 1.0
    assert "Toy tracker" in (ev / "report.md").read_text()  # the report's title comes from the registry

    # The single stages on the evaluation's files: the same commands a user runs.
    contacts = next((ev / "contacts").rglob("*.parquet"))
    tracks, segments, retrieval = tmp_path / "t.parquet", tmp_path / "s.parquet", tmp_path / "r.parquet"
    _cli("track", "--in", str(contacts), "--out", str(tracks), "--method", "toy", "--robot", "disc:0.05",
         "--set", "shift=0.5")
    t = pq.read_table(tracks)
    c = pq.read_table(contacts)
    observed = c.filter(c.column("in_contact")).column("contact_x_m").to_numpy()
    np.testing.assert_allclose(t.column("x_m").to_numpy(), observed + 0.5)  # every contact, in order, shifted
    meta = json.loads(pq.read_schema(tracks).metadata[b"stucco.params"])
    assert meta["method"] == "toy" and meta["shift"] == 0.5
    _cli("segment", "--in", str(tracks), "--out", str(segments))
    assert set(pq.read_table(segments).column("segment").to_pylist()) == {0}  # by=auto: the toy's own labels
    _cli("retrieve", "--segments", str(segments), "--runs", str(REGRESSION / "FB-000.parquet"), "--out",
         str(retrieval), "--estimator", "toy", "--no-grasp")
    row, = pq.read_table(retrieval).to_pylist()
    assert (row["method"], row["estimator"], row["segment"]) == ("toy", "toy", 0)
    np.testing.assert_allclose([row["x_m"], row["y_m"]], np.mean(np.column_stack(
        [t.column("x_m").to_numpy(), t.column("y_m").to_numpy()]), axis=0))


def test_toy_names_leave_with_the_fixture_and_are_refused_after():
    from stucco_cli.main import cli

    assert "toy" not in registry.tracker_names()
    res = CliRunner().invoke(cli, ["retrieve", "--segments", "s", "--runs", "r", "--out", "o", "--estimator", "toy"])
    assert res.exit_code == 2 and "'toy' is not one of 'plausible', 'paper', 'pushtrack'" in res.output


class StillPolicy:
    """Toy collection policy: the scene's gripper start, then ``params.steps`` actions of zero (never moves)."""

    discards = False
    goal = None

    def __init__(self, scene, policy_rng, noise_rng, max_actions, params) -> None:
        self.gripper_start, self.steps = scene.gripper_start, params.steps

    def start(self, world) -> None:
        pass

    def plan(self) -> int:
        return self.steps

    def action(self, world, k, last_contact):
        return np.zeros(2)


@dataclass(frozen=True)
class StillParams:
    steps: int = 2


def test_a_collection_policy_registered_here_runs_through_the_cli(tmp_path):
    registry.register(registry.PolicySpec("still", "Toy: stand still", StillPolicy, params=StillParams,
                                          needs=(("actions", "action sequence"),)))
    try:
        _cli("collect", "--scene", "FB", "--seeds", "0", "--policy", "still", "--out", str(tmp_path))
    finally:
        registry.unregister("policy", "still")
    path, = tmp_path.glob("*.parquet")
    run = pq.read_table(path)
    assert run.num_rows == 2 and set(run.column("cmd_ux").to_pylist()) == {0.0}
    assert json.loads(pq.read_schema(path).metadata[b"stucco.params"])["policy"] == "still"
