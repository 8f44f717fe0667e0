"""Frames without a value: short gaps bridged by linear interpolation, long ones split the recording (the
one gap filler of reconstruct's motion files and of predict's .trc files, `jaxpose.formats.pose_files`).

OpenSim cannot read a marker table with an empty cell, so a motion file must be gap-free.  A joint
missing for at most `max_gap` consecutive frames between two frames that have it is interpolated
linearly, as Pose2Sim does (its `interp_if_gap_smaller_than`, 10 frames by default).  A longer gap
is not invented: the recording is split into segments, the maximal runs of frames in which every
joint is known, one output file each.  Gaps at the start or end of the recording have only one side
to interpolate from; they are never filled, so they fall outside every segment.
"""

from __future__ import annotations

import dataclasses

import numpy as np

DEFAULT_MAX_GAP = 10  # frames, Pose2Sim's default interpolation limit


@dataclasses.dataclass(frozen=True)
class GapFilling:
    """The result of `fill_gaps` on N frames of J joints.

    values:   [N, J, D] the input with the bridged gaps filled (other missing cells left NaN).
    filled:   bool[N, J] the cells filled by interpolation.
    segments: i64[S, 2] (start, stop) frame ranges, half-open, of the maximal runs of complete frames.
    """

    values: np.ndarray
    filled: np.ndarray
    segments: np.ndarray

    @property
    def dropped_frames(self) -> int:
        """Frames in no segment: some joint is missing there even after filling."""
        return len(self.values) - int(np.sum(self.segments[:, 1] - self.segments[:, 0]))


def fill_gaps(values: np.ndarray, max_gap: int = DEFAULT_MAX_GAP) -> GapFilling:
    """Bridge gaps of at most `max_gap` frames and find the complete segments (module docstring).

    values: [N, J, D] (e.g. joints' world positions), a cell (frame, joint) missing where any of its
    D numbers is not finite.  Returns a `GapFilling` whose values keep the input's dtype.
    """
    values = np.asarray(values)
    if values.ndim != 3 or len(values) == 0:
        raise ValueError(f"fill_gaps: values must be [N, J, D] with N >= 1, got shape {values.shape}")
    if max_gap != int(max_gap) or max_gap < 0:
        raise ValueError(f"fill_gaps: max_gap must be a whole number of frames >= 0, got {max_gap!r}")
    out = values.copy()
    missing = ~np.isfinite(values).all(-1)
    filled = np.zeros_like(missing)
    for joint in np.flatnonzero(missing.any(0)):
        present = np.flatnonzero(~missing[:, joint])
        if len(present) < 2:
            continue
        # Each missing frame between two present ones lies in the gap after present[k]; fill it if
        # that gap is short enough.
        frames = np.flatnonzero(missing[:, joint])
        k = np.searchsorted(present, frames) - 1
        inside = (k >= 0) & (k < len(present) - 1)
        frames, k = frames[inside], k[inside]
        before, after = present[k], present[k + 1]
        bridged = after - before - 1 <= max_gap
        frames, before, after = frames[bridged], before[bridged], after[bridged]
        share = ((frames - before) / (after - before))[:, None]
        start, end = values[before, joint].astype(np.float64), values[after, joint].astype(np.float64)
        out[frames, joint] = (1.0 - share) * start + share * end
        filled[frames, joint] = True
    return GapFilling(out, filled, complete_segments(~(missing & ~filled).any(-1)))


def complete_segments(complete: np.ndarray) -> np.ndarray:
    """i64[S, 2]: the (start, stop) ranges, half-open, of the maximal runs of True in bool[N]."""
    edges = np.diff(np.concatenate([[0], np.asarray(complete, np.int8), [0]]))
    return np.stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)], -1).astype(np.int64)
