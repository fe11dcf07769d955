"""The grasp's success rule in geometry (pipeline.grasp_rule): the script's yaw, and the share of a set that the
script aimed at each hypothesis holds (the rule itself against the simulator: tests/test_probe.py)."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.estimators.target_model import target_primitive
from pipeline.grasp import grasp_yaw, plan_for, pregrasp
from pipeline.grasp_rule import own_grasp_shares
from pipeline.scenes import load_scene


@pytest.mark.parametrize("scene", ["FB", "BC", "IB", "TC"])
def test_grasp_yaw_is_the_scripts_yaw(scene):
    sc = load_scene(scene)
    _, prim = target_primitive(sc)
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.1, 0.4, 50), rng.uniform(-0.1, 0.1, 50), rng.uniform(-4, 4, 50)])
    expected = [pregrasp(plan_for(sc), prim, p)[0] for p in poses]
    assert np.allclose(grasp_yaw(plan_for(sc), prim, poses), expected, atol=1e-12)


def test_shares_count_the_weight_each_grasp_holds():
    # three hypotheses within 0.02 rad of each other and one a quarter turn off: a grasp aimed at any of the three
    # holds the three (and not the fourth), the one aimed at the fourth only itself
    sc = load_scene("IB")
    _, prim = target_primitive(sc)
    poses = np.array([[0.25, 0.05, 0.30], [0.25, 0.05, 0.31], [0.25, 0.05, 0.29], [0.25, 0.05, 0.30 + np.pi / 2]])
    w = np.array([1.0, 1.0, 1.0, 2.0])
    share, held = own_grasp_shares(sc, prim, poses, w)
    assert held.tolist() == [[True, True, True, False]] * 3 + [[False, False, False, True]]
    assert np.allclose(share, [0.6, 0.6, 0.6, 0.4])
    # weights need not be normalised; one hypothesis holds all of itself
    share1, held1 = own_grasp_shares(sc, prim, poses[:1], np.array([7.0]))
    assert share1.tolist() == [1.0] and held1.tolist() == [[True]]
