"""The pushtrack estimator: the target's pose tracked through its pushes.

* :mod:`.estimator`: the estimator (segment choice, the filters' starts, pooling, the final pose);
* :mod:`.filter`: the particle filter over SE(2) through the pushes;
* :mod:`.params`: its parameters;
* :mod:`.quasistatic`: the quasi-static pushing model with an ellipsoidal limit surface (a point pusher);
* :mod:`.slice_pusher`: the gripper's slice as the pusher, and the box that tips onto its leading edge;
* :mod:`.kernel`: compiled loops of the filter's likelihoods.
"""
