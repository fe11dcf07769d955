"""Tests for pipeline.robot: grid SDF queries, the disc and Panda grids, their cache, surface points, parsing."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline import robot
from pipeline.robot import GridSDF, disc_sdf, load_robot, panda_sdf, surface_points

ANCHOR = Path(__file__).resolve().parents[1] / "data" / "anchors" / "stream_T50.npz"

# The authors' pybullet-built grid, measured (docs/simulation.md, "The gripper's signed distance grid").
SPEC_MIN = np.array([-0.02592, -0.10399])
SPEC_MAX = np.array([0.11225, 0.10043])


@pytest.fixture(scope="module")
def panda_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("stucco_cache")


@pytest.fixture(scope="module")
def panda(panda_cache) -> GridSDF:
    return panda_sdf(cache_dir=panda_cache)


@pytest.fixture(scope="module")
def panda_surface(panda):
    return surface_points(panda)


def _grid_3d() -> GridSDF:
    rng = np.random.default_rng(7)
    return GridSDF(rng.normal(size=(4, 5, 6)), np.array([-0.1, 0.2, 0.0]), 0.01, name="random3d")


# ------------------------------------------------------------------------------------------------ GridSDF basics


@pytest.mark.parametrize("lead", [(), (5,), (3, 4), (0,)])
def test_query_accepts_batch_shapes(lead):
    grid = disc_sdf(0.05)
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.08, 0.08, size=lead + (2,))
    out = grid.query(q)
    assert out.shape == lead
    assert out.dtype == np.float64


def test_query_single_point_known_values():
    grid = disc_sdf(0.05)
    assert grid.query(np.zeros(2)) == pytest.approx(-0.05)
    assert grid.query([0.03, 0.04]) == pytest.approx(0.0, abs=1e-12)
    # Rounds to the nearest cell: 0.0304 -> cell of 0.030.
    assert grid.query([0.0304, 0.0396]) == pytest.approx(0.0, abs=1e-12)


def test_query_outside_grid_returns_outside_value():
    grid = disc_sdf(0.05)
    q = np.array([[0.2, 0.0], [0.0, -0.2], [np.nan, 0.0], [0.0606, 0.0], [-0.0606, 0.0], [np.inf, 0.0]])
    np.testing.assert_array_equal(grid.query(q), grid.outside_value)
    # Inclusive bounds: the last cell centre and anything rounding to it are inside.
    assert grid.query([0.06, 0.0]) == pytest.approx(0.01)
    assert grid.query([0.0604, 0.0]) == pytest.approx(0.01)


def test_query_rejects_wrong_point_dimension():
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        disc_sdf(0.05).query(np.zeros((4, 3)))


def test_query_works_in_3d():
    grid = _grid_3d()
    idx = np.array([[0, 0, 0], [3, 4, 5], [1, 2, 3]])
    q = grid.origin + grid.resolution * idx + 0.004  # within half a cell
    np.testing.assert_array_equal(grid.query(q), grid.values[idx[:, 0], idx[:, 1], idx[:, 2]])
    assert grid.query(grid.origin - 0.006) == grid.outside_value


def test_pxpen_is_query_of_translated_points():
    grid = disc_sdf(0.05)
    rng = np.random.default_rng(1)
    configs = rng.uniform(-0.1, 0.1, size=(7, 2))
    points = rng.uniform(-0.1, 0.1, size=(9, 2))
    m = grid.pxpen(configs[:, None, :], points[None, :, :])
    assert m.shape == (7, 9)
    np.testing.assert_array_equal(m, grid.query(points[None, :, :] - configs[:, None, :]))
    # Translation invariance: moving robot and points together changes nothing.
    shift = np.array([0.3, -0.2])
    np.testing.assert_allclose(grid.pxpen(configs[:, None] + shift, points[None] + shift), m, atol=1e-12)


def test_values_are_read_only_and_digest_tracks_content():
    grid = disc_sdf(0.05)
    with pytest.raises(ValueError):
        grid.values[0, 0] = 0.0
    assert grid.digest == disc_sdf(0.05).digest
    assert len(grid.digest) == 16
    assert grid.digest != disc_sdf(0.04).digest
    shifted = GridSDF(grid.values, grid.origin + 0.001, grid.resolution)
    assert shifted.digest != grid.digest


def test_origin_dimension_mismatch_raises():
    with pytest.raises(ValueError, match="origin shape"):
        GridSDF(np.zeros((3, 3)), np.zeros(3), 0.01)


def test_interior_bounds_of_disc():
    grid = disc_sdf(0.05)
    # hypot(0.05, 0) - 0.05 rounds to -7e-18, so threshold a hair below 0 to count only cells truly inside:
    # on a 1 mm lattice through 0 those have |x| <= 0.049.
    lo, hi = grid.interior_bounds(-1e-12)
    np.testing.assert_allclose(lo, [-0.049, -0.049], atol=1e-9)
    np.testing.assert_allclose(hi, [0.049, 0.049], atol=1e-9)
    lo, hi = grid.interior_bounds(-0.04)
    np.testing.assert_allclose(hi, [0.009, 0.009], atol=1e-9)


def test_interior_bounds_empty_box_when_nothing_qualifies():
    lo, hi = disc_sdf(0.05).interior_bounds(-1.0)
    assert np.all(lo > hi)


def test_interior_bounds_contains_every_penetrating_query(panda):
    lo, hi = panda.interior_bounds(0.0)
    rng = np.random.default_rng(2)
    q = rng.uniform(panda.origin - 0.01, panda.upper + 0.01, size=(20000, 2))
    neg = q[panda.query(q) < 0.0]
    half = panda.resolution / 2 + 1e-12
    assert np.all(neg >= lo - half) and np.all(neg <= hi + half)


@pytest.mark.parametrize("make", [lambda: disc_sdf(0.05), _grid_3d])
def test_kernel_arrays_flat_lookup_equals_query(make):
    grid = make()
    flat, shape, strides, origin, res = grid.kernel_arrays()
    assert flat.flags.c_contiguous and flat.dtype == np.float64
    assert shape.dtype == np.int64 and strides.dtype == np.int64
    rng = np.random.default_rng(3)
    lo, hi = grid.origin - 2 * res, grid.upper + 2 * res
    q = rng.uniform(lo, hi, size=(2000, grid.ndim))
    idx = np.rint((q - origin) / res).astype(np.int64)
    inside = np.all((idx >= 0) & (idx <= shape - 1), axis=1)
    expect = np.where(inside, flat[np.clip((idx * strides).sum(axis=1), 0, flat.size - 1)], grid.outside_value)
    np.testing.assert_array_equal(grid.query(q), expect)
    assert inside.any() and not inside.all()


# ------------------------------------------------------------------------------------------------------- disc


def test_disc_grid_equals_anchor_grid():
    z = np.load(ANCHOR)
    grid = disc_sdf(float(z["robot_radius"]), resolution=float(z["sdf_resolution"]))
    ny = int(z["sdf_y_len"])
    ref = z["sdf_cache"].reshape(-1, ny)  # flat index x_id * ny + y_id
    assert grid.shape == ref.shape
    np.testing.assert_allclose(grid.origin, [z["sdf_min_x"], z["sdf_min_y"]], atol=1e-12)
    np.testing.assert_allclose(grid.upper, [z["sdf_max_x"], z["sdf_max_y"]], atol=1e-9)
    np.testing.assert_allclose(grid.values, ref, rtol=0, atol=4e-9)  # float32 rounding of values < 0.05


def test_disc_values_match_analytic_distance():
    r = 0.03
    grid = disc_sdf(r, resolution=0.002, margin=0.02)
    rng = np.random.default_rng(4)
    q = rng.uniform(-0.05, 0.05, size=(500, 2))
    # Nearest-cell lookup is off by at most half a cell diagonal.
    np.testing.assert_allclose(grid.query(q), np.hypot(q[:, 0], q[:, 1]) - r, atol=0.002 * np.sqrt(2) / 2 + 1e-12)
    assert grid.name == "disc:0.03"


def test_disc_rejects_non_positive_radius():
    with pytest.raises(ValueError, match="positive"):
        disc_sdf(0.0)


# ------------------------------------------------------------------------------------------------------ panda


def test_panda_grid_matches_spec(panda):
    assert abs(panda.shape[0] - 140) <= 1 and abs(panda.shape[1] - 206) <= 1
    np.testing.assert_allclose(panda.origin, SPEC_MIN, atol=1e-3)
    # The last cell centre lies within one cell beyond the mesh bounds (arange(min, max + res, res)).
    assert np.all(panda.upper >= SPEC_MAX - 1e-3) and np.all(panda.upper <= SPEC_MAX + panda.resolution + 1e-3)
    assert -0.033 <= panda.values.min() <= -0.028
    assert 0.6 <= np.mean(panda.values < 0) <= 0.72
    assert panda.name == "panda"


def test_panda_known_points(panda):
    assert panda.query([0.02, 0.0]) < -0.02  # well inside the palm
    assert panda.query([0.02, 0.08]) < 0.0  # palm extends to |y| ~ 0.1
    assert panda.query([0.09, 0.0]) < 0.0  # between the closed fingers (they touch at y ~ 0)
    assert panda.query([0.1622, 0.0]) == panda.outside_value  # 5 cm beyond the fingertips: off the grid
    assert panda.pxpen([0.0, 0.0], [0.1622, 0.0]) > 0.0
    assert panda.query([0.09, 0.06]) > 0.0  # beside the fingers, in front of the palm


def test_panda_margin_shifts_values_by_the_margin(panda):
    bare = robot.panda_mesh.build_panda_grid(collision_margin=0.0)
    np.testing.assert_allclose(bare.values - panda.values, robot.PYBULLET_COLLISION_MARGIN, atol=1e-12)
    assert bare.values.min() == pytest.approx(-0.0295, abs=1e-3)


def test_panda_cache_second_call_loads_file(panda, panda_cache, monkeypatch):
    files = list(panda_cache.glob("panda_sdf_*.npz"))
    assert len(files) == 1
    assert not list(panda_cache.glob("*.tmp"))

    def no_build(*args, **kwargs):
        raise AssertionError("should have loaded from the cache")

    monkeypatch.setattr(robot.panda_cache, "build_panda_grid", no_build)
    again = panda_sdf(cache_dir=panda_cache)
    np.testing.assert_array_equal(again.values, panda.values)
    np.testing.assert_array_equal(again.origin, panda.origin)
    assert again.resolution == panda.resolution and again.digest == panda.digest


def test_panda_cache_key_depends_on_inputs(panda_cache):
    base = robot.panda_cache._panda_cache_path(0.001, panda_cache, robot.PYBULLET_COLLISION_MARGIN)
    assert base == robot.panda_cache._panda_cache_path(0.001, panda_cache, robot.PYBULLET_COLLISION_MARGIN)
    assert base != robot.panda_cache._panda_cache_path(0.002, panda_cache, robot.PYBULLET_COLLISION_MARGIN)
    assert base != robot.panda_cache._panda_cache_path(0.001, panda_cache, 0.0)


def test_panda_cache_dir_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("STUCCO_CACHE_DIR", str(tmp_path))
    coarse = panda_sdf(resolution=0.004)
    assert len(list(tmp_path.glob("panda_sdf_*.npz"))) == 1
    assert abs(coarse.shape[0] - 36) <= 1 and abs(coarse.shape[1] - 53) <= 1


def test_panda_corrupt_cache_is_rebuilt(tmp_path):
    path = robot.panda_cache._panda_cache_path(0.004, tmp_path, robot.PYBULLET_COLLISION_MARGIN)
    path.write_bytes(b"not an npz")
    grid = panda_sdf(resolution=0.004, cache_dir=tmp_path)
    assert grid.values.min() < -0.02
    assert panda_sdf(resolution=0.004, cache_dir=tmp_path).digest == grid.digest


# --------------------------------------------------------------------------------------------- surface points


def test_surface_points_count_and_extent(panda_surface):
    points, normals = panda_surface
    assert points.shape[1] == 2 and normals.shape == points.shape
    assert 55 <= len(points) <= 90  # spec: 72 with pybullet's projection
    # Spec: x in [-0.027, 0.113], y in [-0.105, 0.101].
    np.testing.assert_allclose(points.min(axis=0), [-0.027, -0.105], atol=2e-3)
    np.testing.assert_allclose(points.max(axis=0), [0.113, 0.101], atol=2e-3)


def test_surface_points_lie_on_zero_level(panda_surface, panda):
    points, _ = panda_surface
    vals = panda.query(points)
    # The 1 mm collision margin pushes a few points up to 1 mm past the mesh-bounded grid.
    on_grid = vals != panda.outside_value
    assert on_grid.mean() > 0.8
    assert np.all(np.abs(vals[on_grid]) < 1.5e-3)
    assert np.all(points >= panda.origin - 1.5e-3) and np.all(points <= panda.upper + 1.5e-3)


def test_surface_points_on_bare_hull_grid_all_on_zero_level():
    bare = robot.panda_mesh.build_panda_grid(collision_margin=0.0)
    points, _ = surface_points(bare)
    assert np.all(np.abs(bare.query(points)) < 1.5e-3)


def test_surface_normals_unit_and_outward(panda_surface, panda):
    points, normals = panda_surface
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    interp = robot.surface._bilinear(panda)
    assert np.all(interp(points + 0.003 * normals) > interp(points - 0.003 * normals))
    assert np.all(interp(points + 0.003 * normals) > 0.0)


def test_surface_points_are_separated(panda_surface):
    points, _ = panda_surface
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() >= 0.005


def test_surface_points_on_disc_lie_on_circle():
    points, normals = surface_points(disc_sdf(0.05), radius=0.115)
    r = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(r, 0.05, atol=1e-3)
    np.testing.assert_allclose(normals, points / r[:, None], atol=0.05)
    # 100 queries 3.2 mm apart once projected onto the 5 cm circle: every other one is kept (6.3 mm apart), and
    # the last ones come back within 5 mm of the first.
    assert 45 <= len(points) <= 50


# ---------------------------------------------------------------------------------------------------- parsing


def test_load_robot_disc():
    grid = load_robot("disc:0.05")
    assert grid.digest == disc_sdf(0.05).digest


def test_load_robot_panda(panda_cache, monkeypatch, panda):
    monkeypatch.setenv("STUCCO_CACHE_DIR", str(panda_cache))
    assert load_robot("panda").digest == panda.digest


@pytest.mark.parametrize(
    "spec, match",
    [
        ("kuka", r"unknown robot 'kuka'; expected 'panda' or 'disc:RADIUS'"),
        ("", r"unknown robot ''"),
        ("disc", r"unknown robot 'disc'"),
        ("disc:abc", r"radius 'abc' is not a number; expected 'panda' or 'disc:RADIUS'"),
        ("disc:", r"radius '' is not a number"),
        ("disc:0", r"radius must be positive and finite; expected 'panda'"),
        ("disc:-0.05", r"radius must be positive and finite"),
        ("disc:nan", r"radius must be positive and finite"),
        ("disc:inf", r"radius must be positive and finite"),
    ],
)
def test_load_robot_rejects_bad_specs(spec, match):
    with pytest.raises(ValueError, match=match):
        load_robot(spec)
