"""`stucco plot` draws one run of any stage's table over its scene; `stucco segment --plot` names the objects as the
scene does and its legend shows every colour; probes and grasp attempts are marked; one method's title fits."""
from __future__ import annotations

import shutil

import pyarrow.parquet as pq
import pytest

import pipeline.figures.draw as draw
import pipeline.figures.tables as tables
from pipeline.atomic import save_figure
from pipeline.layout import partition
from tests.cli.stages import as_probe_run, invoke, ok

TABLES = {"run": "runs/FB-000.parquet", "contacts": "contacts.parquet", "tracks": "tracks.parquet",
          "segments": "segments.parquet", "retrieval": "retrieval.parquet"}


@pytest.fixture
def drawn(monkeypatch):
    """The legend labels and the suptitle of every figure saved by pipeline.figures (it still saves them)."""
    figs = []

    def keep(fig, path, **kw):
        fig.canvas.draw()
        labels = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
        title = fig._suptitle
        box = title.get_window_extent() if title is not None else None
        figs.append(dict(labels=labels, title=title.get_text() if title else "", box=box, width=fig.bbox.width,
                         lines=[(ln.get_color(), ln.get_linewidth()) for ax in fig.axes for ln in ax.get_lines()]))
        return save_figure(fig, path, **kw)

    import pipeline.figures as figures

    monkeypatch.setattr(tables, "save_figure", keep)
    monkeypatch.setattr(figures, "save_figure", keep)
    return figs


@pytest.mark.parametrize("kind", TABLES)
def test_plot_draws_every_stage_table(stages, tmp_path, kind, drawn):
    d, _ = stages
    out = tmp_path / f"{kind}.png"
    ok(invoke("plot", "--in", d / TABLES[kind], "--out", out, "--run", "FB/0"))
    assert out.read_bytes()[:4] == b"\x89PNG"
    (fig,) = drawn
    assert "gripper trail (scripted)" in fig["labels"] and "scene FB, seed 0" in fig["title"]
    if kind in ("tracks", "segments", "retrieval"):
        assert any(t.startswith("true: ") and t[6:] in ("cracker_box", "tomato_can", "mustard", "master_chef_can",
                                                          "potted_meat_can", "no object") for t in fig["labels"])
    if kind == "retrieval":
        assert any(t.startswith("grasp attempt (") for t in fig["labels"])
    assert 0 <= fig["box"].x0 and fig["box"].x1 <= fig["width"]


def test_segment_plot_names_objects_and_shows_every_colour(stages, drawn, tmp_path):
    d, _ = stages
    ok(invoke("segment", "--in", d / "tracks.parquet", "--out", tmp_path / "s.parquet", "--plot", tmp_path / "s.png"))
    (fig,) = drawn
    segments = pq.read_table(tmp_path / "s.parquet").column("segment").to_pylist()
    assert not any(t.startswith("true: object") for t in fig["labels"]), fig["labels"]
    for k in set(segments):
        assert any(t.startswith(f"segment {k}") for t in fig["labels"]), (k, fig["labels"])


def test_probes_are_told_apart_from_the_scripted_trail(stages, tmp_path, drawn):
    d, _ = stages
    # a run of the probing policy whose last 3 actions are its (its rows and metadata agree)
    run = as_probe_run(d / "runs" / "FB-000.parquet", tmp_path / "FB-000.parquet", k=3)
    ok(invoke("plot", "--in", run, "--out", tmp_path / "p.png"))
    (fig,) = drawn
    assert "probes (3 actions)" in fig["labels"]
    assert sum(1 for colour, width in fig["lines"] if colour == draw.PROBE and width >= 2) == 3


def test_one_method_title_is_not_clipped(stages, tmp_path, drawn):
    # an evaluation folder of one method, built from the small pipeline's tables
    d, _ = stages
    ev = tmp_path / "ev"
    for kind, src in (("runs", "runs/FB-000.parquet"), ("segments", "segments.parquet")):
        dst = partition(ev, kind, "FB", 0, None if kind == "runs" else "stucco")
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(d / src, dst)
    for kind, src in (("retrieval", "retrieval.parquet"), ("scores", "scores.parquet")):
        dst = partition(ev, kind, "FB", 0, "stucco", "plausible")
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(d / src, dst)
    from pipeline.figures import run_figure

    path = run_figure(ev, "FB", 0, ["stucco"], "plausible")
    assert path.read_bytes()[:4] == b"\x89PNG"
    (fig,) = drawn
    assert 0 <= fig["box"].x0 and fig["box"].x1 <= fig["width"], (fig["box"], fig["width"])
    assert "grasp attempt" not in " ".join(fig["labels"])  # one figure per run: the suptitle says it all


def test_plot_errors_are_one_line(stages, tmp_path):
    d, _ = stages
    cases = [
        (["--in", d / "segments.parquet", "--run", "FB/9"], "--run FB/9: not in"),
        (["--in", d / "scores.parquet"], "a scores table; `stucco plot` draws run, contacts"),
    ]
    lonely = tmp_path / "alone" / "segments.parquet"
    lonely.parent.mkdir()
    shutil.copyfile(d / "segments.parquet", lonely)
    cases.append((["--in", lonely], "no run file of FB/0 found"))
    other = tmp_path / "other"
    other.mkdir()
    t = pq.read_table(d / "runs" / "FB-000.parquet")
    pq.write_table(t.slice(0, 5), other / "FB-000.parquet")
    cases.append((["--in", d / "segments.parquet", "--runs", other], "is not the run file of FB/0"))
    for args, needle in cases:
        res = invoke("plot", *args, "--out", tmp_path / "x.png")
        assert res.exit_code == 1 and needle in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.output
        assert not (tmp_path / "x.png").exists()
