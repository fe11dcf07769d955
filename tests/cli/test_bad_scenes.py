"""Scene files are refused, in one line naming the file and the key, when a value is outside physical bounds, the
name is not a plain identifier (it would escape ``--out``), or the file is not text (issue 12, classes 4-7).

Every case: ``stucco collect`` exits non-zero, prints one line naming the culprit, writes nothing anywhere (not
even outside ``--out``) and leaves the scene file byte-identical. Bounds are documented in docs/simulation.md.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from stucco_cli.main import cli

FB = Path(__file__).resolve().parents[2] / "data" / "scenes" / "FB.toml"


def _sub(pattern: str, repl: str):
    def edit(text: str) -> str:
        out, n = re.subn(pattern, repl, text, count=1, flags=re.MULTILINE)
        assert n == 1, pattern
        return out
    return edit


#: (case id, edit of FB.toml's text, text the message must contain).
CASES = [
    ("name escapes --out", _sub(r'^name = "FB"', 'name = "../../evil"'), "'name'"),
    ("name with a slash", _sub(r'^name = "FB"', 'name = "a/b"'), "'name'"),
    ("name with a space", _sub(r'^name = "FB"', 'name = "F B"'), "'name'"),
    ("empty name", _sub(r'^name = "FB"', 'name = ""'), "'name'"),
    ("object of 1e9 m", _sub(r"^size = \[0.0616, 0.1575, 0.207\]", "size = [1e9, 0.1575, 0.207]"),
     "'objects[0].size'"),
    ("object far away", _sub(r"^position = \[0.15, 0.05\]", "position = [1e6, 0.05]"), "'objects[0].position'"),
    ("mass of 1e9 kg", _sub(r"^mass = 10.0", "mass = 1e9"), "'objects[0].mass'"),
    ("friction of 1e6", _sub(r"^lateral_friction = 0.5", "lateral_friction = 1e6"),
     "'objects[0].lateral_friction'"),
    ("action scale of 1e6 m", _sub(r"^scale = 0.03", "scale = 1e6"), "'actions.scale'"),
    ("settle steps 1e9 (a hang)", _sub(r"^settle_steps = 1000", "settle_steps = 1000000000"),
     "'effects.settle_steps'"),
    ("noise of 1 m", _sub(r"^noise_mm = 0.5", "noise_mm = 1000.0"), "'effects.noise_mm'"),
    ("gripper far away", _sub(r"^start = \[0.0, 0.1\]", "start = [0.0, 1e7]"), "'gripper.start'"),
    ("a can inside the box", _sub(r"^position = \[0.2, -0.1\]", "position = [0.17, 0.03]"),
     "'cracker_box' has its centre inside 'tomato_can'"),
    ("the gripper inside the box", _sub(r"^start = \[0.0, 0.1\]", "start = [0.18, 0.04]"),
     "the gripper starts inside 'cracker_box'"),
]


def _run(tmp_path: Path, content: bytes, name: str = "X.toml"):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    scene = scenes / name
    scene.write_bytes(content)
    out = tmp_path / "a" / "b" / "runs"
    before = sorted(p for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(cli, ["-q", "collect", "--scene", str(scene), "--seeds", "0", "--out", str(out),
                                 "--max-actions", "2"])
    assert r.exit_code != 0, r.output
    assert "Traceback" not in r.output and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error:"), r.output
    assert sorted(p for p in tmp_path.rglob("*")) == before  # nothing written, anywhere
    assert scene.read_bytes() == content
    return lines[0], scene


@pytest.mark.parametrize("edit, culprit", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_scene_outside_bounds_is_refused_in_one_line(tmp_path, edit, culprit):
    line, scene = _run(tmp_path, edit(FB.read_text()).encode())
    assert str(scene) in line and culprit in line, line


@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe binary", "name = \"FB\"\n\udcff".encode(
    "utf-8", "surrogateescape")], ids=["binary", "not UTF-8"])
def test_a_binary_scene_file_is_named(tmp_path, content):
    line, scene = _run(tmp_path, content)
    assert str(scene) in line and "TOML" in line, line


def test_the_shipped_scenes_are_within_bounds():
    from pipeline.scenes import load_all

    assert len(load_all()) >= 8
