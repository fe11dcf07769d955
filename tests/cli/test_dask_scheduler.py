"""`stucco evaluate --backend dask` with a scheduler address that refuses connections fails at once with one line
(issue 17, item 6), before any folder is written; an address that does not answer keeps distributed's timeout."""
from __future__ import annotations

import socket

import pytest
from click.testing import CliRunner

from stucco_cli.main import cli

pytest.importorskip("distributed")


def _closed_port() -> int:
    """A local TCP port nothing listens on: bound, then released."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_refused_scheduler_address_is_one_line_and_writes_nothing(tmp_path):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    out = tmp_path / "eval"
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco",
                                 "--no-figures", "--max-actions", "2", "--out", str(out),
                                 "--backend", "dask", "--scheduler", address])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "connection refused" in lines[0] and address in lines[0], r.output
    assert not out.exists()


def test_an_address_that_is_not_one_is_named(tmp_path):
    r = CliRunner().invoke(cli, ["-q", "evaluate", "--scenes", "FB", "--seeds", "0", "--methods", "stucco",
                                 "--out", str(tmp_path / "eval"), "--backend", "dask", "--scheduler",
                                 "tcp://127.0.0.1:notaport"])
    assert r.exit_code == 1 and "--scheduler tcp://127.0.0.1:notaport" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1
