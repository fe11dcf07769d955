"""A run carries the scene it was collected in (issue 17, bad-input probe): ``collect`` stores the scene's TOML
text and SHA-256 in the run's metadata, retrieval and scoring use that scene (checked by its digest), never a
scene file whose path a data file names, and ``evaluate --scenes my/FB.toml`` collects and scores that file, not
the shipped FB."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline.retrieve import load_run
from pipeline.scenes import SCENE_DIR, load_scene, scene_digest
from pipeline.schema import read_metadata
from stucco_cli.main import cli
from tests.cli.test_bad_runs import RUN

#: FB with its cracker box moved 5 cm in +y and made 2 cm longer: the same name, another scene.
MOVED = (0.15, 0.10)


def _moved_fb(path: Path) -> Path:
    text = (SCENE_DIR / "FB.toml").read_text()
    text = text.replace("size = [0.0616, 0.1575, 0.207]\nposition = [0.15, 0.05]",
                        f"size = [0.0616, 0.1775, 0.207]\nposition = [{MOVED[0]}, {MOVED[1]}]", 1)
    assert f"position = [{MOVED[0]}, {MOVED[1]}]" in text
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _with_params(src: Path, dst: Path, **changes) -> Path:
    t = pq.read_table(src)
    meta = dict(t.schema.metadata)
    params = json.loads(meta[b"stucco.params"])
    params.update(changes)
    meta[b"stucco.params"] = json.dumps(params).encode()
    pq.write_table(t.replace_schema_metadata(meta), dst)
    return dst


def collect_file(scene: Path, out: Path, max_actions: int, seed: int = 0, root_seed: int = 0) -> Path:
    """Collect seed ``seed`` of the scene file ``scene`` through the pipeline (``stucco collect`` refuses a file that
    takes a shipped scene's name with other content, which these tests need: a run of another scene named FB)."""
    from pipeline.collect import collect

    res = collect(load_scene(scene), [seed], out, root_seed=root_seed, progress=True, max_actions=max_actions)
    assert res[0].path is not None
    return Path(res[0].path)


@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    """Two actions of seed 0 of the moved FB, collected from its file."""
    tmp = tmp_path_factory.mktemp("collected")
    scene = _moved_fb(tmp / "my" / "FB.toml")
    return scene, collect_file(scene, tmp / "runs", 2)


def test_collect_stores_the_scene_and_its_digest(collected):
    scene, run = collected
    params = read_metadata(run)["params"]
    assert params["scene_toml"] == scene.read_text()
    assert params["scene_sha256"] == scene_digest(scene.read_text())


def test_retrieval_uses_the_scene_of_the_run_not_the_shipped_one(collected):
    scene, run = collected
    info = load_run(run)
    shipped = load_scene("FB")
    assert info.scene.name == "FB" and info.scene.target.size[1] == pytest.approx(0.1775)
    assert shipped.target.size[1] == pytest.approx(0.1575)
    scene.write_text("edited after collection")  # the file is not read again
    assert load_run(run).scene.target.size[1] == pytest.approx(0.1775)
    _moved_fb(scene)


def test_a_run_whose_scene_text_was_edited_is_refused(collected, tmp_path):
    _, run = collected
    text = read_metadata(run)["params"]["scene_toml"].replace("0.1775", "0.3", 1)
    bad = _with_params(run, tmp_path / "FB-000.parquet", scene_toml=text)
    with pytest.raises(ValueError, match="FB-000.parquet.*scene_sha256"):
        load_run(bad)


@pytest.mark.parametrize("field", ["scene path", "scene path and text"])
def test_a_scene_path_in_a_run_file_is_never_loaded(tmp_path, field):
    # an old run file (no scene_toml) whose params.scene names a scene file: refused, the file never parsed
    evil = _moved_fb(tmp_path / "evil" / "FB.toml")
    runs = tmp_path / "runs"
    runs.mkdir()
    extra = {"scene_toml": "", "scene_sha256": ""} if field.endswith("text") else {}
    bad = _with_params(RUN, runs / "FB-000.parquet", scene=str(evil), **extra)
    from tests.cli.test_bad_runs import _stucco_segments

    segments = _stucco_segments(tmp_path / "segments.parquet")
    out = tmp_path / "r.parquet"
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(segments), "--runs", str(runs),
                                 "--out", str(out), "--no-grasp", "--method", "stucco"])
    assert r.exit_code == 1 and "not a shipped scene" in r.output and bad.name in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1 and not out.exists()


def test_an_old_run_file_names_a_shipped_scene():
    info = load_run(RUN)  # stored before runs carried their scene
    assert info.scene == load_scene("FB")


def test_evaluate_collects_and_scores_the_scene_file_it_is_given(tmp_path):
    scene = _moved_fb(tmp_path / "my" / "FB.toml")
    out = tmp_path / "ev"
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", str(scene), "--seeds", "0", "--methods", "stucco",
                                 "--estimators", "paper", "--max-actions", "2", "--restarts", "2",
                                 "--no-figures", "--out", str(out)])
    assert r.exit_code == 0, r.output
    runs = sorted((out / "runs").rglob("*.parquet"))
    assert len(runs) == 1
    info = load_run(runs[0])
    assert info.scene.target.size[1] == pytest.approx(0.1775)
    # the box starts 5 cm further in +y than in the shipped FB (its initial pose, after settling)
    start = np.array(read_metadata(runs[0])["params"]["initial"]["obj_pose"][info.target_id][:2])
    shipped = np.array(read_metadata(RUN)["params"]["initial"]["obj_pose"][info.target_id][:2])
    np.testing.assert_allclose(start - shipped, [0.0, MOVED[1] - 0.05], atol=0.005)
    cfg = json.loads((out / "evaluation.json").read_text())
    assert cfg["scene_files"] == [["FB", str(scene.resolve()), scene_digest(scene.read_text())]]
    # not the shipped FB: the report gives it neither the paper's figures nor its verdicts
    report = (out / "report.md").read_text()
    assert "short by" not in report and "holds" not in report and "| FB | ours (STUCCO) | 1 | 0 | " in report
    assert "paper GS %" not in report
    assert "FB: not one of the paper's tasks as shipped" in report
    # the shipped FB is another evaluation
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco",
                                 "--estimators", "paper", "--max-actions", "2", "--restarts", "2",
                                 "--no-figures", "--out", str(out)])
    assert r.exit_code == 1 and "scene_files" in r.output, r.output


def test_commands_that_run_shipped_scenes_refuse_another_file_of_that_name(tmp_path):
    scene = _moved_fb(tmp_path / "my" / "FB.toml")
    r = CliRunner().invoke(cli, ["bench", "accuracy", "--scenes", str(scene), "--out", str(tmp_path / "acc")])
    assert r.exit_code == 2 and "is not the shipped scene 'FB'" in r.output, r.output


def test_a_copy_of_a_shipped_scene_is_that_scene(tmp_path):
    copy = tmp_path / "FB.toml"
    shutil.copyfile(SCENE_DIR / "FB.toml", copy)
    from pipeline.evaluate import parse_scenes, scene_files

    assert parse_scenes(str(copy)) == ("FB",) and scene_files(str(copy)) == ()
