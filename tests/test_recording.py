"""hil-recording/1: exact round trip, and every violation the format lists is refused precisely."""

import json
import shutil

import numpy as np
import pytest

from hil.recording.drivers import record_kinematic
from hil.recording.errors import RecordingError
from hil.recording.format import write_recording
from hil.recording.reader import read_recording
from plant_models import paper_bench
from plant_models.kinematic import OperatingPoint

PROFILE = [OperatingPoint(0.05, 1000.0, 0.5, id="low"), OperatingPoint(0.05, 5000.0, 2.0, id="mid"),
           OperatingPoint(0.05, 3000.0, 1.0, direction=-1, id="rev")]


@pytest.fixture(scope="module")
def recording():
    return record_kinematic(paper_bench(with_deviations=True), PROFILE, seed=3)


@pytest.fixture
def written(tmp_path, recording):
    return write_recording(recording, tmp_path / "rec")


def test_round_trip_is_identical(written, recording, tmp_path):
    back = read_recording(written)
    np.testing.assert_array_equal(back.t_s, recording.t_s)
    np.testing.assert_array_equal(back.sensor, recording.sensor)
    np.testing.assert_array_equal(back.rising, recording.rising)
    np.testing.assert_array_equal(back.segment, recording.segment)
    np.testing.assert_array_equal(back.ref_angle_mech_deg, recording.ref_angle_mech_deg)
    for k, v in recording.truth.items():
        np.testing.assert_array_equal(back.truth[k], v)
    assert back.motor == recording.motor and back.timer_tick_s == recording.timer_tick_s
    assert [s.__dict__ for s in back.segments] == [s.__dict__ for s in recording.segments]
    again = write_recording(back, tmp_path / "again")
    for name in ("meta.json", "edges.csv", "ground_truth.csv"):
        assert (again / name).read_text() == (written / name).read_text()


def test_reference_angle_obeys_its_definition(recording):
    """theta_e = p * ref_angle: ideal A rising edges sit at 0 (forward) once deviations are removed."""
    truth_err = recording.truth["t_conditioned_s"] - recording.truth["t_ideal_s"]
    assert np.all(recording.ref_angle_mech_deg >= 0) and np.all(recording.ref_angle_mech_deg < 360)
    assert np.all(np.isfinite(truth_err))


def test_samples_round_trip(tmp_path, recording):
    from dataclasses import replace

    n = 50
    samples = {
        "t_s": np.linspace(0, 0.01, n),
        "segment": np.zeros(n, dtype=np.int64),
        "i_a": np.sin(np.arange(n)),
        "speed_rpm": np.full(n, 1000.0),
    }
    rec = replace(recording, samples=samples)
    back = read_recording(write_recording(rec, tmp_path / "s"))
    assert set(back.samples) == set(samples)
    for k in samples:
        np.testing.assert_array_equal(back.samples[k], samples[k])


def edit(path, name, line_no, old, new):
    lines = (path / name).read_text().splitlines(keepends=True)
    assert old in lines[line_no - 1], (old, lines[line_no - 1])
    lines[line_no - 1] = lines[line_no - 1].replace(old, new, 1)
    (path / name).write_text("".join(lines))


def refused(path, file, line, column):
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    err = info.value
    assert err.file.endswith(file), str(err)
    assert err.line == line, str(err)
    assert err.column == column, str(err)
    msg = str(err)
    assert file in msg and (line is None or f"line {line}" in msg) and (column is None or column in msg)
    return msg


def test_missing_files(written):
    (written / "edges.csv").unlink()
    refused(written, "edges.csv", None, None)
    (written / "meta.json").unlink()
    refused(written, "meta.json", None, None)


def test_missing_column(written):
    edit(written, "edges.csv", 1, "sensor,", "sensr,")
    assert "missing column" in refused(written, "edges.csv", 1, "sensor")


@pytest.mark.parametrize(
    "old, new, column, what",
    [
        (None, "abc", "t_s", "not a number"),
        (None, "nan", "t_s", "not finite"),
        (None, "inf", "t_s", "not finite"),
    ],
)
def test_bad_numbers(written, old, new, column, what):
    line = (written / "edges.csv").read_text().splitlines()[4]
    t = line.split(",")[0]
    edit(written, "edges.csv", 5, t, new)
    assert what in refused(written, "edges.csv", 5, column)


def test_times_not_increasing(written):
    lines = (written / "edges.csv").read_text().splitlines()
    t4 = lines[3].split(",")[0]
    t5 = lines[4].split(",")[0]
    edit(written, "edges.csv", 5, t5, t4)  # equal to the previous time
    assert "increase" in refused(written, "edges.csv", 5, "t_s")


@pytest.mark.parametrize(
    "field_index, new, column, what",
    [
        (1, "D", "sensor", "unknown sensor"),
        (2, "up", "edge", "unknown edge"),
        (3, "op99", "segment", "unknown segment"),
    ],
)
def test_unknown_sensor_edge_segment(written, field_index, new, column, what):
    parts = (written / "edges.csv").read_text().splitlines()[9].split(",")
    edit(written, "edges.csv", 10, ",".join(parts), ",".join(parts[:field_index] + [new] + parts[field_index + 1 :]))
    assert what in refused(written, "edges.csv", 10, column)


@pytest.mark.parametrize("angle", ["360.0", "-0.5", "1e9"])
def test_angle_outside_range(written, angle):
    parts = (written / "edges.csv").read_text().splitlines()[6].split(",")
    edit(written, "edges.csv", 7, ",".join(parts), ",".join(parts[:4] + [angle]))
    assert "outside [0.0, 360.0)" in refused(written, "edges.csv", 7, "ref_angle_mech_deg")


def test_wrong_field_count(written):
    parts = (written / "edges.csv").read_text().splitlines()[2]
    edit(written, "edges.csv", 3, parts, parts + ",extra")
    refused(written, "edges.csv", 3, None)


def rewrite_meta(path, change):
    meta = json.loads((path / "meta.json").read_text())
    change(meta)
    (path / "meta.json").write_text(json.dumps(meta, indent=2))


@pytest.mark.parametrize(
    "change, column",
    [
        (lambda m: m.update(format="hil-recording/2"), "format"),
        (lambda m: m["motor"].update(pole_pairs=0), "motor.pole_pairs"),
        (lambda m: m["motor"].pop("pole_pairs"), "motor.pole_pairs"),
        (lambda m: m["segments"][1].update(speed_rpm="fast"), "segments[1].speed_rpm"),
        (lambda m: m["segments"][2].update(direction="backwards"), "segments[2].direction"),
        (lambda m: m["segments"][1].update(id="low"), "segments[1].id"),
        (lambda m: m["segments"][1].update(t_start_s=0.01), "segments[1].t_start_s"),
        (lambda m: m.update(timer_tick_s=-1), "timer_tick_s"),
        (lambda m: m.update(segments={}), "segments"),
    ],
)
def test_meta_errors_name_the_key(written, change, column):
    rewrite_meta(written, change)
    with pytest.raises(RecordingError) as info:
        read_recording(written)
    assert info.value.column == column and info.value.file.endswith("meta.json"), str(info.value)
    assert info.value.line is not None


def test_invalid_json_has_line_and_column(written):
    text = (written / "meta.json").read_text().splitlines()
    text[3] = text[3] + ","  # trailing comma breaks JSON
    (written / "meta.json").write_text("\n".join(text) + "\n}")
    with pytest.raises(RecordingError) as info:
        read_recording(written)
    assert info.value.line is not None and "not valid JSON" in str(info.value)


def test_extra_keys_and_files_are_ignored(written):
    rewrite_meta(
        written, lambda m: (m["motor"].update(cooling="water"), m.update(bench="B2"), m["segments"][0].update(note="x"))
    )
    (written / "notes.txt").write_text("operator notes")
    shutil.copy(written / "edges.csv", written / "edges_backup.csv")
    rec = read_recording(written)
    assert rec.meta_extra == {"bench": "B2"} and rec.segments[0].extra == {"note": "x"}


def test_samples_errors(written, recording):
    (written / "samples.csv").write_text("t_s,segment,i_a\n0.0,low,1.0\n0.1,low,x\n")
    assert "not a number" in refused(written, "samples.csv", 3, "i_a")
    (written / "samples.csv").write_text("t_s,i_a\n0.0,1.0\n")
    refused(written, "samples.csv", 1, "segment")


@pytest.mark.parametrize(
    "body, line, column, message",
    [
        ("0.0,low,1.0\n0.1,low,nan\n", 3, "i_a", "not finite"),
        ("0.0,low,1.0\n\n0.0,low,2.0\n", 4, "t_s", "times must increase"),
        ("0.0,low,1.0\n0.1,nowhere,2.0\n", 3, "segment", "unknown segment"),
        ("0.0,low,1.0\n0.1,low\n", 3, None, "expected 3 fields"),
        ("0.0,low,1.0\n0.1,low,2.0,9\n", 3, None, "expected 3 fields"),
    ],
)
def test_samples_errors_name_the_line_behind_the_fast_reader(written, body, line, column, message):
    """samples.csv is parsed in bulk first; a file the bulk parse doubts goes to the strict
    reader, so the error still names the line (blank lines counted) and the column."""
    (written / "samples.csv").write_text("t_s,segment,i_a\n" + body)
    assert message in refused(written, "samples.csv", line, column)


def test_a_large_samples_file_reads_exactly(tmp_path, recording):
    from dataclasses import replace

    n = 50_000
    rng = np.random.default_rng(0)
    samples = {
        "t_s": np.arange(n) * 5e-5,
        "segment": np.zeros(n, dtype=np.int64),
        "i_a": rng.normal(size=n),
        "u_b": rng.normal(size=n) * 40,
    }
    back = read_recording(write_recording(replace(recording, samples=samples), tmp_path / "big"))
    for k in samples:
        np.testing.assert_array_equal(back.samples[k], samples[k])


# --- files that must not eat the machine, and encodings -------------------------------------------


def one_line(path, file, line, column=None):
    """Refused with a RecordingError of one line naming file, line (and column)."""
    msg = refused(path, file, line, column)
    assert "\n" not in msg
    return msg


def sparse(path, size):
    with open(path, "wb") as fh:
        fh.truncate(size)  # a hole: costs no disk and no time to make


def test_a_2_gib_edges_file_is_refused_by_its_size(written):
    sparse(written / "edges.csv", 2 << 30)
    assert "above the reader's limit" in one_line(written, "edges.csv", None)


def test_a_2_gib_edges_file_streams_in_bounded_memory_when_the_cap_is_lifted(written):
    """The size cap is not what keeps memory bounded: with it lifted, the reader still holds
    one line at a time and refuses the first line of NULs (peak RSS growth of a fresh process)."""
    import subprocess
    import sys

    sparse(written / "edges.csv", 2 << 30)
    code = (
        "import resource, sys\nfrom hil.recording.errors import RecordingError\n"
        "from hil.recording.reader import read_recording\n"
        "peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024\nbefore = peak()\n"
        "try:\n    read_recording(sys.argv[1], max_table_bytes=1 << 40)\nexcept RecordingError as e:\n    print(e)\n"
        "print(peak() - before)\n"
    )
    out = subprocess.run([sys.executable, "-c", code, str(written)], capture_output=True, text=True, timeout=120)
    message, growth_mb = out.stdout.strip().splitlines()
    assert "edges.csv, line 1: line longer than 4096 bytes" in message, out.stdout + out.stderr
    assert int(growth_mb) < 20, f"peak RSS grew by {growth_mb} MB reading it"


def test_a_5_mb_field_is_refused_at_its_line(written):
    lines = (written / "edges.csv").read_text().splitlines(keepends=True)
    lines[4] = "1.0,A,rise," + "x" * (5 << 20) + "\n"
    (written / "edges.csv").write_text("".join(lines))
    assert "line longer than" in one_line(written, "edges.csv", 5)


def test_nul_bytes_and_broken_quotes_are_refused_at_their_line(written):
    lines = (written / "edges.csv").read_text().splitlines(keepends=True)
    (written / "edges.csv").write_text("".join(lines[:3] + ["0.1,A\0,rise,low\n"] + lines[3:]))
    assert "NUL byte" in one_line(written, "edges.csv", 4, "6 (byte)")
    (written / "edges.csv").write_text("".join(lines[:3] + ['0.1,"A,rise,low\n'] + lines[3:]))
    assert "not valid CSV" in one_line(written, "edges.csv", 4)


def test_invalid_utf8_is_named_by_line_and_column(written):
    data = (written / "edges.csv").read_bytes().split(b"\n")
    data[5] = data[5].replace(b",A,", b",\xff,", 1).replace(b",B,", b",\xff,", 1).replace(b",C,", b",\xff,", 1)
    (written / "edges.csv").write_bytes(b"\n".join(data))
    column = f"{data[5].index(bytes([0xFF])) + 1} (character)"
    assert "not valid UTF-8 (byte 0xFF)" in one_line(written, "edges.csv", 6, column)
    meta = (written / "meta.json").read_bytes().split(b"\n")
    meta[2] = meta[2] + b" \xc3\x28"
    (written / "meta.json").write_bytes(b"\n".join(meta))
    assert "not valid UTF-8" in one_line(written, "meta.json", 3, f"{len(meta[2]) - 1} (character)")


def test_deep_json_and_huge_numbers_are_refused_at_their_position(written):
    text = (written / "meta.json").read_text()
    (written / "meta.json").write_text(text[:-2] + ',\n "deep": ' + "[" * 100_000 + "]" * 100_000 + "\n}\n")
    assert "nested deeper than 64 levels" in one_line(
        written, "meta.json", text.count("\n") + 1, "73 (character)"
    )  # the object counts
    (written / "meta.json").write_text(text[:-2] + ',\n "big": ' + "9" * 5000 + "\n}\n")
    assert "a number longer than 100 characters" in one_line(
        written, "meta.json", text.count("\n") + 1, "9 (character)"
    )
    (written / "meta.json").write_text("x" * (2 << 20))
    assert "above the reader's limit" in one_line(written, "meta.json", None)


def test_a_byte_order_mark_is_accepted(written, recording):
    for name in ("meta.json", "edges.csv", "ground_truth.csv"):
        (written / name).write_bytes(b"\xef\xbb\xbf" + (written / name).read_bytes())
    back = read_recording(written)
    np.testing.assert_array_equal(back.t_s, recording.t_s)
    assert back.motor == recording.motor
