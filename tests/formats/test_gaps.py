"""Gap filling and segments (jaxpose.formats.gaps) against a frame-by-frame loop oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxpose.formats.gaps import DEFAULT_MAX_GAP, complete_segments, fill_gaps


def oracle(values: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """The same rules, one joint and one frame at a time."""
    out, filled = values.astype(np.float64).copy(), np.zeros(values.shape[:2], bool)
    N, J = values.shape[:2]
    for joint in range(J):
        frame = 0
        while frame < N:
            if np.isfinite(values[frame, joint]).all():
                frame += 1
                continue
            end = frame
            while end < N and not np.isfinite(values[end, joint]).all():
                end += 1
            if frame > 0 and end < N and end - frame <= max_gap:
                for inside in range(frame, end):
                    share = (inside - frame + 1) / (end - frame + 1)
                    out[inside, joint] = (1 - share) * values[frame - 1, joint] + share * values[end, joint]
                    filled[inside, joint] = True
            frame = end
    segments, start = [], None
    for frame in range(N + 1):
        complete = frame < N and np.isfinite(out[frame]).all()
        if complete and start is None:
            start = frame
        elif not complete and start is not None:
            segments.append((start, frame))
            start = None
    return out, filled, segments


@given(
    missing=st.lists(st.lists(st.booleans(), min_size=3, max_size=3), min_size=1, max_size=40),
    joints=st.integers(1, 3),
    max_gap=st.integers(0, 6),
    partial=st.booleans(),
)
def test_fill_gaps_matches_the_loop_oracle(missing, joints, max_gap, partial):
    missing = np.asarray(missing)[:, :joints]
    rng = np.random.default_rng(len(missing) * 7 + joints)
    values = rng.normal(0.0, 500.0, (len(missing), joints, 3)).astype(np.float32)
    values[missing, 1 if partial else slice(None)] = np.nan  # one NaN coordinate makes the cell missing
    expected, expected_filled, expected_segments = oracle(values, max_gap)

    result = fill_gaps(values, max_gap)
    assert result.values.dtype == values.dtype
    np.testing.assert_array_equal(result.filled, expected_filled)
    np.testing.assert_allclose(result.values[expected_filled], expected[expected_filled], rtol=1e-6, atol=1e-3)
    untouched = ~expected_filled
    np.testing.assert_array_equal(result.values[untouched], values[untouched])
    assert [tuple(segment) for segment in result.segments] == expected_segments
    for start, stop in result.segments:
        assert np.isfinite(result.values[start:stop]).all()  # no empty cell in any output file
    in_segment = np.zeros(len(values), bool)
    for start, stop in result.segments:
        in_segment[start:stop] = True
    assert (~np.isfinite(result.values[~in_segment]).all((1, 2))).all()  # what is left out has a hole
    assert result.dropped_frames == (~in_segment).sum()
    assert result.filled.any(-1).sum() == expected_filled.any(1).sum()


def test_pose2sim_limit_bridges_ten_frames_and_splits_at_eleven():
    values = np.arange(40, dtype=np.float64)[:, None, None] * np.ones((1, 2, 3))
    values[5:15, 0] = np.nan  # 10 frames: bridged, exactly on the line
    values[25:36, 1] = np.nan  # 11 frames: a split
    result = fill_gaps(values)
    assert DEFAULT_MAX_GAP == 10
    np.testing.assert_allclose(result.values[5:15, 0], np.arange(5, 15)[:, None] * np.ones(3))
    np.testing.assert_array_equal(result.segments, [[0, 25], [36, 40]])
    assert (result.filled.any(-1).sum(), result.dropped_frames) == (10, 11)


def test_gaps_at_the_ends_are_cut_not_extrapolated():
    values = np.ones((8, 1, 3))
    values[:2] = values[-1:] = np.nan
    result = fill_gaps(values, max_gap=5)
    assert not result.filled.any()
    np.testing.assert_array_equal(result.segments, [[2, 7]])


def test_complete_segments_and_bad_arguments():
    np.testing.assert_array_equal(complete_segments(np.array([True, True, False, True])), [[0, 2], [3, 4]])
    assert complete_segments(np.zeros(3, bool)).shape == (0, 2)
    with pytest.raises(ValueError, match=r"values must be \[N, J, D\] with N >= 1, got shape \(4, 3\)"):
        fill_gaps(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="max_gap must be a whole number of frames >= 0, got -1"):
        fill_gaps(np.zeros((4, 1, 3)), max_gap=-1)
