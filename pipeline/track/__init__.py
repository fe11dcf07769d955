"""Contact trackers behind one interface (:mod:`.base`): STUCCO soft tracking (paper §IV-B), baselines (§V-A)."""
