"""Optional speed-ups do not change what stucco does (issue 17, environment): STUCCO's numba kernels
(pipeline/track/kernels.py, ordering.py, replacement.py, weights.py) run as plain Python (``NUMBA_DISABLE_JIT=1``;
a kernel's ``py_func`` is what that runs) give the compiled kernels' results, and an unwritable cache folder (the
Panda grid's, under ``$HOME``) only costs time."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.robot import panda_cache
from pipeline.track import kernels, ordering, replacement, weights
from tests.test_soft import _random_stream, make, run

# every jitted function, helpers included (as NUMBA_DISABLE_JIT=1 runs them: numpy scalars, not Python floats)
KERNELS = tuple((module, name) for module in (kernels, ordering, replacement, weights)
                for name, f in vars(module).items()
                if hasattr(f, "py_func"))


def _state(tracker):
    m = tracker.n_points_
    return (tracker._P[:, :m].copy(), tracker._C[:, :m].copy(), tracker._colpen[:, :m].copy(),
            tracker._npen[:, :m].copy(), tracker.log_weights_.copy())


@pytest.mark.parametrize("replace", ["never", "after-resample"])
def test_python_kernels_give_the_compiled_results(disc, monkeypatch, replace):
    def tracked():
        rng = np.random.default_rng(5)
        return _state(run(make(disc, 5, n_particles=6, replace=replace), _random_stream(rng, 15, p_free=0.0)))

    compiled = tracked()
    assert {"predict_and_update", "free_space_penetration", "replace_inconsistent", "contribution",
            "groups_by_first_coordinate", "_sort_group", "below_exp"} <= {name for _, name in KERNELS}
    for module, name in KERNELS:
        monkeypatch.setattr(module, name, getattr(module, name).py_func)
    python = tracked()
    if replace == "never":  # penetrating points stay counted, so the count updates (bool arithmetic) ran
        assert python[3].sum() > 0
    for a, b in zip(compiled, python):
        np.testing.assert_array_equal(a, b)



def test_an_unwritable_cache_folder_warns_once_and_builds_the_grid(disc, tmp_path, monkeypatch, capsys):
    locked = tmp_path / "home"
    locked.write_text("")  # ~/.cache/stucco cannot be created (as in a read-only $HOME, whatever the user)
    built = []
    monkeypatch.setattr(panda_cache, "build_panda_grid", lambda *a: built.append(a) or disc)
    monkeypatch.setattr(panda_cache, "_WARNED", set())
    grids = [panda_cache.panda_sdf(cache_dir=locked / ".cache" / "stucco") for _ in range(2)]
    assert all(g is disc for g in grids) and len(built) == 2
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "cache" in ln]
    assert len(warnings) == 1 and "STUCCO_CACHE_DIR" in warnings[0]
    assert locked.read_text() == ""
