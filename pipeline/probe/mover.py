"""The ``scripted+probe`` collection policy: the scene's scripted actions, then the probing loop in the same world.

:func:`pipeline.collect.collect_run` drives it like every policy of :mod:`pipeline.policies` (the scripted part is
:class:`~pipeline.policies.ScriptedPolicy`'s), then calls :meth:`ScriptedProbePolicy.after`, which runs
:func:`pipeline.probe.policy.run_policy` on what was sensed so far and appends its probe actions to the run
(docs/active.md). Registered in :mod:`pipeline.registry`.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.policies import ScriptedPolicy
from pipeline.probe.policy import ProbeParams, run_policy

__all__ = ["ScriptedProbePolicy"]


class ScriptedProbePolicy(ScriptedPolicy):
    """The scripted actions with their replay noise, then probes (:class:`~pipeline.probe.policy.ProbeParams`)."""

    def __init__(self, scene, policy_rng: np.random.Generator, noise_rng: np.random.Generator,
                 max_actions: int | None = None, params: ProbeParams | None = None) -> None:
        super().__init__(scene, policy_rng, noise_rng, max_actions, params)
        self.probe = params if params is not None else ProbeParams()
        #: The run's wall times, kept out of the run file (CollectResult.probe_s): ``decision_s`` (s, a list: each
        #: probe decision) and ``prior_s`` (s: the pushes' prior, once).
        self.times: dict | None = None

    def after(self, world, rows: list, summarize: Callable, table: Callable, seed: int, root_seed: int
              ) -> dict[str, Any]:
        """Probe in ``world`` after the scripted ``rows`` (appending the probe actions to them); what the run's
        metadata records under ``probe`` (no wall time: the same command writes the same file)."""
        meta, self.times = run_policy(world, self.scene, seed, root_seed, rows, summarize, table, self.probe)
        return meta
