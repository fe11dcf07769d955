"""retrieve: model points, planar ICP (no mirror images), the selection rule, hard cases, the stored FB run, CLI."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.retrieve import (
    CANDIDATES_COLUMNS,
    RETRIEVAL_COLUMNS,
    Primitive,
    RetrievalParams,
    choose_segment,
    estimate_run,
    icp_restarts,
    initial_transforms,
    load_run,
    min_clearance,
    model_normals,
    model_points,
    pose_error,
    primitive_of,
    read_retrieval,
    retrieval_rng,
    target_primitive,
)
from pipeline.robot import disc_sdf, load_robot
from pipeline.scenes import load_scene
from pipeline.schema import SchemaError, read_metadata, write_table

REGRESSION = Path(__file__).resolve().parents[1] / "data" / "regression" / "FB-000.parquet"
PARAMS = RetrievalParams()


def _rot(a):
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _posed(pose, local):
    return local @ _rot(pose[2]).T + np.asarray(pose[:2])


@pytest.fixture(scope="module")
def box() -> Primitive:
    return target_primitive(load_scene("FB"))[1]


@pytest.fixture(scope="module")
def can() -> Primitive:
    return target_primitive(load_scene("TC"))[1]


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


@pytest.fixture(scope="module")
def fb_run():
    return load_run(REGRESSION)


def _rngs(k=0):
    return retrieval_rng(k, "test/0")[:2]


# ------------------------------------------------------------------------------------------------ geometry


def test_primitive_of_cracker_box_is_the_hull_in_the_com_frame(box):
    # shape_offset (0.0275, -0.0108) minus com_offset (0.03, -0.01): the hull centre in the COM frame.
    np.testing.assert_allclose(box.centre, [-0.0025, -0.0008], atol=1e-12)
    assert box.half == pytest.approx((0.0308, 0.07875))
    assert box.symmetry == pytest.approx(math.pi)


def test_signed_distance_of_box_and_can(box, can):
    pose = np.array([0.3, 0.1, math.pi / 2])  # long side along world x now
    c = box.centre_world(pose)
    pts = np.array([c + [0.0, 0.0308 + 0.01], c + [0.07875 + 0.02, 0.0], c, c + [0.0, 0.0208]])
    np.testing.assert_allclose(box.signed_distance(pts, pose), [0.01, 0.02, -0.0308, -0.01], atol=1e-12)
    cc = can.centre_world(np.zeros(3))
    np.testing.assert_allclose(can.signed_distance(cc + [[0.039 + 0.005, 0.0], [0.0, 0.0]], np.zeros(3)),
                               [0.005, -0.039], atol=1e-12)


def test_model_points_lie_on_the_surface_and_are_seeded(box, can):
    a = model_points(box, PARAMS, _rngs(0)[0])
    b = model_points(box, PARAMS, _rngs(0)[0])
    c = model_points(box, PARAMS, _rngs(1)[0])
    assert a.shape == (50, 2)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    np.testing.assert_allclose(box.signed_distance(a, np.zeros(3)), 0.0, atol=1e-12)
    # Even coverage: every face gets points (the authors' tester sampling leaves the short faces nearly empty).
    q = a - box.centre
    assert np.sum(np.isclose(np.abs(q[:, 1]), box.half[1])) >= 5
    m = model_points(can, PARAMS, _rngs(0)[0])
    assert m.shape == (49, 2)
    np.testing.assert_allclose(can.signed_distance(m, np.zeros(3)), 0.0, atol=1e-12)
    t = model_points(box, RetrievalParams(box_sampling="tester"), _rngs(0)[0])
    assert t.shape == (50, 2)
    np.testing.assert_allclose(box.signed_distance(t, np.zeros(3)), 0.0, atol=1e-12)


def test_canonical_pose_is_a_half_turn_about_the_box_centre(box):
    pose = np.array([0.2, -0.1, 2.8])
    can_pose = box.canonical(pose)
    assert -math.pi / 2 <= can_pose[2] < math.pi / 2
    np.testing.assert_allclose(box.centre_world(can_pose), box.centre_world(pose), atol=1e-12)
    assert pose_error(box, can_pose, pose) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_pose_error_modulo_symmetry(box, can):
    truth = np.array([0.3, 0.0, 0.1])
    assert pose_error(box, truth + [0.0, 0.0, math.pi], truth)[1] == pytest.approx(0.0, abs=1e-12)
    assert pose_error(box, truth + [0.0, 0.0, math.pi / 2], truth)[1] == pytest.approx(math.pi / 2)
    assert pose_error(box, truth + [0.0, 0.0, -0.3 + math.pi], truth)[1] == pytest.approx(0.3)
    assert pose_error(box, truth + [0.03, 0.04, 0.0], truth)[0] == pytest.approx(0.05)
    assert pose_error(can, truth + [0.0, 0.0, 1.0], truth + [0.0, 0.0, 1.0])[1] == 0.0
    # The can's COM is 11 mm off its axis: rotating the estimate about the axis is no error.
    c = can.centre_world(truth)
    spun = np.r_[c - _rot(2.0) @ can.centre, 2.0]
    assert pose_error(can, spun, truth) == pytest.approx((0.0, 0.0), abs=1e-12)


# ------------------------------------------------------------------------------------------------ planar ICP


def _flat_cloud(pts):
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.column_stack([pts, np.zeros(len(pts))])))


def _origin_rotations(n, rng):
    # The authors' initial guesses: rotations about the world origin, zero translation (far from the data).
    return np.column_stack([np.zeros((n, 2)), rng.uniform(0, 2 * np.pi, n)])


def test_icp_never_returns_a_mirror_image_where_plain_open3d_does(box):
    # Open3D's 3-D ICP of flat clouds (which the project no longer uses) mirrors; the SE(2) ICP cannot.
    import open3d as o3d

    reg = o3d.pipelines.registration
    rng = np.random.default_rng(1)
    model = model_points(box, PARAMS, rng)
    truth = np.array([0.25, 0.05, 0.9])
    # Points on two faces of the posed box (world), flip-prone: all at one height.
    local = model[(model[:, 0] > 0.02) | (model[:, 1] > 0.07)]
    pts = _posed(truth, local)
    inits = _origin_rotations(30, rng)

    def matrix(tf):
        T = np.eye(4)
        T[:2, :2] = _rot(tf[2])
        T[:2, 3] = tf[:2]
        return T

    flat = [np.asarray(reg.registration_icp(_flat_cloud(pts), _flat_cloud(model), 1.0, matrix(tf),
                                            reg.TransformationEstimationPointToPoint(),
                                            reg.ICPConvergenceCriteria(max_iteration=30)).transformation)
            for tf in inits]
    mirrored = [T for T in flat if T[2, 2] < 0 or np.linalg.det(T[:2, :2]) < 0]
    assert mirrored, "plain Open3D should return a mirror image on these planar inputs"

    res = icp_restarts(pts, model, inits, PARAMS, model_normals(box, model))
    assert res.valid.all()  # SE(2) by construction: every result is a rotation about z
    assert np.all(np.isfinite(res.poses))
    # From restarts near the data, every restart that fits is the true pose, never its mirror image.
    res = icp_restarts(pts, model, initial_transforms(pts, model, 30, rng), PARAMS, model_normals(box, model))
    assert res.valid.all()
    good = res.rmse < 1e-6
    assert good.sum() >= 3
    for pose in res.poses[good]:
        assert pose_error(box, pose, truth) == pytest.approx((0.0, 0.0), abs=1e-6)
    # The point-to-point estimator (the one that flips when flat) gives proper rotations as well.
    p2p = icp_restarts(pts, model, inits, RetrievalParams(estimation="point_to_point"))
    assert p2p.valid.all() and np.all(np.isfinite(p2p.poses))


def test_icp_result_is_a_proper_rotation_about_z_for_random_inputs(box):
    rng = np.random.default_rng(7)
    model = model_points(box, PARAMS, rng)
    for _ in range(5):
        pts = rng.uniform(-0.3, 0.3, (int(rng.integers(1, 12)), 2))
        # (max_point_distance out of the way: every result of the SE(2) iteration is valid.)
        for params in (RetrievalParams(max_point_distance=1e3),
                       RetrievalParams(estimation="point_to_point", max_point_distance=1e3)):
            res = icp_restarts(pts, model, _origin_rotations(10, rng), params, model_normals(box, model))
            assert res.valid.all()
            assert np.all(np.isfinite(res.poses)) and np.all(np.isfinite(res.rmse))
        # The returned transform reproduces the error reported: it is the transform that was evaluated.
        moved = np.einsum("bij,mj->bmi", np.stack([_rot(t) for t in res.world_to_model[:, 2]]), pts) \
            + res.world_to_model[:, None, :2]
        d = np.sqrt(((moved[:, :, None] - model[None, None]) ** 2).sum(-1).min(-1).mean(-1))
        np.testing.assert_allclose(d, res.rmse, atol=1e-12)


def test_icp_recovers_exact_pose_from_exact_model_points(box):
    rm, rr = _rngs(3)
    model = model_points(box, PARAMS, rm)
    truth = np.array([0.31, -0.07, -2.2])
    pts = _posed(truth, model[::2])
    res = icp_restarts(pts, model, initial_transforms(pts, model, 30, rr), PARAMS, model_normals(box, model))
    best = int(np.argmin(res.rmse))
    assert res.rmse[best] < 1e-9
    np.testing.assert_allclose(res.poses[best][:2], truth[:2], atol=1e-9)
    assert abs((res.poses[best][2] - truth[2] + math.pi) % (2 * math.pi) - math.pi) < 1e-9


# ------------------------------------------------------------------------------------------------ choice rule


def test_choose_takes_lowest_position_variance_segment():
    rng = np.random.default_rng(0)
    tight = np.array([0.3, 0.0]) + rng.normal(0, 0.001, (30, 2))
    loose = np.array([0.1, 0.2]) + rng.normal(0, 0.02, (30, 2))
    z = np.zeros(30)
    ok = np.ones(30, bool)
    c = choose_segment([loose, tight], [z, z], [z + 0.01, z + 0.01], [ok, ok], 0.002)
    assert c.segment_index == 1
    assert c.position_var[1] == pytest.approx(np.var(tight, axis=0, ddof=1).sum())


def test_choose_skips_segments_that_do_not_fit_while_one_does():
    line_like = np.zeros((30, 2))  # every restart agrees exactly: variance 0
    spread = np.random.default_rng(1).normal(0, 0.01, (30, 2))
    ok = np.ones(30, bool)
    z = np.zeros(30)
    # The tight segment fits badly (3 cm), the other well: the fit gate keeps the variance rule to fitting ones.
    assert choose_segment([line_like, spread], [z, z], [z + 0.03, z + 0.001], [ok, ok], 0.01, 0.02).segment_index == 1
    assert choose_segment([line_like, spread], [z, z], [z + 0.03, z + 0.001], [ok, ok], 0.01, None).segment_index == 0
    # No segment fits: back to the paper's rule over all.
    assert choose_segment([line_like, spread], [z, z], [z + 0.03, z + 0.04], [ok, ok], 0.01, 0.02).segment_index == 0


def test_choose_variance_over_agreeing_restarts():
    # Segment 0: 10 restarts found the same pose (error 1 mm), 20 stopped elsewhere (error 2 cm, scattered).
    # Segment 1: all 30 moderately scattered at 4 mm. Over all restarts segment 1 agrees best; over the
    # restarts within 2 mm of each segment's best, segment 0 does.
    rng = np.random.default_rng(2)
    c0 = np.vstack([np.tile([0.3, 0.0], (10, 1)), rng.normal(0, 0.05, (20, 2))])
    e0 = np.r_[np.full(10, 0.001), np.full(20, 0.02)]
    c1 = rng.normal(0, 0.01, (30, 2))
    e1 = np.full(30, 0.004)
    ok = np.ones(30, bool)
    z = np.zeros(30)
    assert choose_segment([c0, c1], [z, z], [e0, e1], [ok, ok], 0.01, None, None).segment_index == 1
    ch = choose_segment([c0, c1], [z, z], [e0, e1], [ok, ok], 0.01, None, 0.002)
    assert ch.segment_index == 0 and ch.position_var[0] == pytest.approx(0.0, abs=1e-20)
    assert ch.restart < 10


def test_choose_least_penetration_then_lowest_icp_error():
    centres = [np.zeros((4, 2))]
    ok = [np.ones(4, bool)]
    # Penetration within the 2 mm tolerance ties; the tie goes to the lowest ICP error (the paper's rule).
    pen = [np.array([0.0, 0.0015, 0.01, 0.0])]
    err = [np.array([0.004, 0.002, 0.0001, 0.003])]
    assert choose_segment(centres, pen, err, ok, 0.002).restart == 1
    # Beyond the tolerance the penetration decides, whatever the error.
    pen = [np.array([0.02, 0.03, 0.01, 0.05])]
    assert choose_segment(centres, pen, err, ok, 0.002).restart == 2
    # Exact ties on both keys: the first restart.
    assert choose_segment(centres, [np.zeros(4)], [np.ones(4)], ok, 0.0).restart == 0


def test_min_clearance_with_a_disc_robot():
    sdf = disc_sdf(0.05)
    model = np.array([[0.0, 0.0], [0.01, 0.0]])
    poses = np.array([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    ee = np.array([[0.0, 0.0], [0.13, 0.0]])
    got = min_clearance(sdf, model, poses, ee)
    # pose 0: model points at 0.10, 0.11; ee 0.13 -> distances 0.03, 0.02 -> sdf -0.02, -0.03; ee 0 is 0.1 away,
    # beyond the grid (radius + 1 cm margin). pose 1: 0.07 and 0.08 from ee 0.13, also beyond: the outside value.
    np.testing.assert_allclose(got, [-0.03, sdf.outside_value], atol=1.5e-3)


# ------------------------------------------------------------------------------------------------ stored run


def _true_contacts_in_final_pose(info):
    """The run's recorded true contact points on the box, each moved with the box from the pose it had at its
    action to the final pose: what a perfect tracker would report at the end."""
    t = pq.read_table(info.path, columns=["true_contact_x_m", "true_contact_y_m", "object_id", "obj_pose"])
    tc = np.column_stack([t.column("true_contact_x_m").to_numpy(zero_copy_only=False),
                          t.column("true_contact_y_m").to_numpy(zero_copy_only=False)]).astype(float)
    oid = t.column("object_id").to_numpy()
    poses = np.array(t.column("obj_pose").to_pylist())[:, info.target_id]
    fin = info.true_pose
    out = []
    for k in np.flatnonzero(np.isfinite(tc).all(axis=1) & (oid == info.target_id)):
        local = _rot(-poses[k, 2]) @ (tc[k] - poses[k, :2])
        out.append(_rot(fin[2]) @ local + fin[:2])
    return np.array(out)


def test_retrieve_on_ground_truth_contacts_of_stored_run(fb_run, panda):
    pts = _true_contacts_in_final_pose(fb_run)
    assert len(pts) >= 15
    assert np.max(np.abs(fb_run.target.signed_distance(pts, fb_run.true_pose))) < 0.004
    for seed in range(3):
        est = estimate_run([(0, pts)], fb_run.target, fb_run.ee, panda, PARAMS, *retrieval_rng(seed, fb_run.run)[:2])
        pos, yaw = pose_error(fb_run.target, est.pose, fb_run.true_pose)
        assert pos < 0.01 and yaw < 0.1, (seed, est.pose, fb_run.true_pose)
        assert est.segment == 0 and est.n_points == len(pts)
        assert not est.low_confidence, est.notes


def test_retrieve_on_surface_samples_picks_the_box_over_the_can(fb_run, panda):
    rng = np.random.default_rng(5)
    box_local = model_points(fb_run.target, RetrievalParams(), rng)[:25]
    box_pts = _posed(fb_run.true_pose, box_local)
    can_spec = fb_run.scene.objects[1]
    can_prim = primitive_of(can_spec)
    can_pts = _posed(fb_run.final_poses[1], model_points(can_prim, PARAMS, rng)[10:30])
    est = estimate_run([(0, can_pts), (1, box_pts)], fb_run.target, fb_run.ee, panda, PARAMS,
                       *retrieval_rng(0, fb_run.run)[:2])
    assert est.segment == 1
    pos, yaw = pose_error(fb_run.target, est.pose, fb_run.true_pose)
    assert pos < 0.01 and yaw < 0.1
    cand = est.candidates
    assert len(cand["segment"]) == 60 and cand["chosen"].sum() == 1
    assert cand["segment_chosen"][cand["segment"] == 1].all()


# ------------------------------------------------------------------------------------------------ hard cases


def _est(segs, target, panda, ee=np.array([[0.0, 0.1]]), seed=0):
    return estimate_run(segs, target, ee, panda, PARAMS, *retrieval_rng(seed, "hard/0")[:2])


def _finite(est):
    assert np.all(np.isfinite(est.pose))
    assert np.all(np.isfinite(est.candidates["x_m"])) and np.all(np.isfinite(est.candidates["icp_rmse_m"]))


def test_icp_single_point_stays_finite_and_low_confidence(box, panda):
    est = _est([(0, np.array([[0.3, 0.05]]))], box, panda)
    _finite(est)
    assert est.low_confidence and "few_points" in est.notes
    assert abs(box.signed_distance(np.array([[0.3, 0.05]]), est.pose)[0]) < 0.006


def test_icp_two_points_stays_finite_and_low_confidence(box, panda):
    est = _est([(0, np.array([[0.3, 0.05], [0.3, 0.09]]))], box, panda)
    _finite(est)
    assert "few_points" in est.notes and "collinear" in est.notes


def test_icp_collinear_points_returns_low_confidence(box, panda):
    line = np.column_stack([np.full(12, 0.3), np.linspace(0.0, 0.12, 12)])
    est = _est([(0, line)], box, panda)
    _finite(est)
    assert est.low_confidence and "collinear" in est.notes
    assert np.max(np.abs(box.signed_distance(line, est.pose))) < 0.006  # still a pose that fits the line


def test_icp_duplicate_points_stay_finite(box, panda):
    est = _est([(0, np.tile([[0.3, 0.05]], (6, 1)))], box, panda)
    _finite(est)
    assert "collinear" in est.notes


def test_symmetric_can_position_found_yaw_reported_as_zero(can, panda):
    truth = np.array([0.2, 0.05, 1.3])
    arc = np.linspace(-2.2, 0.4, 15)
    local = can.centre + can.half[0] * np.column_stack([np.cos(arc), np.sin(arc)])
    pts = _posed(truth, local)
    est = _est([(0, pts)], can, panda)
    _finite(est)
    assert est.pose[2] == 0.0
    pos, yaw = pose_error(can, est.pose, truth)
    assert pos < 0.005 and yaw == 0.0
    assert not est.low_confidence, est.notes
    # Restarts reaching the can agree on its axis whatever their yaw (positions are of the axis, not the COM).
    cand = est.candidates
    fit = cand["icp_rmse_m"] < 1e-3
    assert fit.sum() >= 10
    centres = can.centre_world(np.column_stack([cand["x_m"], cand["y_m"], cand["yaw_rad"]])[fit])
    assert np.ptp(centres, axis=0).max() < 2e-3


def test_segment_far_from_target_is_not_chosen(box, panda):
    rm = retrieval_rng(9, "hard/0")[0]
    truth = np.array([0.28, 0.04, 0.2])
    near = _posed(truth, model_points(box, PARAMS, rm)[::3])
    far = np.column_stack([np.linspace(1.0, 1.0, 20), np.linspace(-0.6, 0.6, 20)])  # points on a far wall
    est = _est([(0, far), (1, near)], box, panda)
    _finite(est)
    assert est.segment == 1
    assert pose_error(box, est.pose, truth)[0] < 0.01


def test_segment_far_from_target_alone_is_flagged(box, panda):
    wall = np.column_stack([np.full(20, 1.0), np.linspace(-0.6, 0.6, 20)])
    est = _est([(0, wall)], box, panda)
    _finite(est)
    assert est.low_confidence and "poor_fit" in est.notes


def test_empty_segmentation_gives_finite_flagged_estimate(box, panda):
    ee = np.array([[0.0, 0.1], [0.05, 0.08]])
    est = _est([], box, panda, ee=ee)
    _finite(est)
    assert est.segment == -1 and est.n_points == 0 and est.notes == ["no_points"]
    np.testing.assert_allclose(est.pose, [0.05, 0.08, 0.0])
    assert len(est.candidates["segment"]) == 0


# ------------------------------------------------------------------------------------------------ stage + CLI


def _segments_table(run: str, pts: np.ndarray, segment: np.ndarray, object_id: np.ndarray | None = None) -> pa.Table:
    n = len(pts)
    cols = {"run": pa.array([run] * n), "step": pa.array(np.arange(n), pa.int64()),
            "contact_index": pa.array(np.zeros(n, np.int64)), "estimate_step": pa.array(np.full(n, 53, np.int64)),
            "x_m": pa.array(pts[:, 0]), "y_m": pa.array(pts[:, 1]),
            "tracker_label": pa.array(np.asarray(segment, np.int64)),
            "object_id": pa.array(np.zeros(n, np.int64) if object_id is None else np.asarray(object_id, np.int64)),
            "segment": pa.array(np.asarray(segment, np.int64))}
    return pa.table(cols)


@pytest.fixture()
def stage_inputs(tmp_path, fb_run):
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(REGRESSION, runs / REGRESSION.name)
    pts = _true_contacts_in_final_pose(fb_run)
    seg = tmp_path / "segments.parquet"
    write_table(_segments_table(fb_run.run, pts, np.zeros(len(pts))), seg, stage="segment",
                params={"method": "stucco"}, seed=0, kind="segments")
    return tmp_path, seg, runs


def _invoke(args):
    import stucco_cli.retrieve  # noqa: F401  (registers the commands)
    from stucco_cli.main import cli

    return CliRunner().invoke(cli, args)


def test_cli_retrieve_writes_both_tables(stage_inputs, fb_run):
    tmp, _, runs = stage_inputs
    # The paper's estimator runs at every in-contact step: here one, the last (step 53), holding every point.
    pts = _true_contacts_in_final_pose(fb_run)
    table = _segments_table(fb_run.run, pts, np.zeros(len(pts)))
    steps = np.arange(len(pts))
    steps[-1] = 53
    seg = tmp / "every.parquet"
    write_table(table.set_column(1, "step", pa.array(steps, pa.int64())), seg, stage="segment",
                params={"method": "stucco", "every_step": True}, seed=0, kind="segments")
    out = tmp / "retrieval.parquet"
    r = _invoke(["-q", "--seed", "0", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(out),
                 "--no-grasp", "--print", "--estimator", "paper"])
    assert r.exit_code == 0, r.output
    t = read_retrieval(out)
    assert t.column_names[:len(RETRIEVAL_COLUMNS)] == [c.name for c in RETRIEVAL_COLUMNS]
    row = t.to_pylist()[0]
    assert row["run"] == "FB/0" and row["scene"] == "FB" and row["seed"] == 0 and row["method"] == "stucco"
    assert row["estimator"] == "paper"
    assert row["position_error_m"] < 0.01 and row["yaw_error_rad"] < 0.1
    assert row["grasp_success"] is None and row["grasp_s"] is None
    assert "FB/0" in r.output  # --print goes to stdout
    cand = pq.read_table(tmp / "retrieval.candidates.parquet")
    assert cand.column_names == [c.name for c in CANDIDATES_COLUMNS]
    assert cand.num_rows == 30 and sum(cand.column("chosen").to_pylist()) == 1
    meta = read_metadata(out)
    assert meta["stage"] == "retrieve" and meta["schema"] == "retrieval" and meta["params"]["n_restarts"] == 30
    assert meta["params"]["estimator"] == "paper" and "plausible" not in meta["params"]
    assert meta["inputs"]["segments"]["file"] == "every.parquet"
    # Same seed, same estimate (timings aside).
    out2 = tmp / "again.parquet"
    assert _invoke(["-q", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(out2),
                    "--no-grasp", "--estimator", "paper"]).exit_code == 0
    a, b = read_retrieval(out).drop(["icp_s"]), read_retrieval(out2).drop(["icp_s"])
    assert a.equals(b)


def test_cli_retrieve_plausible_estimator_is_the_default(stage_inputs):
    tmp, seg, runs = stage_inputs
    out = tmp / "plausible.parquet"
    r = _invoke(["-q", "--seed", "0", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(out),
                 "--no-grasp", "--hypotheses", "16"])
    assert r.exit_code == 0, r.output
    row = read_retrieval(out).to_pylist()[0]
    assert row["estimator"] == "plausible" and row["position_error_m"] < 0.02
    meta = read_metadata(out)
    assert meta["params"]["estimator"] == "plausible" and meta["params"]["plausible"]["n_hypotheses"] == 16
    cand = pq.read_table(tmp / "plausible.candidates.parquet")
    assert sum(cand.column("chosen").to_pylist()) == 1 and all(cand.column("segment_chosen").to_pylist())
    bad = _invoke(["-q", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(tmp / "x.parquet"),
                   "--estimator", "mean"])
    assert bad.exit_code == 2 and "--estimator" in bad.output


def test_cli_retrieve_empty_segmentation_run_gets_a_flagged_row(tmp_path, stage_inputs):
    tmp, _, runs = stage_inputs
    seg = tmp / "empty.parquet"
    write_table(_segments_table("FB/0", np.zeros((0, 2)), np.zeros(0)), seg, stage="segment", params={}, seed=0,
                kind="segments")
    out = tmp / "r.parquet"
    r = _invoke(["-q", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(out), "--no-grasp"])
    assert r.exit_code == 0, r.output
    row = read_retrieval(out).to_pylist()[0]
    assert row["segment"] == -1 and row["low_confidence"] and row["notes"] == "no_points"
    assert math.isfinite(row["x_m"]) and row["icp_rmse_m"] is None


def test_cli_retrieve_takes_only_the_runs_the_segments_were_tracked_from(tmp_path, stage_inputs):
    # Another run in the same folder was never tracked into these segments: it gets no row (not a no_points row
    # claiming it had no contact); segments that record no runs still take every run file.
    tmp, _, runs = stage_inputs
    shutil.copy(REGRESSION.with_name("TC-000.parquet"), runs / "TC-000.parquet")
    empty = _segments_table("FB/0", np.zeros((0, 2)), np.zeros(0))
    recorded, bare = tmp / "recorded.parquet", tmp / "bare.parquet"
    write_table(empty, recorded, stage="segment", params={}, seed=0, kind="segments",
                inputs={"run": runs / REGRESSION.name})
    write_table(empty, bare, stage="segment", params={}, seed=0, kind="segments")
    assert read_metadata(recorded)["runs"].keys() == {"FB/0"}
    rows = {}
    for seg in (recorded, bare):
        out = tmp / f"r-{seg.stem}.parquet"
        r = _invoke(["-q", "retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(out), "--no-grasp"])
        assert r.exit_code == 0, r.output
        rows[seg.stem] = read_retrieval(out).column("run").to_pylist()
    assert rows == {"recorded": ["FB/0"], "bare": ["FB/0", "TC/0"]}
    # a recorded run whose file is not there is refused, naming it
    alone = tmp / "alone"
    alone.mkdir()
    shutil.copy(runs / "TC-000.parquet", alone / "TC-000.parquet")
    r = _invoke(["-q", "retrieve", "--segments", str(recorded), "--runs", str(alone), "--out", str(tmp / "y.parquet"),
                 "--no-grasp"])
    assert r.exit_code != 0 and "'FB/0' has no collected run file" in r.output


@pytest.mark.parametrize("case, pattern", [
    ("missing_segments", r"segments-nope\.parquet: file not found"),
    ("runs_not_dir", r"not a directory of collected runs"),
    ("run_without_file", r"run 'FB/7' has no collected run file"),
    ("not_segments", r"column 'segment': missing"),
])
def test_cli_retrieve_bad_inputs_fail_with_one_line(stage_inputs, case, pattern):
    import re

    tmp, seg, runs = stage_inputs
    args = ["retrieve", "--segments", str(seg), "--runs", str(runs), "--out", str(tmp / "o.parquet"), "--no-grasp"]
    if case == "missing_segments":
        args[2] = str(tmp / "segments-nope.parquet")
    elif case == "runs_not_dir":
        args[4] = str(tmp / "nowhere")
    elif case == "run_without_file":
        other = tmp / "other.parquet"
        write_table(_segments_table("FB/7", np.ones((3, 2)) * 0.2, np.zeros(3)), other, stage="segment", params={},
                    seed=0, kind="segments")
        args[2] = str(other)
    else:
        bad = tmp / "bad.parquet"
        pq.write_table(_segments_table("FB/0", np.ones((3, 2)), np.zeros(3)).drop(["segment"]), bad)
        args[2] = str(bad)
    r = _invoke(args)
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.output
    assert re.search(pattern, lines[0]), lines[0]
    assert not (tmp / "o.parquet").exists()


def test_retrieval_table_rejects_duplicate_runs():
    from pipeline.retrieve import retrieval_table

    row = {c.name: None for c in RETRIEVAL_COLUMNS}
    row.update(run="FB/0", scene="FB", seed=0, method="stucco", estimator="paper", target="cracker_box", x_m=0.0,
               y_m=0.0, yaw_rad=0.0,
               segment=0, n_points=3, n_segments=1, penetration_m=0.0, low_confidence=False, notes="",
               true_x_m=0.0, true_y_m=0.0, true_yaw_rad=0.0, position_error_m=0.0, yaw_error_rad=0.0,
               grasp_outcome="", icp_s=0.01)
    retrieval_table([row])
    with pytest.raises(SchemaError, match=r"column 'run', row 1: run 'FB/0' appears more than once"):
        retrieval_table([row, row])


def test_docs_describe_every_column():
    text = (Path(__file__).resolve().parents[1] / "docs" / "tables.md").read_text()
    from pipeline.score import SCORES_COLUMNS

    for c in RETRIEVAL_COLUMNS + CANDIDATES_COLUMNS + SCORES_COLUMNS:
        assert f"| `{c.name}` |" in text, c.name


def _emitted_notes() -> set[str]:
    """Every note string the estimators and the active protocol's retrieval emit: literals appended to a notes
    list, returned as one, or filtered in."""
    import ast

    found: set[str] = set()
    for mod in ("estimators/paper/choice", "estimators/estimate", "probe/belief", "probe/retrieval"):
        tree = ast.parse((Path(__file__).resolve().parents[1] / "pipeline" / f"{mod}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "append" and \
                    getattr(node.func.value, "id", "") == "notes":
                found |= {a.value for a in node.args if isinstance(a, ast.Constant)}
            elif isinstance(node, (ast.List, ast.Tuple)) and node.elts and all(
                    isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value.islower()
                    and "_" in e.value and " " not in e.value for e in node.elts):
                found |= {e.value for e in node.elts}
            elif isinstance(node, ast.keyword) and node.arg == "notes" and isinstance(node.value, ast.List):
                found |= {e.value for e in node.value.elts if isinstance(e, ast.Constant)}
    return found


def test_the_notes_column_lists_every_note_the_estimators_emit():
    from pipeline.schema.results import NOTES

    emitted = _emitted_notes()
    assert {"no_points", "no_free_space", "ambiguous_yaw", "wide_set", "no_valid_icp"} <= emitted
    assert emitted <= set(NOTES), sorted(emitted - set(NOTES))
    meaning = next(c.meaning for c in RETRIEVAL_COLUMNS if c.name == "notes")
    assert all(n in meaning for n in NOTES)


def test_the_paper_choice_is_computed_once_for_the_estimators_that_start_from_it(fb_run, panda, monkeypatch):
    """The plausible and pushtrack estimators start from the paper's choice on the final points of the same run:
    computed once per job, the same estimate (a copy) and the same results as with the choice computed afresh."""
    from pipeline.estimators import estimate as estimators
    from pipeline.estimators.estimate import Segment, estimate

    pts = _true_contacts_in_final_pose(fb_run)
    segs = [Segment(0, pts, np.arange(len(pts))), Segment(1, pts[:5] + 0.2, np.zeros(5, dtype=int))]
    calls = []
    real = estimators.estimate_run
    monkeypatch.setattr(estimators, "estimate_run", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(estimators, "_LAST_PAPER", [])
    first = estimators.paper_choice(segs, fb_run, panda, RetrievalParams(), retrieval_rng(0, fb_run.run))
    # the stage loads the robot's grid afresh for each estimator (another object, the same grid)
    shared = estimate("plausible", segs, fb_run, load_robot("panda"), retrieval_rng(0, fb_run.run))
    assert len(calls) == 1
    monkeypatch.setattr(estimators, "_LAST_PAPER", [])
    fresh = estimate("plausible", segs, fb_run, panda, retrieval_rng(0, fb_run.run))
    assert len(calls) == 2
    np.testing.assert_array_equal(shared.pose, fresh.pose)
    for k in fresh.candidates:
        np.testing.assert_array_equal(shared.candidates[k], fresh.candidates[k])
    again = estimators.paper_choice(segs, fb_run, panda, RetrievalParams(), retrieval_rng(0, fb_run.run))
    assert len(calls) == 2 and again is not first
    np.testing.assert_array_equal(again.pose, first.pose)
    other = estimators.paper_choice(segs, fb_run, panda, RetrievalParams(), retrieval_rng(1, fb_run.run))
    assert len(calls) == 3 and other.segment == first.segment  # other generators: computed


def test_retrieval_streams_are_independent_and_stream_0_is_the_default():
    from pipeline.estimators.run_info import _STREAM, run_key

    old = [np.random.default_rng(c) for c in np.random.SeedSequence([3, run_key("FB-001"), _STREAM]).spawn(3)]
    assert [g.integers(2 ** 62) for g in retrieval_rng(3, "FB-001")] == [g.integers(2 ** 62) for g in old]
    assert [g.integers(2 ** 62) for g in retrieval_rng(3, "FB-001", 0)] == [g.integers(2 ** 62) for g in
                                                                           retrieval_rng(3, "FB-001")]
    draws = {(s, i): g.integers(2 ** 62) for s in range(4) for i, g in enumerate(retrieval_rng(3, "FB-001", s))}
    assert len(set(draws.values())) == len(draws)  # no generator of any stream repeats another's
    assert [g.integers(2 ** 62) for g in retrieval_rng(3, "FB-001", 2)] == [draws[(2, i)] for i in range(3)]
    # nor what stream 0's generators would spawn (a SeedSequence's spawn key extends its entropy)
    spawned = {g.integers(2 ** 62) for k in range(3) for g in retrieval_rng(3, "FB-001")[k].spawn(3)}
    assert not spawned & set(draws.values())
    for bad in (-1, 1.0, True):
        with pytest.raises(ValueError, match="stream must be a non-negative integer"):
            retrieval_rng(3, "FB-001", bad)


def test_cli_retrieve_stream_reruns_the_estimators_draws(stage_inputs):
    tmp, seg, runs = stage_inputs
    base = ["-q", "--seed", "0", "retrieve", "--segments", str(seg), "--runs", str(runs), "--no-grasp",
            "--hypotheses", "16"]
    for name, extra in (("s0", []), ("s1", ["--stream", "1"]), ("s1b", ["--stream", "1"])):
        r = _invoke(base + ["--out", str(tmp / f"{name}.parquet"), *extra])
        assert r.exit_code == 0, r.output
    cand = {k: pq.read_table(tmp / f"{k}.candidates.parquet") for k in ("s0", "s1", "s1b")}
    assert cand["s1"].equals(cand["s1b"]) and not cand["s1"].equals(cand["s0"])
    assert read_metadata(tmp / "s1.parquet")["params"]["stream"] == 1
    assert "stream" not in read_metadata(tmp / "s0.parquet")["params"]
    bad = _invoke(base + ["--out", str(tmp / "x.parquet"), "--stream", "-1"])
    assert bad.exit_code == 2 and "--stream" in bad.output and not (tmp / "x.parquet").exists()
