"""Fixtures shared by the tracking tests, and the order in which ``make test`` hands the test files out."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from pipeline.robot import load_robot

TESTS = Path(__file__).resolve().parent

#: The slowest test files, slowest first (seconds of one `make test` on the 2-core machine, each file in one
#: xdist worker, summed over its tests: about 75, 55, 55, 40, 30, 25, 20, 17, 15, 13, 12, with the other worker
#: busy). `--dist loadfile` hands whole files to the two workers in the collection order (pyproject.toml turns
#: off xdist's own reordering, which put files with many tests first and so these, with 1-21 tests each, last),
#: and the suite cannot end before the file a worker starts last: handing out the longest first lets the many
#: short files even out the two workers at the end. Only the order changes; a file missing here runs after them.
SLOWEST_FIRST = ("test_regression.py", "test_study.py", "test_evaluate.py", "test_dask_processes.py",
                 "test_scale.py", "test_collect.py", "test_outputs_open.py", "test_sim_reuse.py", "test_ladder.py",
                 "test_icp_kernel.py", "cli/test_track_cli.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}

    def file_rank(item) -> int:
        try:
            return rank.get(item.path.relative_to(TESTS).as_posix(), len(rank))
        except ValueError:  # a test outside tests/ (named on the command line)
            return len(rank)

    items.sort(key=file_rank)  # stable: the other files, and the tests of each file, keep their order


@pytest.fixture(scope="session", autouse=True)
def _loky_workers_stopped_at_the_end():
    """At the end of a worker's tests, stop the loky processes they started (evaluate, collect and track with
    jobs=2, which joblib keeps for reuse) without waiting for each to shut its interpreter down: the xdist worker's
    exit otherwise joined them, 1-2 s on an idle machine and up to 15 s on a busy one, at the end of the suite.
    Every test has run by then, so no result depends on it."""
    yield
    executor = getattr(sys.modules.get("joblib.externals.loky.reusable_executor"), "_executor", None)
    if executor is not None:
        executor.shutdown(wait=False, kill_workers=True)


@pytest.fixture(scope="session")
def disc():
    """The anchor streams' robot: a disc of radius 0.05 m on a 1 mm signed distance grid."""
    return load_robot("disc:0.05")
