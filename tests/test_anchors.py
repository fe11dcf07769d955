"""The authors' benchmark streams (pipeline/studies/anchors.py): a contact count without its own file is cut from a
longer stream, which is the same trajectory (the streams are prefixes of one another)."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.studies.anchors import (
    ANCHOR_DIR,
    check_streams,
    load_contacts_stream,
    load_stream,
    source_path,
    stream_path,
)


def test_a_stream_cut_from_a_longer_one_is_the_shorter_file(tmp_path):
    # only T=100 in the folder: T=50 must come out of it exactly as the T=50 file holds it
    (tmp_path / "stream_T100.npz").write_bytes(stream_path(100).read_bytes())
    assert source_path(50, tmp_path) == tmp_path / "stream_T100.npz"
    cut, whole = load_contacts_stream(50, tmp_path), load_stream(stream_path(50))
    assert set(cut) == set(whole)
    for k in whole:
        np.testing.assert_array_equal(cut[k], whole[k], err_msg=k)


def test_an_intermediate_count_has_exactly_that_many_contacts_and_ends_on_one():
    s = load_contacts_stream(300)
    c = s["in_contact"].astype(bool)
    assert c.sum() == 300 and c[-1]
    assert len(s["x"]) == len(s["obj_centers"]) == len(c) < len(load_stream(stream_path(400))["x"])
    assert check_streams([300]) == [stream_path(400)]


def test_a_count_beyond_every_stream_is_refused_with_the_counts_available():
    with pytest.raises(ValueError, match=r"no stream for T=500 .*T=50, T=100, T=200, T=400"):
        check_streams([500], ANCHOR_DIR)
