"""Contact trackers: STUCCO soft tracking (:mod:`.soft`) and the baselines, behind one interface (:mod:`.base`)."""
