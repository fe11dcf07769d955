"""A small pipeline made through the CLI once per test session (FB seed 0, 12 actions, one grasp) for the tests of
the commands' shared behaviour: the overwrite rule, global options after the command, what each command says it
wrote, ``stucco plot``. Used through the ``stages`` fixture of tests/cli/conftest.py."""
from __future__ import annotations

from pathlib import Path

import pyarrow as pa
from click.testing import CliRunner

from pipeline import schema
from stucco_cli.main import cli

N_ACTIONS = 12
FAST_TRACK = ("--robot", "disc:0.05", "--particles", "20")


def invoke(*args, **kwargs):
    return CliRunner().invoke(cli, [str(a) for a in args], **kwargs)


def ok(res):
    assert res.exit_code == 0, (res.exit_code, res.output, res.exception)
    return res


#: Each stage command of the small pipeline: name -> (arguments, {option: output file}), in pipeline order.
def commands(d: Path) -> dict[str, tuple[list, dict[str, Path]]]:
    return {
        "collect": (["collect", "--scene", "FB", "--seeds", 0, "--max-actions", N_ACTIONS, "--out", d / "runs"],
                    {"--out": d / "runs" / "FB-000.parquet"}),
        "isolate": (["isolate", "--in", d / "runs", "--out", d / "contacts.parquet"],
                    {"--out": d / "contacts.parquet"}),
        "track": (["track", "--in", d / "contacts.parquet", "--out", d / "tracks.parquet", *FAST_TRACK],
                  {"--out": d / "tracks.parquet", "--diagnostics": d / "tracks.diagnostics.parquet"}),
        "segment": (["segment", "--in", d / "tracks.parquet", "--out", d / "segments.parquet", "--plot",
                     d / "segments.png"], {"--out": d / "segments.parquet", "--plot": d / "segments.png"}),
        "retrieve": (["retrieve", "--segments", d / "segments.parquet", "--runs", d / "runs", "--out",
                      d / "retrieval.parquet", "--estimator", "plausible", "--hypotheses", 4],
                     {"--out": d / "retrieval.parquet", "--candidates": d / "retrieval.candidates.parquet"}),
        "score": (["score", "--retrieval", d / "retrieval.parquet", "--segments", d / "segments.parquet", "--runs",
                   d / "runs", "--out", d / "scores.parquet"], {"--out": d / "scores.parquet"}),
        "plot": (["plot", "--in", d / "segments.parquet", "--out", d / "plot.png"], {"--out": d / "plot.png"}),
    }


def make(d: Path) -> dict[str, str]:
    """Run every command of :func:`commands` in ``d``; their stderr, by command."""
    said = {}
    for name, (args, _) in commands(d).items():
        said[name] = ok(invoke(*args)).stderr
    return said


def as_probe_run(src: Path, path: Path, *, k: int = 3, drop_column: bool = False, record=None, columns=None) -> Path:
    """The run file ``src`` recast as a run of the probing policy whose last ``k`` actions are probe
    actions of no probe (a consistent log), then edited: ``record`` changes its log, ``columns`` its columns."""
    t = schema.read_run(src)
    meta = schema.read_metadata(src)
    n = t.num_rows
    if not drop_column:
        t = t.append_column("probe", pa.array([i >= n - k for i in range(n)], pa.bool_()))
    log = {"params": {"budget": 0}, "probes": 0, "actions": k, "contacts": [], "lines": [], "share": 0.5,
           "agreed": False, "flagged": "budget_spent", "segment": -1, "target_steps": [], "other_steps": [],
           "switches": 0, "history": [{"rows": n - k, "segment": -1, "share": 0.5, "target_steps": [],
                                       "stop": False, "held": 0.0}]}
    log.update(record or {})
    for name, values in (columns or {}).items():
        t = t.set_column(t.column_names.index(name), name, values(t.column(name)))
    params = dict(meta["params"], policy="scripted+probe", probe=log)
    return schema.write_table(t, path, stage="collect", params=params, seed=meta["seed"], kind="sim_run")
