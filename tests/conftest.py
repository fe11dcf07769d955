"""Fixtures shared by the tracking tests."""
from __future__ import annotations

import pytest

from pipeline.robot import load_robot


@pytest.fixture(scope="session")
def disc():
    """The anchor streams' robot: a disc of radius 0.05 m on a 1 mm signed distance grid."""
    return load_robot("disc:0.05")
