"""Pose estimators: segments of tracked contact points and the gripper's trail -> the target's planar pose.

One subpackage per estimator behind ``stucco retrieve --estimator`` (docs/estimators.md), and what they share:

* :mod:`~pipeline.estimators.paper`: the paper's ICP procedure (§V-C), at the end of a run or online at every
  in-contact step, as the authors ran it;
* :mod:`~pipeline.estimators.plausible`: SE(2) hypotheses fitted to the target's shape, its contacts and the
  gripper's free space (the default);
* :mod:`~pipeline.estimators.pushtrack`: the target's pose tracked through its pushes by particle filters, with
  the pushing models (quasi-static limit surface, the gripper's slice as the pusher);
* :mod:`~pipeline.estimators.estimate`: the estimators behind ``--estimator``, one call per run;
* :mod:`~pipeline.estimators.params`: the paper's estimation parameters, which every estimator shares;
* :mod:`~pipeline.estimators.target_model`: the target's primitive, model points and normals, pose error;
* :mod:`~pipeline.estimators.segment_choice`: which segment is the target's (the one that resisted the pushes);
* :mod:`~pipeline.estimators.run_info`: collected run files as the estimators and the scorer read them.

The package imports nothing itself, so importing one estimator does not load the others.
"""
