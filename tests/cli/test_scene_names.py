"""A scene file that takes a shipped scene's name with other content is refused by `stucco collect` (a byte-identical
copy is that scene); the report compares with the paper only the shipped tasks, by their digest."""
from __future__ import annotations

import shutil
from dataclasses import replace

import pyarrow as pa
import pytest

from pipeline.report import claims, paper_tasks, table_ii
from pipeline.scenes import SCENE_DIR, scene_digest
from pipeline.scenes.files import shadows_shipped, shipped_digest
from pipeline.score import SCORES_COLUMNS
from tests.cli.stages import invoke, ok
from tests.cli.test_run_scene import _moved_fb


def test_collect_refuses_a_file_named_like_a_shipped_scene(tmp_path):
    scene = _moved_fb(tmp_path / "mine.toml")
    assert 'name = "FB"' in scene.read_text()
    res = invoke("collect", "--scene", scene, "--seeds", 0, "--max-actions", 1, "--out", tmp_path / "runs")
    assert res.exit_code == 1 and "Traceback" not in res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {scene}: name = \"FB\" is the name of a shipped scene")
    assert "rename it" in lines[0] and not (tmp_path / "runs").exists()


def test_a_file_named_by_its_stem_is_refused_too(tmp_path):
    text = _moved_fb(tmp_path / "x.toml").read_text().replace('name = "FB"\n', "", 1)
    (tmp_path / "FB.toml").write_text(text)
    res = invoke("collect", "--scene", tmp_path / "FB.toml", "--seeds", 0, "--max-actions", 1, "--out", tmp_path / "r")
    assert res.exit_code == 1 and 'name = "FB" is the name of a shipped scene' in res.stderr


@pytest.mark.parametrize("renamed", [False, True])
def test_a_copy_or_a_renamed_scene_is_collected(tmp_path, renamed):
    path = tmp_path / "mine.toml"
    shutil.copyfile(SCENE_DIR / "FB.toml", path)
    if renamed:
        path.write_text(path.read_text().replace('name = "FB"', 'name = "my_FB"', 1))
    ok(invoke("-q", "collect", "--scene", path, "--seeds", 0, "--max-actions", 1, "--out", tmp_path / "runs"))
    assert (tmp_path / "runs" / f"{'my_FB' if renamed else 'FB'}-000.parquet").is_file()


def test_shadowing_is_decided_by_content():
    from pipeline.scenes import load_scene

    fb = load_scene("FB")
    assert shipped_digest("FB") == scene_digest(fb.source) and shipped_digest("MINE") is None
    assert not shadows_shipped(fb)
    assert shadows_shipped(replace(fb, source=fb.source + "\n# edited\n"))


def _scores(scene: str, digest: str | None, gs: bool = False) -> pa.Table:
    row = dict(scene=scene, seed=0, method="stucco", estimator="plausible", run=f"{scene}/0", grasp_success=gs,
               fmi=0.9, contact_error_cm=1.0, position_error_cm=1.0, yaw_error_rad=0.1, low_confidence=False,
               n_points=5, n_segments=2, track_s=0.1, retrieve_s=0.1, grasp_s=0.1, wall_s=0.3, scene_sha256=digest,
               grasp_attempts=None, grasp_success_any=None)
    return pa.table({c.name: pa.array([row[c.name]], type=c.type) for c in SCORES_COLUMNS})


def test_the_report_keys_the_paper_on_the_shipped_digest():
    shipped = _scores("FB", shipped_digest("FB"))
    mine = _scores("FB", "0" * 64)
    assert paper_tasks(shipped) == {"FB"} and paper_tasks(mine) == set()
    assert paper_tasks(shipped.drop_columns(["scene_sha256"])) == {"FB"}  # tables written before the column
    assert table_ii(shipped)[0].paper_gs_pct == 70 and table_ii(mine)[0].paper_gs_pct is None
    text = " ".join(claims(table_ii(mine)))
    assert "short by" not in text and "holds" not in text and "not one of the paper's tasks" in text
    assert "GS 0 % < 65 %: short by 65 points" in " ".join(claims(table_ii(shipped)))
