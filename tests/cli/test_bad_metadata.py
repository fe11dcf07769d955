"""Valid JSON of the wrong shape in a table's ``stucco.*`` metadata or in ``evaluation.json`` (``[1]``, ``7``,
``"x"``) is refused in one line naming the file (issue 17, bad-input probe), never an AttributeError traceback."""
from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from pipeline import schema
from pipeline.studies.anchors import load_stream, stream_path, stream_to_contacts
from stucco_cli.main import cli
from tests.cli.test_bad_runs import RUN, _stucco_segments

SHAPES = {"list": "[1]", "number": "7", "string": '"x"'}


def _with_metadata(src: Path, dst: Path, key: str, text: str) -> Path:
    t = pq.read_table(src)
    meta = dict(t.schema.metadata or {})
    meta[f"stucco.{key}".encode()] = text.encode()
    pq.write_table(t.replace_schema_metadata(meta), dst)
    return dst


def _one_line(r, path: Path) -> None:
    assert r.exit_code not in (0, None) and isinstance(r.exception, SystemExit), r.output
    lines = [ln for ln in r.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.output, r.output
    assert str(path) in lines[0] or path.name in lines[0], r.output


@pytest.mark.parametrize("key", ["params", "inputs", "seed"])
@pytest.mark.parametrize("shape", list(SHAPES), ids=list(SHAPES))
def test_read_metadata_refuses_a_wrong_shape_naming_the_file(tmp_path, key, shape):
    if key == "seed" and shape == "number":
        pytest.skip("7 is a valid seed")
    bad = _with_metadata(RUN, tmp_path / "FB-000.parquet", key, SHAPES[shape])
    with pytest.raises(schema.SchemaError, match=rf"FB-000.parquet.*stucco.{key}"):
        schema.read_metadata(bad)


def test_an_input_entry_of_the_wrong_shape_is_named(tmp_path):
    bad = _with_metadata(RUN, tmp_path / "FB-000.parquet", "inputs", '{"segments": [1]}')
    with pytest.raises(schema.SchemaError, match="input 'segments'"):
        schema.read_metadata(bad)


@pytest.mark.parametrize("shape", list(SHAPES), ids=list(SHAPES))
@pytest.mark.parametrize("culprit", ["segments", "run"])
def test_retrieve_names_the_file_with_bad_metadata(tmp_path, shape, culprit):
    runs = tmp_path / "runs"
    runs.mkdir()
    segments = _stucco_segments(tmp_path / "segments.parquet")
    run = runs / "FB-000.parquet"
    if culprit == "run":
        _with_metadata(RUN, run, "params", SHAPES[shape])
        bad = run
    else:
        run.write_bytes(RUN.read_bytes())
        bad = _with_metadata(segments, segments, "params", SHAPES[shape])
    out = tmp_path / "retrieval.parquet"
    r = CliRunner().invoke(cli, ["-q", "retrieve", "--segments", str(segments), "--runs", str(runs),
                                 "--out", str(out), "--method", "stucco", "--no-grasp"])
    _one_line(r, bad)
    assert not out.exists()


@pytest.mark.parametrize("value", ["[1]", '"x"', "1e999", "-0.02"], ids=["list", "string", "infinite", "negative"])
def test_segment_names_a_recorded_length_of_the_wrong_type_or_range(tmp_path, value):
    contacts = tmp_path / "contacts.parquet"
    pq.write_table(stream_to_contacts(load_stream(stream_path(50)), "r").slice(0, 70), contacts)
    tracks = tmp_path / "tracks.parquet"
    r = CliRunner().invoke(cli, ["-q", "track", "--in", str(contacts), "--out", str(tracks), "--robot", "disc:0.05"])
    assert r.exit_code == 0, r.output
    params = json.loads(pq.read_schema(tracks).metadata[b"stucco.params"])
    text = json.dumps(dict(params, length=json.loads(value)))
    _with_metadata(tracks, tracks, "params", text)
    out = tmp_path / "segments.parquet"
    r = CliRunner().invoke(cli, ["-q", "segment", "--in", str(tracks), "--out", str(out)])
    _one_line(r, tracks)
    assert "stucco.params.length" in r.output and not out.exists()


@pytest.mark.parametrize("text", ["[1]", "7", '"x"', "null"])
def test_evaluate_names_an_evaluation_json_of_the_wrong_shape(tmp_path, text):
    out = tmp_path / "ev"
    out.mkdir()
    (out / "evaluation.json").write_text(text)
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco",
                                 "--out", str(out), "--no-figures", "--max-actions", "2"])
    _one_line(r, out / "evaluation.json")
    assert (out / "evaluation.json").read_text() == text
