"""Active retrieval (docs/active.md): after the scripted rummage a policy probes with
guarded moves until the target's pose is known (:mod:`.policy`, planning in :mod:`.planning`, the pipeline's view
of what was sensed in :mod:`.belief`), then grasps with the grasp that succeeds for most of the plausible set
(:mod:`.set_grasp`).
"""
