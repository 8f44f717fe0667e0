"""Following people through the frames of one camera: which detected 2D pose is which person.

`follow_people` gives every pose a track number, a person followed from frame to frame.  How it decides:
the frames are taken in order.  Each open track predicts where its person's keypoints lie in the frame
at hand: its last pose, moved by its velocity times the frames elapsed (the velocity is the median
displacement per frame of the keypoints detected in its last two poses; none yet: where it was).  The cost of giving a pose
to a track is the median, over the joints detected in both, of the distance between the pose's keypoint
and the predicted one, divided by the person's size (the larger side of the box around the detected
keypoints of the track's last pose or of the pose, whichever is larger, at least `MIN_SIZE_PX`).  Pairs
are taken greedily, the cheapest first, while the cost is at most `gate`, each track and each pose once.
A pose left over starts a new track; a track not seen for more than `max_gap` frames is closed, so a
person who comes back later is a new track.  A pose without any detected keypoint is followed by none
(track -1).  Tracks are numbered in order of first appearance (frame, then the pose's place in it).

Pure numpy; a few operations per frame on arrays of the people in it and the open tracks.
"""

from __future__ import annotations

import dataclasses

import numpy as np

DEFAULT_GATE = 0.5
"""The largest cost (median keypoint distance / the person's size) at which a pose continues a track."""
DEFAULT_TRACK_GAP = 30
"""Frames a track may go unseen and still be continued."""
MIN_SIZE_PX = 10.0
"""The smallest size a person is given, so that one or two detected keypoints do not make every distance huge."""
NOT_FOLLOWED = -1


@dataclasses.dataclass
class _Track:
    keypoints: np.ndarray  # f[J, 2] the last pose
    valid: np.ndarray  # bool[J]
    frame: int  # where it was last seen
    velocity: np.ndarray  # f[2] px per frame

    def continue_with(self, keypoints: np.ndarray, valid: np.ndarray, frame: int) -> None:
        both = self.valid & valid  # the median over shared joints: a joint set that changes is no motion
        moved = np.median(keypoints[both] - self.keypoints[both], axis=0) if both.any() else np.zeros(2)
        self.velocity = moved / (frame - self.frame)
        self.keypoints, self.valid, self.frame = keypoints, valid, frame


def _size(keypoints: np.ndarray, valid: np.ndarray) -> float:
    points = keypoints[valid]
    return max(float(np.ptp(points, axis=0).max()), MIN_SIZE_PX)


def _costs(tracks: list[_Track], frame: int, keypoints: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """f[T, P] the cost of each open track for each pose of `frame` (inf where no joint is detected in both)."""
    costs = np.full((len(tracks), len(keypoints)), np.inf)
    sizes = [_size(k, v) for k, v in zip(keypoints, valid)]
    for t, track in enumerate(tracks):
        predicted = track.keypoints + track.velocity * (frame - track.frame)
        both = track.valid & valid  # [P, J]
        distance = np.linalg.norm(keypoints - predicted, axis=-1)  # [P, J]
        for p in np.flatnonzero(both.any(1)):
            scale = max(_size(track.keypoints, track.valid), sizes[p])
            costs[t, p] = np.median(distance[p, both[p]]) / scale
    return costs


def follow_people(
    frames: np.ndarray, keypoints: np.ndarray, valid: np.ndarray, gate: float = DEFAULT_GATE,
    max_gap: int = DEFAULT_TRACK_GAP,
) -> np.ndarray:  # fmt: skip
    """int64[N] the track of each pose (`NOT_FOLLOWED` for a pose without a detected keypoint).

    frames int[N] the frame number of each pose (any order; several poses per frame), keypoints f[N, J, 2]
    pixels, valid bool[N, J] the detected keypoints.  See the module docstring for how a pose is matched.
    """
    frames = np.asarray(frames, np.int64)
    keypoints = np.asarray(keypoints, np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(keypoints).all(-1)
    if not gate > 0 or max_gap < 0:
        raise ValueError(f"follow_people: gate must be > 0 and max_gap >= 0, got {gate} and {max_gap}")
    tracks: list[_Track] = []
    open_tracks: list[int] = []
    assigned = np.full(len(frames), NOT_FOLLOWED, np.int64)
    order = np.argsort(frames, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(frames[order]) != 0])
    for rows in np.split(order, starts[1:]):
        rows = rows[valid[rows].any(1)]
        if not len(rows):
            continue
        frame = int(frames[rows[0]])
        open_tracks = [t for t in open_tracks if frame - tracks[t].frame <= max_gap + 1]
        costs = _costs([tracks[t] for t in open_tracks], frame, keypoints[rows], valid[rows])
        taken = np.full(len(rows), NOT_FOLLOWED, np.int64)
        used = set()
        for t, p in zip(*np.unravel_index(np.argsort(costs, axis=None, kind="stable"), costs.shape)):
            if costs[t, p] > gate:
                break
            if t not in used and taken[p] == NOT_FOLLOWED:
                used.add(t)
                taken[p] = open_tracks[t]
        for p, row in enumerate(rows):
            if taken[p] == NOT_FOLLOWED:
                taken[p] = len(tracks)
                tracks.append(_Track(keypoints[row], valid[row], frame, np.zeros(2)))
                open_tracks.append(int(taken[p]))
            else:
                tracks[taken[p]].continue_with(keypoints[row], valid[row], frame)
        assigned[rows] = taken
    return assigned
