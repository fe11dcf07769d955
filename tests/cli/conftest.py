"""Fixtures shared by the CLI tests."""
from __future__ import annotations

import pytest

from tests.cli.stages import make


@pytest.fixture(scope="session")
def stages(tmp_path_factory):
    """(folder, stderr by command) of the small pipeline of :mod:`tests.cli.stages`, made once per session."""
    d = tmp_path_factory.mktemp("stages")
    return d, make(d)
