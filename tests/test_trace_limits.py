"""Trace files (CSV through a column mapping) meet the same limits and encodings as recordings."""

import numpy as np
import pytest

from hil.recording.errors import RecordingError
from hil.recording.drivers import record_kinematic
from hil.recording.traces import TraceMapping, read_trace, write_level_trace, write_meta
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint


@pytest.fixture(scope="module")
def rec():
    return record_kinematic(paper_bench(), [OperatingPoint(0.02, 3000.0, 1.0, id="a")], seed=1)


@pytest.fixture
def files(tmp_path, rec):
    return write_meta(rec, tmp_path / "meta.json"), write_level_trace(rec, tmp_path / "t.csv", 200e3)


MAPPING = TraceMapping(threshold=2.5)


def test_a_byte_order_mark_is_accepted_in_trace_meta_and_mapping(files, rec, tmp_path):
    meta, trace = files
    plain = read_trace(trace, MAPPING, meta)
    for path in (meta, trace):
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    mapping = tmp_path / "m.toml"
    mapping.write_bytes(b"\xef\xbb\xbfthreshold = 2.5\n")
    back = read_trace(trace, TraceMapping.from_toml(mapping), meta)
    np.testing.assert_array_equal(back.t_s, plain.t_s)


def test_sparse_oversized_and_undecodable_traces_are_one_line(files, tmp_path):
    meta, trace = files
    lines = trace.read_bytes().split(b"\n")
    lines[7] = lines[7][:3] + b"\xfe" + lines[7][4:]
    trace.write_bytes(b"\n".join(lines))
    with pytest.raises(RecordingError) as info:
        read_trace(trace, MAPPING, meta)
    assert (info.value.line, info.value.column) == (8, "4 (character)") and "not valid UTF-8" in str(info.value)
    with open(trace, "wb") as fh:
        fh.truncate(2 << 30)
    with pytest.raises(RecordingError, match="above the reader's limit") as info:
        read_trace(trace, MAPPING, meta)
    assert "\n" not in str(info.value)
    meta.write_text('{"format": "hil-recording/1", "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(
        RecordingError, match=r"meta.json, line 1, column \d+ \(character\): nested deeper than 64 levels"
    ):
        read_trace(tmp_path / "t.csv", MAPPING, meta)
