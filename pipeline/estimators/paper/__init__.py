"""The paper's pose estimator (§V-C): ICP restarts on every segment (:mod:`.icp`, :mod:`.icp_kernel`), the paper's
choice of segment and pose (:mod:`.choice`), run at the end of a run or online at every in-contact step
(:mod:`.online`)."""
