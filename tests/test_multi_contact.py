"""Several contact points in one control step (paper §V-E), through every registered tracker, the segment stage and
the pose estimators.

A contacts table may hold K >= 1 rows for one in-contact step (docs/tables.md). Each tracker's ``update(x, dx, p)``
takes the K points of a step at once; for STUCCO every existing point is connected to its *nearest* new point
(measured at that point's pre-motion location ``p - dx``) with probability exp(-d^2 / l) and, if connected, moves
with that point's own ``dx`` (pipeline/track/kernels.py, ``_predict_particle``). The tests below check that rule
directly, that K points per step come out as K tracked rows numbered 0..K-1 by every tracker, and that such
tables go through ``track_file`` -> ``segment_file`` -> ``retrieve_log`` for every tracker and estimator.
"""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.special import logsumexp

from pipeline import registry, schema
from pipeline.parallel import single_threaded
from pipeline.retrieve.log_route import retrieve_log
from pipeline.retrieve.stage import RetrieveConfig
from pipeline.robot import load_robot
from pipeline.seeds import run_rng
from pipeline.segment import segment_file, segment_table, segmentation_params
from pipeline.track.kernels import penetration_bruteforce
from pipeline.track.soft import SoftTracker, SoftTrackingParams
from pipeline.track.stage import WARM_UP_LOG, TrackConfig, build_tracker, track_file, track_table

DISC = "disc:0.05"
RADIUS = 0.05  # the disc robot's radius, m
TOL = 0.002  # STUCCO's default intersection tolerance, m
TRACKERS = registry.tracker_names()


@pytest.fixture(autouse=True, scope="module")
def _one_thread_per_library():
    """One thread per numeric library, as every evaluation job runs (:func:`pipeline.parallel.single_threaded`):
    on a busy two-core machine scikit-learn's OpenMP threads only spin, and a k-means test took 9 s instead of
    0.2 s (the same reason as in tests/test_cluster.py)."""
    with single_threaded():
        yield


def small(method: str, **stucco) -> dict:
    """Parameter overrides that keep a test fast: few particles for STUCCO, the defaults for the others."""
    return dict(n_particles=16, **stucco) if method == "stucco" else {}


def contacts(rows) -> pa.Table:
    """A validated contacts table from rows (run, step, ee (x, y), contact (x, y) or None, dx (dx, dy) or None,
    object_id); rows of one step share the end-effector position (metres)."""
    def col(i, k):
        return pa.array([None if r[i] is None else float(r[i][k]) for r in rows], pa.float64())

    return schema.validate_contacts(pa.table({
        "run": pa.array([r[0] for r in rows], pa.string()),
        "step": pa.array([r[1] for r in rows], pa.int64()),
        "ee_x_m": pa.array([float(r[2][0]) for r in rows]), "ee_y_m": pa.array([float(r[2][1]) for r in rows]),
        "in_contact": pa.array([r[3] is not None for r in rows]),
        "contact_x_m": col(3, 0), "contact_y_m": col(3, 1), "dx_m": col(4, 0), "dy_m": col(4, 1),
        "object_id": pa.array([r[5] for r in rows], pa.int64()),
    }))


def on_disc(x, angle):
    """The point of the disc's rim at ``angle`` (rad) when its centre is at ``x``."""
    return np.asarray(x, float) + RADIUS * np.array([np.cos(angle), np.sin(angle)])


def finger_rows(run="fingers", n=6):
    """The disc pushing in +x, 1 cm per step, with two 'finger sensors': one on the target (object 0, moved the
    whole step) and one on a neighbour 4 cm away (object 1, touched later in the step: dx 6 mm), except at the first
    contact step (the target alone); the fourth contact step adds a third contact on the target, and every other
    contact step is followed by a free-space step. K = 1, 2 and 3 contacts per step."""
    rows, x, step = [(run, 0, (-0.02, 0.0), None, None, -1)], np.zeros(2), 1
    for i in range(n):
        x = x + [0.01, 0.0]
        rows.append((run, step, x, on_disc(x, -0.4), (0.01, 0.0), 0))
        if i > 0:
            rows.append((run, step, x, on_disc(x, 0.45), (0.006, 0.0), 1))
        if i == 3:
            rows.append((run, step, x, on_disc(x, 0.0), (0.01, 0.0), 0))
        step += 1
        if i % 2 == 1:
            rows.append((run, step, x - [0.005, 0.0], None, None, -1))
            step += 1
    return rows


def coincident_rows(run="same", k2=2):
    """The disc pushing in +x; at step 2, ``k2`` contacts at the very same point with the same dx."""
    rows, x = [(run, 0, (-0.02, 0.0), None, None, -1)], np.zeros(2)
    for step, k in ((1, 1), (2, k2), (3, 1), (4, 1)):
        x = x + [0.01, 0.0]
        rows += [(run, step, x, on_disc(x, 0.1), (0.01, 0.0), 0)] * k
    rows.append((run, 5, x - [0.01, 0.0], None, None, -1))
    return rows


def column(table, name):
    return table.column(name).to_numpy(zero_copy_only=False)


def xy(table):
    return np.column_stack([column(table, "x_m"), column(table, "y_m")])


def n_contact_rows(table) -> int:
    return int(np.sum(column(table, "in_contact")))


def segments_of(tracks, method, params):
    length, alpha = segmentation_params(method, params)
    return segment_table(tracks, length=length, alpha=alpha, method=method)


def assert_weights_sane(tracker: SoftTracker):
    lw = tracker.log_weights_
    assert np.all(np.isfinite(lw)) and logsumexp(lw) == pytest.approx(0.0, abs=1e-9)
    assert np.isfinite(tracker.last_step_.ess) and 0.0 < tracker.last_step_.ess <= 1.0
    assert np.all(np.isfinite(tracker.particle_points_)) and np.all(np.isfinite(tracker.points_))


def test_every_tracker_of_the_paper_is_registered():
    # the parametrisations below go over the registry: make sure it holds the paper's Table II
    assert {"stucco", "birch", "dbscan", "kmeans", "gmphd"} <= set(TRACKERS)


# ------------------------------------------------------------------------------- 1. coincident contacts
@pytest.mark.parametrize("method", TRACKERS)
def test_two_contacts_at_the_same_point_are_two_identical_points_of_one_segment(method):
    t = contacts(coincident_rows())
    config = TrackConfig(method=method, robot=DISC, params=small(method), every_step=True)
    tracks, diag = track_table(t, config, seed=0)
    schema.validate_tracks(tracks)
    assert np.all(np.isfinite(xy(tracks)))
    np.testing.assert_array_equal(column(diag, "n_contacts"), [0, 1, 2, 1, 1, 0])
    ess = column(diag, "ess")
    assert np.all(np.isfinite(ess)) and np.all((ess > 0) & (ess <= 1))
    # right after step 2 both of its points are tracked, at the same place
    at2 = tracks.filter(pc.and_(pc.equal(tracks["estimate_step"], 2), pc.equal(tracks["step"], 2)))
    np.testing.assert_array_equal(column(at2, "contact_index"), [0, 1])
    pair = xy(at2)
    np.testing.assert_array_equal(pair[0], pair[1])
    # the final estimate holds every contact row, and the pair is one segment
    segs = segments_of(tracks, method, config.params)
    final = segs.filter(pc.equal(segs["estimate_step"], 5))
    assert final.num_rows == n_contact_rows(t) == 5
    seg = column(final, "segment")
    assert np.all(seg >= 0)
    assert len(set(seg[column(final, "step") == 2])) == 1


def test_coincident_contacts_keep_stucco_weights_finite_when_the_robot_sweeps_through_them(disc):
    tracker = SoftTracker(disc, SoftTrackingParams(n_particles=16, replace="every-step"), rng=np.random.default_rng(0))
    p0 = on_disc([0.0, 0.0], 0.0)
    tracker.update([0.0, 0.0], np.zeros((1, 2)), p0[None])
    # the disc moves 4 mm in +x and three sensors report the same contact: its pre-motion point is the old point's
    x1, p1 = np.array([0.004, 0.0]), p0 + [0.004, 0.0]
    tracker.update(x1, np.full((3, 2), [0.004, 0.0]), np.repeat(p1[None], 3, axis=0))
    assert_weights_sane(tracker)
    # every particle holds four identical points: the old one moved with the new ones, which entered at the contact
    np.testing.assert_allclose(tracker.particle_points_, np.broadcast_to(p1, (16, 4, 2)), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(tracker.labels(), [0, 0, 0, 0])
    # free space with the disc's centre 2 cm from the points: all four penetrate it 3 cm, in every particle
    x2 = p1 - [0.02, 0.0]
    assert np.all(disc.query(tracker.particle_points_.reshape(-1, 2) - x2) + TOL < -0.02)
    tracker.update(x2)
    assert_weights_sane(tracker)
    assert tracker.n_points_ == 4


# ------------------------------------------------------------------------------- 2. two objects far apart
A, B, C = np.array([RADIUS, 0.0]), np.array([0.55, 0.0]), np.array([0.25, 0.3])
A2, B2 = A + [0.0, 0.004], B + [0.004, 0.0]  # 4 mm from A and B: connected with probability exp(-1.6e-5 / l)
DX_A, DX_B = np.array([0.01, 0.0]), np.array([0.0, 0.02])
X0, X1 = np.zeros(2), np.array([0.01, 0.0])


def two_object_steps():
    """Step 0: five points (A, A', B, B', and C far from both) touched without displacement. Step 1: two contacts,
    one on object A (moved by DX_A) and one on object B half a metre away (moved by DX_B), whose pre-motion points
    are exactly A and B."""
    return [(X0, np.zeros((5, 2)), np.stack([A, A2, B, B2, C])),
            (X1, np.stack([DX_A, DX_B]), np.stack([A + DX_A, B + DX_B]))]


def test_stucco_moves_each_point_with_the_dx_of_its_nearest_new_contact(disc):
    n = 32
    # l = 0.01 m^2: a point 4 mm from a new contact joins it with probability 0.998, one 0.39 m away with e^-15
    tracker = SoftTracker(disc, SoftTrackingParams(n_particles=n, length=0.01, replace="never"),
                          rng=np.random.default_rng(3))
    (x0, dx0, p0), (x1, dx1, p1) = two_object_steps()
    tracker.update(x0, dx0, p0)
    before = tracker.particle_points_.copy()
    tracker.update(x1, dx1, p1)
    assert_weights_sane(tracker)
    moved = tracker.particle_points_[:, :5] - before  # (N, 5, 2); replace="never": only the prediction moved them
    for j, dx in ((0, DX_A), (1, DX_A), (2, DX_B), (3, DX_B), (4, np.zeros(2))):
        # each old point either stays or moves with the dx of its own nearest new contact, never with the other's
        still = np.all(moved[:, j] == 0.0, axis=1)
        with_own = np.all(np.isclose(moved[:, j], dx, rtol=0, atol=1e-15), axis=1)
        assert np.all(still | with_own), (j, moved[:, j])
        if j in (0, 2):  # at distance 0 from the new contact's pre-motion point: always connected
            assert with_own.all()
        elif j in (1, 3):
            assert with_own.mean() >= 0.9
        else:  # C, 0.39 m from both contacts, is not connected
            assert still.all()
    # the MAP particle: A's points moved by A's dx, B's by B's dx, C stayed; new points at the observed contacts
    expect = np.stack([A + DX_A, A2 + DX_A, B + DX_B, B2 + DX_B, C, A + DX_A, B + DX_B])
    np.testing.assert_allclose(tracker.points_, expect, rtol=0, atol=1e-15)
    # Alg. 3 separates the two objects (and C): A's three points, B's three points, C alone
    np.testing.assert_array_equal(tracker.labels(), [0, 0, 1, 1, 2, 0, 1])
    # the particles' penetration bookkeeping is exact after a step with two different displacements
    colpen, npen = penetration_bruteforce(tracker._P, tracker._C, tracker.n_points_, disc.query, TOL)
    np.testing.assert_array_equal(tracker._npen[:, : tracker.n_points_], npen)
    np.testing.assert_allclose(tracker._colpen[:, : tracker.n_points_], colpen, rtol=0, atol=1e-12)


def two_objects_pushed_rows(n=5):
    """Step 0: A and B (0.5 m apart) touched without displacement; steps 1..n: both pushed at once, A by DX_A and B
    by DX_B, each contact's pre-motion point exactly the object's previous contact. Object ids 0 (A), 1 (B)."""
    rows = [("far", 0, X0, A, (0.0, 0.0), 0), ("far", 0, X0, B, (0.0, 0.0), 1)]
    for s in range(1, n + 1):
        rows += [("far", s, X0 + s * DX_A, A + s * DX_A, DX_A, 0), ("far", s, X0 + s * DX_A, B + s * DX_B, DX_B, 1)]
    return rows


@pytest.mark.parametrize("method", TRACKERS)
def test_two_objects_half_a_metre_apart_pushed_at_once_are_separated_by_every_tracker(method):
    n = 5
    t = contacts(two_objects_pushed_rows(n))
    params = small(method, length=0.01)
    tracks, _ = track_table(t, TrackConfig(method=method, robot=DISC, params=params), seed=0)
    assert tracks.num_rows == 2 * (n + 1) and np.all(np.isfinite(xy(tracks)))
    seg = column(segments_of(tracks, method, params), "segment")
    obj = column(tracks, "object_id")
    # object A's points and object B's points are never in one segment
    assert not set(seg[obj == 0]) & set(seg[obj == 1]), seg
    if method in ("stucco", "birch", "dbscan"):
        # Distance-based: each object is one segment from the start, and every point of it moved with its own
        # contact's displacement at every later step (STUCCO: its nearest new point's dx, here at distance 0, so
        # always connected; the baselines: the mean dx of the new points of its cluster, here that one point).
        # k-means (k starts at 1) and GM-PHD (targets by weight) join A and B for the first step, moving both by
        # the mean of the two displacements, as their rule says, and separate them afterwards.
        assert len(set(seg[obj == 0])) == len(set(seg[obj == 1])) == 1
        pts, steps = xy(tracks), column(tracks, "step")
        np.testing.assert_allclose(pts[obj == 0], np.broadcast_to(A + n * DX_A, (n + 1, 2)), rtol=0, atol=1e-12)
        np.testing.assert_allclose(pts[obj == 1], np.broadcast_to(B + n * DX_B, (n + 1, 2)), rtol=0, atol=1e-12)
        assert np.all(np.diff(steps[obj == 0]) == 1)


# ------------------------------------------------------------------------------- 3. target + neighbour (fingers)
@pytest.mark.parametrize("method", TRACKERS)
def test_two_finger_contacts_per_step_are_all_tracked(method):
    t = contacts(finger_rows())
    tracks, diag = track_table(t, TrackConfig(method=method, robot=DISC, params=small(method)), seed=0)
    schema.validate_tracks(tracks)
    schema.validate_diagnostics(diag)
    (_, rc), = schema.contacts_by_run(t)
    # one diagnostics row per step, with its number of contacts; one tracked row per contact row
    np.testing.assert_array_equal(column(diag, "n_contacts"), np.where(rc.in_contact, rc.row_count, 0))
    assert column(diag, "n_contacts").max() == 3
    assert tracks.num_rows == n_contact_rows(t) == 12
    assert np.all(np.isfinite(xy(tracks)))
    touching = np.repeat(rc.in_contact, rc.row_count)  # row level
    np.testing.assert_array_equal(column(tracks, "object_id"), rc.object_id[touching])  # each its own contact's
    ess = column(diag, "ess")
    assert np.all(np.isfinite(ess)) and np.all((ess > 0) & (ess <= 1))


def test_stucco_on_two_finger_contacts_is_finite_and_its_bookkeeping_exact(disc):
    (_, rc), = schema.contacts_by_run(contacts(finger_rows(n=8)))
    tracker = SoftTracker(disc, SoftTrackingParams(n_particles=16), rng=np.random.default_rng(1))
    for s in range(rc.n_steps):
        tracker.update(*rc.observation(s))
        assert_weights_sane(tracker)
        m = tracker.n_points_
        colpen, npen = penetration_bruteforce(tracker._P, tracker._C, m, disc.query, TOL)
        np.testing.assert_array_equal(tracker._npen[:, :m], npen)
        np.testing.assert_allclose(tracker._colpen[:, :m], colpen, rtol=0, atol=1e-12)
    assert tracker.n_points_ == rc.n_rows - int(np.sum(~rc.in_contact))


# ------------------------------------------------------------------------------- 4. rows, indices, equivalence
def interleaved_table():
    """Two runs whose rows interleave (allowed), with K = 1, 2 and 3 contacts per step and per-contact object
    ids."""
    a, b = finger_rows("a", n=4), finger_rows("b", n=3)
    rows = []
    while a or b:
        rows += [a.pop(0)] if a else []
        rows += [b.pop(0)] if b else []
    return contacts(rows)


@pytest.mark.parametrize("method", TRACKERS)
def test_contact_index_numbers_the_contacts_of_a_step_and_the_stage_equals_the_tracker(method, disc):
    t = interleaved_table()
    config = TrackConfig(method=method, robot=DISC, params=small(method), every_step=True)
    tracks, _ = track_table(t, config, seed=7)
    schema.validate_tracks(tracks)  # (run, estimate_step, step) -> contact_index 0..K-1 once each
    segs = schema.validate_segments(segments_of(tracks, method, config.params))
    assert segs.num_rows == tracks.num_rows and np.all(column(segs, "segment") >= 0)
    for run, rc in schema.contacts_by_run(t):
        mine = tracks.filter(pc.equal(tracks["run"], run))
        tracker = build_tracker(method, config.params, disc, run_rng(7, run))
        for s in range(rc.n_steps):
            x, dx, p = rc.observation(s)
            tracker.update(x, dx, p)
            est = mine.filter(pc.equal(mine["estimate_step"], int(rc.step[s])))
            if est.num_rows == 0:  # free space before the first contact
                continue
            # the estimate after step s holds every contact observed so far, in order, K rows per step
            seen = rc.in_contact[: s + 1]
            k = rc.row_count[: s + 1][seen]
            np.testing.assert_array_equal(column(est, "step"), np.repeat(rc.step[: s + 1][seen], k))
            np.testing.assert_array_equal(column(est, "contact_index"), np.concatenate([np.arange(n) for n in k]))
            touching = np.repeat(rc.in_contact, rc.row_count)[: rc.row_start[s] + rc.row_count[s]]
            np.testing.assert_array_equal(column(est, "object_id"), rc.object_id[: len(touching)][touching])
            # and it is the tracker's estimate fed the same K-point observations with the run's stream
            np.testing.assert_array_equal(xy(est), tracker.points_)
            np.testing.assert_array_equal(column(est, "tracker_label"), tracker.labels())


def test_stucco_does_not_depend_on_the_order_of_the_contacts_within_a_step(disc):
    """Three objects, each pushed at one spot with its own displacement at every step (three contacts per step):
    every old point moves with the contact whose pre-motion point it sits on (its nearest, at distance 0), whatever
    that contact's index in the step, so permuting the contacts of each step only permutes the new points. The
    connection draws go by point index; a tiny l makes every connection certain (distance 0) or impossible (cm
    apart), and a tolerance above the disc's radius keeps the weights uniform, so the comparison is exact."""
    rng = np.random.default_rng(5)
    spots = RADIUS * np.c_[np.cos([-1.0, 0.0, 1.0]), np.sin([-1.0, 0.0, 1.0])]  # (3, 2): each object's spot
    steps = []
    for i in range(6):
        dx = np.zeros((3, 2)) if i == 0 else rng.uniform(-0.01, 0.01, (3, 2))
        spots = spots + dx
        steps.append((np.array([0.01 * i, 0.0]), dx, spots.copy()))

    def track(perms):
        tracker = SoftTracker(disc, SoftTrackingParams(n_particles=8, length=1e-9, tolerance=0.06),
                              rng=np.random.default_rng(2))
        for (x, dx, p), perm in zip(steps, perms):
            tracker.update(x, dx[perm], p[perm])
            assert np.all(tracker.penetration_() == 0.0)
        return tracker

    perms = [rng.permutation(3) for _ in steps]
    assert sum(not np.array_equal(q, np.arange(3)) for q in perms) >= 3
    base, shuffled = track([np.arange(3)] * len(steps)), track(perms)
    back = np.concatenate([3 * i + np.argsort(q) for i, q in enumerate(perms)])
    np.testing.assert_array_equal(shuffled.particle_points_[:, back], base.particle_points_)
    # and every point of an object is where its last contact is, in every particle: each moved with its own dx
    final = np.broadcast_to(np.tile(spots, (len(steps), 1)), base.particle_points_.shape)
    np.testing.assert_allclose(base.particle_points_, final, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(base.labels(), np.tile([0, 1, 2], len(steps)))


@pytest.mark.parametrize("method", ["birch", "dbscan"])
def test_a_duplicated_contact_is_tracked_like_the_single_one_by_the_clustering_baselines(method):
    """BIRCH and DBSCAN refit on the points and move a cluster by the mean dx of its new points: on one pushed
    object, a step with its contact given twice tracks every point exactly as the step with it once, plus the
    copy (which stays on its original)."""
    config = TrackConfig(method=method, robot=DISC)
    once, _ = track_table(contacts(coincident_rows(k2=1)), config, seed=0)
    twice, _ = track_table(contacts(coincident_rows(k2=2)), config, seed=0)
    assert (once.num_rows, twice.num_rows) == (4, 5)
    np.testing.assert_array_equal(np.delete(xy(twice), 2, axis=0), xy(once))
    np.testing.assert_array_equal(xy(twice)[2], xy(twice)[1])
    np.testing.assert_array_equal(column(twice, "contact_index"), [0, 0, 1, 0, 0])


# ------------------------------------------------------------------------------- 5. the stages end to end
@pytest.fixture(scope="module")
def two_sensor_log(tmp_path_factory):
    """The stored FB log (the Panda gripper pushing the cracker box) with a second sensor 1.5 cm to the side of
    the first on every third in-contact step, which met the contact later (half the displacement)."""
    base = schema.read_contacts(WARM_UP_LOG).drop_columns(["object_id"])
    rows = []
    for r in base.to_pylist():
        rows.append(r)
        if r["in_contact"] and r["step"] % 3 == 1:
            d = np.array([r["dx_m"], r["dy_m"]])
            side = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-9)
            rows.append(dict(r, contact_x_m=r["contact_x_m"] + 0.015 * side[0],
                             contact_y_m=r["contact_y_m"] + 0.015 * side[1], dx_m=d[0] / 2, dy_m=d[1] / 2))
    table = schema.validate_contacts(pa.Table.from_pylist(rows))
    path = tmp_path_factory.mktemp("log") / "log.parquet"
    pq.write_table(table, path)
    (_, rc), = schema.contacts_by_run(table)
    assert rc.row_count.max() == 2 and int(np.sum(rc.row_count == 2)) >= 10
    return path, table


@pytest.mark.parametrize("method", TRACKERS)
def test_track_segment_and_retrieve_files_with_several_contacts_per_step(method, two_sensor_log, tmp_path):
    log_path, log = two_sensor_log
    config = TrackConfig(method=method, params=small(method))  # the Panda gripper the log was recorded with
    tracks, diag = track_file(log_path, tmp_path / "tracks.parquet", config, seed=0)
    assert schema.read_tracks(tmp_path / "tracks.parquet").equals(tracks)
    assert tracks.num_rows == n_contact_rows(log)
    assert int(np.sum(column(diag, "n_contacts"))) == n_contact_rows(log)
    segs = segment_file(tmp_path / "tracks.parquet", tmp_path / "segments.parquet", seed=0)
    assert schema.read_segments(tmp_path / "segments.parquet").equals(segs)
    seg = column(segs, "segment")
    assert segs.num_rows == tracks.num_rows and not segs.column("segment").null_count and np.all(seg >= 0)
    # one row numbered contact_index 1 per two-sensor step
    two = pc.equal(segs["contact_index"], 1)
    assert int(pc.sum(two).as_py()) == int(np.sum(column(log, "in_contact"))) - len(np.unique(
        column(log, "step")[column(log, "in_contact")]))
    # the default pose estimator reads these segments with the log (the target given by its shape)
    retrieval, _ = retrieve_log(segs, log, "FB:cracker_box", RetrieveConfig(method=method))
    row = retrieval.to_pylist()[0]
    assert np.all(np.isfinite([row["x_m"], row["y_m"], row["yaw_rad"]]))
    assert row["n_segments"] == len(np.unique(seg))
    assert row["segment"] in set(seg.tolist())


@pytest.fixture(scope="module")
def stucco_every_step(two_sensor_log):
    _, log = two_sensor_log
    config = TrackConfig(params=dict(n_particles=30), every_step=True)
    tracks, _ = track_table(log, config, seed=0)
    return segments_of(tracks, "stucco", config.params)


@pytest.mark.parametrize("estimator", registry.estimator_names())
def test_every_pose_estimator_reads_several_contacts_per_step(estimator, two_sensor_log, stucco_every_step):
    _, log = two_sensor_log
    segs = stucco_every_step
    retrieval, candidates = retrieve_log(segs, log, "FB:cracker_box", RetrieveConfig(estimator=estimator))
    row = retrieval.to_pylist()[0]
    assert np.all(np.isfinite([row["x_m"], row["y_m"], row["yaw_rad"]]))
    final = segs.filter(pc.equal(segs["estimate_step"], pc.max(segs["estimate_step"])))
    seg, step = column(final, "segment"), column(final, "step")
    assert row["n_segments"] == len(np.unique(seg)) and row["segment"] in set(seg.tolist())
    chosen = seg == row["segment"]
    rows, steps = int(chosen.sum()), len(np.unique(step[chosen]))
    assert steps < rows  # the chosen segment does hold steps with two contacts
    assert 0 < row["n_points"] <= rows
    if estimator in ("plausible", "paper"):  # they fit every tracked point of the segment, both sensors' ones
        assert row["n_points"] == rows
    if estimator == "pushtrack":  # one contact per action, those the filter kept
        assert row["n_points"] <= steps
    assert candidates.num_rows > 0


# ------------------------------------------------------------------------------- 6. determinism
@pytest.mark.parametrize("method", TRACKERS)
def test_the_same_seed_gives_the_same_tracks_of_a_multi_contact_table(method):
    t = interleaved_table()
    config = TrackConfig(method=method, robot=DISC, params=small(method), every_step=True)
    first, diag1 = track_table(t, config, seed=11)
    second, diag2 = track_table(t, config, seed=11)
    assert first.equals(second)
    assert diag1.drop_columns(["update_ms"]).equals(diag2.drop_columns(["update_ms"]))


def test_the_disc_fixture_is_the_robot_the_stage_loads(disc):
    # the direct-tracker comparisons above build trackers on the fixture and the stage loads DISC itself
    assert disc.digest == load_robot(DISC).digest
