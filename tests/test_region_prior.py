"""The no-segment prior and the scene's target region (docs/scene_generator.md, "The target region and the
probing policy"): with nothing fitted to the target, the policy's hypotheses lie in the region the scene declares
and clear of the space the gripper swept; a scene without a region keeps the prior around the visited positions."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pipeline.estimators.plausible.fit import PlausibleParams
from pipeline.geometry import Primitive
from pipeline.probe.belief import NO_TARGET, pose_set, prior_set
from pipeline.robot import load_robot
from pipeline.scenes import WORKSPACE_M, declared_region, load_scene

BOX = Primitive(kind="box", half=(0.03, 0.08), centre=np.zeros(2), yaw=0.0)
REGION = ((0.2, -0.1), (0.6, 0.3))


@pytest.fixture(scope="module")
def sdf():
    return load_robot("panda")


def _sweep():
    """A poke along y = 0.1 from x = -0.1 to 0.25 (base), and back."""
    xs = np.r_[np.arange(-0.1, 0.25, 0.03), np.arange(0.25, -0.1, -0.03)]
    return np.column_stack([xs, np.full(len(xs), 0.1)])


def test_the_prior_lies_in_the_region_and_off_the_swept_space(sdf):
    ee = _sweep()
    s = prior_set(BOX, ee, np.arange(len(ee) - 1), sdf, PlausibleParams(), np.random.default_rng(0), region=REGION)
    assert s.segment == -1 and s.notes == ["no_segment"] and len(s.poses) == 48
    (x0, y0), (x1, y1) = REGION
    assert (s.poses[:, 0] >= x0).all() and (s.poses[:, 0] <= x1).all()
    assert (s.poses[:, 1] >= y0).all() and (s.poses[:, 1] <= y1).all()
    # The poke's fingertips reached x = 0.36 along y = 0.1 (the hand 0.2 m wide): no box stands there.
    centres = BOX.centre_world(s.poses)
    swept = (centres[:, 0] < 0.3) & (np.abs(centres[:, 1] - 0.1) < 0.05)
    assert not swept.any()
    # The same through pose_set, the policy's entry point, and deterministic for the stream.
    again = pose_set(NO_TARGET, BOX, ee, np.arange(len(ee) - 1), sdf, np.random.default_rng(0), np.zeros((0, 2)),
                     np.zeros(0), np.zeros((0, 2)), plausible=PlausibleParams(), region=REGION)
    assert np.array_equal(again.poses, s.poses)


def test_the_prior_keeps_clear_of_other_objects_contacts(sdf):
    # A row of contacts on another object across the region's middle: no hypothesis of the box holds one of them.
    from pipeline.estimators.estimate import Segment
    from pipeline.probe.attribution import no_target

    ee = _sweep()
    wall_of_cans = np.column_stack([np.linspace(0.2, 0.6, 41), np.full(41, 0.2)])
    none = no_target([Segment(3, wall_of_cans[:20], np.arange(20)), Segment(5, wall_of_cans[20:], np.arange(21))])
    assert none.segment == -1 and np.array_equal(none.others, wall_of_cans)
    s = pose_set(none, BOX, ee, np.arange(len(ee) - 1), sdf, np.random.default_rng(0), np.zeros((0, 2)),
                 np.zeros(0), np.zeros((0, 2)), plausible=PlausibleParams(), region=REGION)
    assert s.notes == ["no_segment"] and len(s.poses) == 48
    held = [BOX.signed_distance(wall_of_cans, pose).min() for pose in s.poses]
    assert min(held) > -PlausibleParams().free_tolerance
    free = prior_set(BOX, ee, np.arange(len(ee) - 1), sdf, PlausibleParams(), np.random.default_rng(0), region=REGION)
    assert min(BOX.signed_distance(wall_of_cans, pose).min() for pose in free.poses) < -0.01  # without them: some do
    assert no_target([]).others.shape == (0, 2)
    assert no_target([Segment(3, wall_of_cans, np.arange(41))], clear_of_others=False).others.shape == (0, 2)


def test_a_run_probed_before_the_rule_is_retrieved_without_it():
    from pipeline.probe.params import ProbeParams
    from pipeline.probe.retrieval import _recorded_params

    old = {k: v for k, v in ProbeParams().to_dict().items() if k != "prior_clear_of_others"}
    assert _recorded_params(old).prior_clear_of_others is False
    assert _recorded_params(ProbeParams().to_dict()).prior_clear_of_others is True
    with pytest.raises(ValueError, match="prior_clear_of_others"):
        ProbeParams(prior_clear_of_others=1)


def test_without_a_region_the_prior_is_around_the_visited_positions(sdf):
    ee = _sweep()
    s = prior_set(BOX, ee, np.arange(len(ee) - 1), sdf, PlausibleParams(), np.random.default_rng(0))
    assert np.all(np.abs(s.poses[:, :2] - ee.mean(axis=0)) <= 0.25 + 1e-9)


def test_the_declared_region_is_the_scene_files_or_none():
    assert declared_region(None) is None
    assert declared_region(load_scene("FB")) == ((0.09, -0.3), (0.48, 0.35))  # the task's file declares one
    assert declared_region(replace(load_scene("FB"), target_region=WORKSPACE_M)) is None

    class Scene:
        target_region = REGION

    assert declared_region(Scene()) == REGION
