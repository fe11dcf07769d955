"""Evaluating a folder of generated scenes with the active protocol: the folder is read as its scene files, the
report gives the active protocol's table by target shape and no paper verdict (docs/active.md, "The planned
grasp"; docs/scene_generator.md)."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from pipeline.evaluate import parse_scenes
from stucco_cli.main import cli


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen")
    r = CliRunner().invoke(cli, ["-q", "scenes", "generate", "--n", "2", "--seed", "7", "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out


def test_a_folder_is_its_scene_files_in_name_order(generated):
    assert parse_scenes(str(generated), files=True) == ("GEN_00000", "GEN_00001")


def test_a_folder_without_scene_files_is_one_line(tmp_path):
    with pytest.raises(ValueError, match=r"a folder with no scene file \(\*\.toml\) in it"):
        parse_scenes(str(tmp_path), files=True)


def test_evaluate_runs_a_folder_with_the_active_protocol(generated, tmp_path):
    out = tmp_path / "ev"
    r = CliRunner().invoke(cli, ["--seed", "0", "evaluate", "--scenes", str(generated), "--seeds", "0",
                                 "--methods", "stucco", "--estimators", "plausible", "--policy", "scripted+probe",
                                 "--max-actions", "25", "--no-figures", "--jobs", "1", "--out", str(out)])
    assert r.exit_code == 0, r.output
    report = (out / "report.md").read_text()
    assert "| active protocol | runs | GS % first attempt | GS % within the attempts |" in report
    assert "other scenes, box target" in report and "other scenes, can target" in report
    assert "short by" not in report and ">= 65 %" not in report  # no paper verdict for a generated scene
    assert "paper GS %" not in report  # nor the paper's columns
