"""OpenSim marker files (`jaxpose.formats.trc`); predict's .trc / .csv outputs are tested in test_pose_files.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.trc import HEADER_KEYS, marker_name, read_trc, write_trc
import paths

TRC = paths.FORMATS / "trc"
needs_formats = pytest.mark.skipif(not TRC.is_dir(), reason=f"{TRC} (the real TRC samples) is absent")


def _data_rows(path: Path) -> list[list[str]]:
    """The data rows as tab-split text, the header and blank lines left out."""
    return [line.split("\t") for line in path.read_text().splitlines()[5:] if line.strip()]


# ---------------------------------------------------------------------------------------------
# The real samples, read as they are


@needs_formats
@pytest.mark.parametrize(
    "name, markers, rows, header_frames, rate, first_frame, first_time, names",
    [
        ("pose2sim_demo_BalancingTrial_0-100.trc", 21, 100, "100", 60.0, 1, 1 / 60, ("RHip", "RKnee", "LWrist")),
        ("opencap_walk_first50.trc", 63, 50, "222", 60.0, 1, 0.0, ("Neck", "RShoulder", None)),
        ("freemocap_dao_yin_interpolated_first50.trc", 19, 50, "388", 25.0, 0, 0.0, ("nose", "left_eye", None)),
    ],
)
def test_real_trc_files(name, markers, rows, header_frames, rate, first_frame, first_time, names):
    path = TRC / name
    data = read_trc(path)
    assert data.units == "m" and data.rate == rate and float(data.header["CameraRate"]) == rate
    assert list(data.header) == list(HEADER_KEYS) and data.header["NumMarkers"] == str(markers)
    assert data.header["NumFrames"] == header_frames  # not always the number of rows
    assert len(data.marker_names) == markers and data.markers.shape == (rows, markers, 3)
    assert data.marker_names[:2] == names[:2] and (names[2] is None or data.marker_names[-1] == names[2])
    assert data.frame_numbers.tolist() == list(range(first_frame, first_frame + rows))
    np.testing.assert_allclose(data.times[0], first_time, atol=1e-7)
    np.testing.assert_allclose(np.diff(data.times), 1 / rate, atol=1e-6)
    assert data.path_line.startswith("PathFileType") and np.isfinite(data.markers).all()
    assert np.abs(data.markers).max() < 10.0  # metres, a person in a room
    text = _data_rows(path)
    assert len(text) == rows
    np.testing.assert_array_equal(data.markers[0].ravel(), [float(v) for v in text[0][2 : 2 + 3 * markers]])
    np.testing.assert_array_equal(data.markers[-1, -1], [float(v) for v in text[-1][-3:]])


@needs_formats
def test_real_quirks_are_there():
    """The variations read_trc takes, as the samples have them."""
    opencap = (TRC / "opencap_walk_first50.trc").read_text().splitlines()
    assert opencap[0].startswith("PathFileType  4\t") and opencap[5] == ""  # two spaces; blank line
    pose2sim = (TRC / "pose2sim_demo_BalancingTrial_0-100.trc").read_text().splitlines()
    assert pose2sim[3].endswith("\t\t") and pose2sim[5].startswith("1\t")  # trailing tabs; no blank line
    freemocap = (TRC / "freemocap_dao_yin_interpolated_first50.trc").read_text().splitlines()
    assert freemocap[5] == "" and freemocap[6].startswith("0\t")  # Frame# from 0


# ---------------------------------------------------------------------------------------------
# Writing, and refusals


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    markers = rng.normal(0, 0.5, (6, 4, 3))
    markers[2] = np.nan  # a missing frame
    markers[4, 1, 2] = np.nan  # a missing value
    path = write_trc(tmp_path / "out" / "walk.trc", markers, ["Hip", "Neck/Nose", "R Knee", "LWrist"], 120.0)
    lines = path.read_text().split("\n")
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\twalk.trc"
    assert lines[1] == "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames"
    assert lines[2] == "120\t120\t6\t4\tm\t120\t1\t6"
    assert lines[3] == "Frame#\tTime\tHip\t\t\tNeck_Nose\t\t\tR_Knee\t\t\tLWrist\t\t"
    assert lines[4] == "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\tX4\tY4\tZ4"
    assert lines[7] == "3\t0.016667" + "\t" * 12 and all(len(line.split("\t")) == 14 for line in lines[3:-1])
    data = read_trc(path)
    np.testing.assert_allclose(data.markers, markers, atol=5e-7)
    assert np.isnan(data.markers[2]).all() and np.isnan(data.markers[4, 1, 2])
    assert data.frame_numbers.tolist() == [1, 2, 3, 4, 5, 6] and data.units == "m" and data.rate == 120.0
    np.testing.assert_allclose(data.times, np.arange(6) / 120.0, atol=1e-6)
    assert data.marker_names == ("Hip", "Neck_Nose", "R_Knee", "LWrist")
    mm = read_trc(write_trc(tmp_path / "mm.trc", markers * 1000, ["a", "b", "c", "d"], 30, units="mm", first_frame=0))
    np.testing.assert_allclose(mm.markers, markers * 1000, atol=5e-4)
    assert mm.frame_numbers[0] == 0 and mm.units == "mm"


def test_marker_names():
    assert marker_name("Neck/Nose") == "Neck_Nose" and marker_name("r.ASIS_study") == "r.ASIS_study"


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda lines: ["Hello"] + lines[1:], "line 1 starting with PathFileType"),
        (lambda lines: lines[:2] + ["60\t60\t2\t3\tm"] + lines[3:], r"3 marker names on line 4 \(NumMarkers\)"),
        (lambda lines: lines[:2] + ["sixty\t60\t2\t2\tm\t60\t1\t2"] + lines[3:], "numbers for DataRate"),
        (lambda lines: lines[:3] + ["Time\t" + lines[3]] + lines[4:], "line 4 starting with Frame#, Time"),
        (lambda lines: lines[:5] + [lines[5].replace("0.5", "abc", 1)] + lines[6:], r"numbers or empty .*line 6"),
        (lambda lines: lines[:5] + [lines[5] + "\t9"] + lines[6:], r"8 fields per data row .*9 on line 6"),
        (lambda lines: lines[:3], "5 header lines"),
    ],
)
def test_trc_refusals(tmp_path, change, message):
    markers = np.full((2, 2, 3), 0.5)
    lines = write_trc(tmp_path / "a.trc", markers, ["a", "b"], 60).read_text().splitlines()
    (tmp_path / "b.trc").write_text("\n".join(change(lines)) + "\n")
    with pytest.raises(DataFormatError, match=message):
        read_trc(tmp_path / "b.trc")


def test_short_rows_are_padded_with_missing_values(tmp_path):
    lines = write_trc(tmp_path / "a.trc", np.ones((2, 2, 3)), ["a", "b"], 60).read_text().splitlines()
    lines[5] = "\t".join(lines[5].split("\t")[:5])  # a writer that drops trailing empty fields
    (tmp_path / "a.trc").write_text("\r\n".join(lines) + "\r\n")  # and writes CRLF
    data = read_trc(tmp_path / "a.trc")
    assert data.markers[0, 0].tolist() == [1, 1, 1] and np.isnan(data.markers[0, 1]).all()
