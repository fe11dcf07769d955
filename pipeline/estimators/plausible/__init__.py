"""The plausible-set estimator: SE(2) hypotheses fitted to the target's shape, its contact points and the gripper's
free space (:mod:`.fit`), the evidence it weighs (:mod:`.evidence`) and its compiled cost terms (:mod:`.kernel`)."""
