"""The pushtrack estimator's compiled loops (pipeline/estimators/pushtrack/kernel.py) give the numpy forms' bits.

The free-space likelihood of the filter against the numpy form it replaced (:func:`free_loglik_numpy`), and the
batched refinement (:func:`~pipeline.estimators.plausible.cost.refine` with (B, P, 2) points, each particle with its own
contacts) against the one-particle refinement it replaced. Equality is exact
(``assert_array_equal``): a last-bit difference in a weight or a cost could flip a resampling draw or a near-tie
and so change a reported pose.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.estimators.plausible import cost as plausible
from pipeline.estimators.plausible import kernel as plausible_kernel
from pipeline.estimators.plausible.cost import compiled_terms, refine
from pipeline.estimators.plausible.params import PlausibleParams
from pipeline.estimators.pushtrack import filter as pushmodel
from pipeline.estimators.pushtrack import kernel as pushtrack_kernel
from pipeline.estimators.pushtrack.filter import PushTrackParams, free_loglik
from pipeline.geometry import Primitive, primitive_sdf, rotate
from pipeline.portable import logsumexp
from pipeline.track import weights

BOX = Primitive(kind="box", half=(0.05, 0.08), centre=np.array([0.004, -0.002]), yaw=0.3, name="box")
CAN = Primitive(kind="cylinder", half=(0.034,), centre=np.array([0.011, 0.0]), yaw=0.0, name="can")
P = PushTrackParams()
LM = PlausibleParams(contact_sigma=P.contact_sigma, free_tolerance=P.free_tolerance)


def free_loglik_numpy(prim, pose, free, params):
    """The numpy form the compiled free-space likelihood replaced, kept as its reference: (N, F) temporaries."""
    centre = prim.centre_world(pose)
    q = rotate(free[None, :, :] - centre[:, None, :], (pose[:, 2] + prim.yaw)[:, None], inverse=True)
    sd, _ = primitive_sdf(prim, q)
    r = np.minimum(sd + params.free_tolerance, 0.0) / params.free_sigma
    return -0.5 * np.sum(r * r, axis=1)


def _poses(rng, n):
    return np.column_stack([rng.normal(0.0, 0.03, (n, 2)), rng.uniform(-4.0, 4.0, n)])


def _same_free(prim, pose, free):
    got = free_loglik(prim, pose, free, P)
    np.testing.assert_array_equal(got, free_loglik_numpy(prim, pose, free, P))
    return got


@pytest.mark.parametrize("prim", [BOX, CAN], ids=["box", "can"])
# point counts across numpy's pairwise-summation branches: < 8, one block of 8 partial sums, > 128 (halved)
@pytest.mark.parametrize("n_free", [1, 7, 8, 9, 129, 1000])
def test_free_loglik_is_the_numpy_form_bit_for_bit(prim, n_free):
    rng = np.random.default_rng(n_free)
    got = _same_free(prim, _poses(rng, 61), rng.normal(0.0, 0.06, (n_free, 2)))
    assert np.all(got <= 0.0) and np.any(got < 0.0)  # some points fall inside some particles


def test_free_loglik_one_particle_one_point_coincident_points():
    """One particle, one point, every point at the same place (the target's centre: a can's r = 0 branch, a box's
    medial axis), points on the circumscribed circle where the compiled loop starts skipping, and points that
    all lie outside every particle (exactly 0)."""
    rng = np.random.default_rng(4)
    for prim in (BOX, CAN):
        one = np.array([[0.1, -0.05, 0.7]])
        centre = prim.centre_world(one)
        assert _same_free(prim, one, centre)[0] < 0.0  # the centre is deep inside
        _same_free(prim, one, np.repeat(centre, 9, axis=0))
        _same_free(prim, _poses(rng, 5), np.repeat(centre, 130, axis=0))
        ring = np.hypot(*prim.half) if len(prim.half) > 1 else prim.half[0]
        ang = np.linspace(0.0, 2.0 * np.pi, 40, endpoint=False)
        edge = centre + ring * np.column_stack([np.cos(ang), np.sin(ang)]) * (1.0 + np.array([[-1e-9], [1e-9]]))[
            np.arange(40) % 2]
        _same_free(prim, np.repeat(one, 3, axis=0), edge)
        far = np.array([[5.0, 5.0], [-5.0, 0.0]])
        np.testing.assert_array_equal(free_loglik(prim, _poses(rng, 4), far, P), np.zeros(4))


def test_free_loglik_non_finite_poses_and_points_give_numpys_nans():
    """A diverged particle (NaN or infinite coordinate) or a NaN point: the compiled loop skips far points, but
    not infinitely far ones, whose NaNs numpy keeps (the filter then drops the particle's weight)."""
    pose = np.array([[np.nan, 0.0, 0.0], [0.0, np.nan, 0.0], [0.0, 0.0, np.nan], [np.inf, 0.0, 0.0],
                     [0.0, -np.inf, 1.0], [0.0, 0.0, 0.0]])
    free = np.array([[0.0, 0.0], [0.01, 0.02], [1.0, 1.0], [np.nan, 0.0]])
    with np.errstate(invalid="ignore"):
        for prim in (BOX, CAN):
            for pts in (free[:3], free):
                got = free_loglik(prim, pose, pts, P)
                np.testing.assert_array_equal(got, free_loglik_numpy(prim, pose, pts, P))
                assert np.isnan(got[:3]).all() and got[-1] < 0.0 if len(pts) == 3 else np.isnan(got).all()


def _contacts(rng, n, t):
    pts = rng.normal(0.0, 0.05, (n, t, 2))
    sigma = 0.004 * 1.5 ** rng.integers(0, 4, t)
    return pts, sigma


@pytest.mark.parametrize("prim", [BOX, CAN], ids=["box", "can"])
@pytest.mark.parametrize("sizes", [(1, 1, 0, 0), (1, 9, 8, 3), (32, 7, 129, 0), (5, 130, 0, 17)])
def test_each_particles_terms_and_refinement_are_its_own_one_particle_fit(prim, sizes):
    """Row b of the batched terms and refinement has the bits of the one-particle call on its own contacts
    (one particle, one contact, and sizes across the pairwise-summation branches)."""
    n, t, n_free, n_others = sizes
    rng = np.random.default_rng(sum(sizes))
    pose = _poses(rng, n)
    pts, sigma = _contacts(rng, n, t)
    free, others = rng.normal(0.0, 0.08, (n_free, 2)), rng.normal(0.0, 0.08, (n_others, 2))
    terms, H, g = compiled_terms(prim, pose, pts, sigma, free, others, LM, jacobian=True)
    refined, rterms = refine(prim, pose, pts, sigma, free, others, LM)
    for b in range(n):
        t1, H1, g1 = compiled_terms(prim, pose[b:b + 1], pts[b], sigma, free, others, LM, jacobian=True)
        for name in ("contact", "free", "others"):
            np.testing.assert_array_equal(getattr(terms, name)[b:b + 1], getattr(t1, name), err_msg=name)
        np.testing.assert_array_equal(H[b:b + 1], H1)
        np.testing.assert_array_equal(g[b:b + 1], g1)
        r1, rt1 = refine(prim, pose[b:b + 1], pts[b], sigma, free, others, LM)
        np.testing.assert_array_equal(refined[b:b + 1], r1)
        np.testing.assert_array_equal(rterms.total[b:b + 1], rt1.total)


def test_coincident_contacts_and_a_contact_at_the_centre():
    """Every carried contact at one place, and at the primitive's centre (the sdf's subgradient cases)."""
    pose = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, np.pi / 2], [0.0, 0.0, -np.pi]])
    for prim in (BOX, CAN):
        pts = np.zeros((3, 6, 2))
        pts[1] = [0.07, 0.01]
        sigma = np.full(6, 0.004)
        refined, terms = refine(prim, pose, pts, sigma, np.zeros((0, 2)), np.zeros((0, 2)), LM)
        for b in range(3):
            r1, t1 = refine(prim, pose[b:b + 1], pts[b], sigma, np.zeros((0, 2)), np.zeros((0, 2)), LM)
            np.testing.assert_array_equal(refined[b:b + 1], r1)
            np.testing.assert_array_equal(terms.total[b:b + 1], t1.total)
        assert np.all(np.isfinite(refined))


def test_plain_python_kernels_give_the_compiled_bits(monkeypatch):
    """What NUMBA_DISABLE_JIT=1 runs (each kernel's py_func) gives the compiled results."""
    rng = np.random.default_rng(11)
    pose = _poses(rng, 4)
    free = rng.normal(0.0, 0.06, (20, 2))
    pts, sigma = _contacts(rng, 4, 5)
    compiled = [(free_loglik(prim, pose, free, P), compiled_terms(prim, pose, pts, sigma, free, free, LM, True))
                for prim in (BOX, CAN)]
    monkeypatch.setattr(pushtrack_kernel, "pairwise_sum", pushtrack_kernel.pairwise_sum.py_func)
    monkeypatch.setattr(pushtrack_kernel, "local_sdf", pushtrack_kernel.local_sdf.py_func)
    monkeypatch.setattr(plausible_kernel, "local_sdf", plausible_kernel.local_sdf.py_func)
    monkeypatch.setattr(plausible_kernel, "pairwise_sum", plausible_kernel.pairwise_sum.py_func)
    monkeypatch.setattr(pushmodel, "free_depth_sums", pushtrack_kernel.free_depth_sums.py_func)
    monkeypatch.setattr(plausible, "piece_terms_each", plausible_kernel.piece_terms_each.py_func)
    monkeypatch.setattr(plausible_kernel, "piece_terms", plausible_kernel.piece_terms.py_func)
    for prim, (ll, (t, H, g)) in zip((BOX, CAN), compiled):
        np.testing.assert_array_equal(free_loglik(prim, pose, free, P), ll)
        t2, H2, g2 = compiled_terms(prim, pose, pts, sigma, free, free, LM, True)
        np.testing.assert_array_equal(t2.total, t.total)
        np.testing.assert_array_equal(H2, H)
        np.testing.assert_array_equal(g2, g)


def _normalised_numpy(log_w):
    """The filter's numpy normalisation that :func:`pushtrack_kernel.reweigh` replaced, kept as its reference."""
    log_w = np.where(np.isnan(log_w), -np.inf, log_w)
    if not np.any(np.isfinite(log_w)):
        return np.full(len(log_w), -np.log(len(log_w))), -np.inf
    total = logsumexp(log_w)
    return log_w - total, float(total)


@pytest.mark.parametrize("n", [1, 7, 8, 9, 129, 512, 2048])
def test_reweigh_is_the_numpy_normalisation_bit_for_bit(n):
    """Weights across numpy's pairwise-summation branches, with -inf, NaN, underflowing and +-0 entries."""
    rng = np.random.default_rng(n)
    log_w = rng.normal(-math.log(n), 3.0, n)
    ll = -0.5 * rng.gamma(0.5, 40.0, n)
    ll[rng.uniform(size=n) < 0.1] = 0.0
    ll[rng.uniform(size=n) < 0.05] = -np.inf
    ll[rng.uniform(size=n) < 0.02] = np.nan
    ll[rng.uniform(size=n) < 0.05] = -1e308
    for a, b in ((log_w, ll), (log_w, np.zeros(n)), (np.full(n, -0.0), -0.0 * ll), (log_w, np.full(n, -np.inf)),
                 (log_w, np.full(n, -1e4))):
        out = np.empty(n)
        total, before = pushtrack_kernel.reweigh(a, b, out)
        want, want_total = _normalised_numpy(a + b)
        np.testing.assert_array_equal(out, want)
        assert total == want_total or (np.isnan(total) and np.isnan(want_total))
        assert before == float(logsumexp(a))
        assert weights.logsumexp(2.0 * a) == float(logsumexp(2.0 * a))  # the effective sample size's
        assert not np.any(np.isnan(out)) and np.any(np.isfinite(out))  # all inconsistent: uniform, finite


def test_near_points_is_the_numpy_selection():
    rng = np.random.default_rng(3)
    poses = rng.normal(0.0, 0.2, (40, 2))
    pts = poses[:, None, :] + rng.normal(0.0, 0.05, (40, 17, 2))
    pts[3, 4] = [np.nan, 0.0]
    centre = np.array([0.05, -0.02])
    for reach, radius in ((0.25, 0.12), (0.0, 0.1), (1.0, 0.0), (np.inf, np.inf)):
        near = np.hypot(*(poses - centre).T) <= reach
        want = pts[near].reshape(-1, 2)
        want = want[np.hypot(*(want - centre).T) <= radius]
        got = pushtrack_kernel.near_points(poses, pts, centre[0], centre[1], reach, radius)
        np.testing.assert_array_equal(got, want)


def test_plain_python_weights_and_free_points_give_the_compiled_bits(monkeypatch):
    """What NUMBA_DISABLE_JIT=1 runs for the filter's weights update and the free-space cut."""
    rng = np.random.default_rng(5)
    log_w, ll = rng.normal(-5.0, 2.0, 300), -rng.gamma(0.5, 30.0, 300)
    poses = rng.normal(0.0, 0.2, (30, 2))
    pts = poses[:, None, :] + rng.normal(0.0, 0.05, (30, 9, 2))
    out = np.empty(300)
    got = pushtrack_kernel.reweigh(log_w, ll, out)
    near = pushtrack_kernel.near_points(poses, pts, 0.01, 0.0, 0.2, 0.1)
    monkeypatch.setattr(pushtrack_kernel, "logsumexp", weights.logsumexp.py_func)
    monkeypatch.setattr(weights, "pairwise_sum", weights.pairwise_sum.py_func)
    out2 = np.empty(300)
    assert pushtrack_kernel.reweigh.py_func(log_w, ll, out2) == got
    np.testing.assert_array_equal(out2, out)
    np.testing.assert_array_equal(pushtrack_kernel.near_points.py_func(poses, pts, 0.01, 0.0, 0.2, 0.1), near)
