"""Lifted 3D poses out to a file (`jaxpose.predict`'s output), on the input's time axis.

Every pose keeps its input frame (an OpenPose file's index, a COCO image id's number:
`jaxpose.formats.detection_file`), its time in seconds, Time = (frame - first frame) / fps, where the
first frame is the input's first (so every file of one input shares one time axis), and its person
(a track of `jaxpose.serving.tracking`; -1 for a pose followed by none).  By suffix; poses are root-relative, in
the camera frame (x right, y down, z forward), in mm unless said otherwise:
- ``.json``: a list, a record per input pose in input order, {"image_id", "frame", "time_s", "person",
  "pose3d_mm": [[x, y, z] * J] or null, "joint_names"};
- ``.npz``: ``pose3d_mm`` f32[N, J, 3] (NaN rows), ``valid`` [N], ``image_id`` [N], ``frame`` int64[N],
  ``time_s`` f64[N], ``person`` int64[N], ``joint_names`` [J];
- ``.csv``: a header row ``image_id,frame,time_s,person,<joint>_x_mm,<joint>_y_mm,<joint>_z_mm,...``,
  then a row per pose, with empty cells for a pose that could not be lifted;
- ``.trc`` (OpenSim markers, `jaxpose.formats.trc`): a file per person and continuous segment, a row per
  frame, Frame# the input's frame and Time as above, a marker per joint (``/`` becomes ``_``), Units m.
  A frame where the person has no lifted pose is filled by linear interpolation between the lifted frames
  around it when the gap is at most `max_gap` frames (`jaxpose.formats.gaps`); a longer gap ends the segment, so that no TRC holds
  an empty cell (OpenSim stops at one).  One segment in all is written to the path given; otherwise
  ``<stem>.person<P>.trc`` holds person P's first segment and ``<stem>.person<P>.seg<S>.trc`` its later
  ones (S = 1, 2, ...).  The axes are OpenSim's for a subject facing the camera (X forward, Y up, Z to
  the subject's right): X = -z, Y = -y, Z = -x of the camera frame (a rotation of the camera axes), as
  line 1 of each file says after the file name.
Every file is written to a temporary name and renamed into place (`jaxpose.formats.outputs`).
"""

from __future__ import annotations

import csv
import dataclasses
import glob
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats import trc
from jaxpose.formats.gaps import DEFAULT_MAX_GAP, fill_gaps
from jaxpose.formats.outputs import atomic_output

SUFFIXES = (".json", ".npz", ".csv", ".trc")
# The .trc axes from the camera frame's (x right, y down, z forward): X = -z, Y = -y, Z = -x, a rotation
# (determinant +1) to OpenSim's X forward, Y up, Z right for a subject who faces the camera.
TRC_AXES = np.array([[0, 0, -1], [0, -1, 0], [-1, 0, 0]], np.float32)
TRC_NOTE = "(jaxpose: root-relative; X=-z Y=-y Z=-x of the camera's x right y down z forward)"


@dataclasses.dataclass(frozen=True)
class LiftedPoses:
    """The poses to write, a row per input pose, with where each sits in time and whose it is."""

    poses: np.ndarray
    """f32[N, J, 3] mm, root-relative, camera frame; NaN rows were not lifted."""
    joint_names: Sequence[str]
    image_ids: list[Any]
    frames: np.ndarray
    """int64[N] the input frame of each pose."""
    persons: np.ndarray
    """int64[N] the person (track) of each pose, negative for none."""
    first_frame: int
    """The input's first frame: Time 0."""
    fps: float

    @property
    def times(self) -> np.ndarray:
        """float64[N] seconds: (frame - first frame) / fps."""
        return (self.frames - self.first_frame) / self.fps

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.poses).all((1, 2))


@dataclasses.dataclass(frozen=True)
class Segment:
    """A person's run of frames in one .trc: every frame from the first to the last, filled."""

    person: int
    index: int
    """0 for the person's first segment, then 1, 2, ..."""
    frames: np.ndarray
    """int64[F] consecutive frame numbers."""
    poses: np.ndarray
    """f64[F, J, 3] mm, camera frame, all finite."""
    filled: int
    """Frames interpolated (no lifted pose of the person in them)."""


def write_poses(path: Path, lifted: LiftedPoses) -> None:
    """`lifted` as a .json, .npz or .csv file by the suffix of `path` (the module docstring); .trc: `write_trc_files`."""
    if path.suffix not in (".json", ".npz", ".csv"):
        raise ValueError(f"{path}: write_poses writes .json, .npz or .csv (a .trc goes through write_trc_files)")
    path.parent.mkdir(parents=True, exist_ok=True)
    valid, times = lifted.valid, lifted.times
    if path.suffix == ".npz":
        with atomic_output(path) as temporary:
            np.savez(temporary, pose3d_mm=lifted.poses, valid=valid, image_id=np.asarray(lifted.image_ids),
                     frame=lifted.frames, time_s=times, person=lifted.persons,
                     joint_names=np.asarray(lifted.joint_names))  # fmt: skip
        return
    # 0.01 mm is far below any pose error; float64 first so the text holds no float32 round-off digits.
    rounded = np.round(lifted.poses.astype(np.float64), 2)
    columns = zip(lifted.image_ids, lifted.frames.tolist(), np.round(times, 6).tolist(), lifted.persons.tolist())
    if path.suffix == ".csv":
        header = ["image_id", "frame", "time_s", "person"]
        header += [f"{joint}_{axis}_mm" for joint in lifted.joint_names for axis in "xyz"]
        with atomic_output(path) as temporary, open(temporary, "w", newline="") as file:
            writer = csv.writer(file, lineterminator="\n")
            writer.writerow(header)
            for (image_id, frame, time, person), pose, ok in zip(columns, rounded, valid):
                writer.writerow([image_id, frame, time, person, *(pose.ravel().tolist() if ok else [""] * pose.size)])
        return
    records = [
        {"image_id": image_id, "frame": frame, "time_s": time, "person": person,
         "pose3d_mm": pose.tolist() if ok else None, "joint_names": list(lifted.joint_names)}
        for (image_id, frame, time, person), pose, ok in zip(columns, rounded, valid)
    ]  # fmt: skip
    with atomic_output(path) as temporary:
        temporary.write_text(json.dumps(records))


def segments(lifted: LiftedPoses, max_gap: int = DEFAULT_MAX_GAP) -> list[Segment]:
    """Each person's lifted poses as continuous segments, person by person (`jaxpose.formats.gaps.fill_gaps`):
    a gap of at most `max_gap` frames without a lifted pose is filled by linear interpolation, a longer one
    starts a new segment."""
    if max_gap < 0:
        raise ValueError(f"max_gap must be >= 0, got {max_gap}")
    found = []
    for person in np.unique(lifted.persons[lifted.persons >= 0]).tolist():
        rows = np.flatnonzero((lifted.persons == person) & lifted.valid)
        if not len(rows):  # never lifted: no segment
            continue
        rows = rows[np.argsort(lifted.frames[rows], kind="stable")]
        frames = lifted.frames[rows]
        if (np.diff(frames) == 0).any():
            frame = int(frames[np.flatnonzero(np.diff(frames) == 0)[0]])
            raise ValueError(f"person {person} has two poses in frame {frame}: a person is in a frame once")
        # Filled on a time axis where every gap longer than max_gap is cut to max_gap + 1 frames (still too
        # long to bridge), so that memory follows the poses, not the frame numbers; a segment holds no cut gap.
        position = np.concatenate([[0], np.cumsum(np.minimum(np.diff(frames), max_gap + 2))])
        poses = np.full((position[-1] + 1, *lifted.poses.shape[1:]), np.nan)
        poses[position] = lifted.poses[rows]
        filling = fill_gaps(poses, max_gap)
        for index, (start, stop) in enumerate(filling.segments.tolist()):
            span = frames[np.searchsorted(position, start)] + np.arange(stop - start)
            found.append(Segment(person, index, span, filling.values[start:stop], int(filling.filled[start:stop].any(-1).sum())))
    return found


def trc_paths(path: Path, found: Sequence[Segment]) -> list[Path]:
    """The file of each segment: `path` itself where there is one, else <stem>.person<P>[.seg<S>].trc."""
    if len(found) == 1:
        return [path]
    return [path.with_name(f"{path.stem}.person{s.person}" + (f".seg{s.index}" if s.index else "") + ".trc") for s in found]


def trc_family(path: Path) -> list[Path]:
    """The existing files a .trc output named `path` could write: `path` and <stem>.person*.trc beside it."""
    pattern = glob.escape(path.stem) + ".person*.trc"
    return sorted({*([path] if path.exists() else []), *path.parent.glob(pattern)})


def write_trc_files(path: Path, lifted: LiftedPoses, max_gap: int = DEFAULT_MAX_GAP) -> list[tuple[Path, Segment]]:
    """A TRC file per person and segment (`segments`, `trc_paths`); returns what was written."""
    found = segments(lifted, max_gap)
    names = [trc.marker_name(name) for name in lifted.joint_names]
    written = []
    for target, segment in zip(trc_paths(path, found), found):
        metres = segment.poses @ TRC_AXES.T.astype(np.float64) / 1000.0
        trc.write_trc(target, metres, names, lifted.fps, units="m", path_note=TRC_NOTE, first_frame=int(segment.frames[0]),
                      time_zero_frame=lifted.first_frame)  # fmt: skip
        written.append((target, segment))
    return written


def trc_summary(
    written: list[tuple[Path, Segment]], lifted: LiftedPoses, max_gap: int, earlier: Sequence[Path] = (), listed: int = 10
) -> str:
    """What `write_trc_files` wrote: files, people, frames filled and segments, a line per file (the first
    `listed`), and the files of `earlier` (`trc_family` before writing) that it did not write."""
    people = np.unique(lifted.persons[lifted.persons >= 0])
    with_file = {segment.person for _, segment in written}
    split = sum(1 for _, segment in written if segment.index == 1)
    lines = [
        f"wrote {len(written)} .trc files for {len(with_file)} of {len(people)} people followed, Time = (frame -"
        f" {lifted.first_frame}) / {lifted.fps:g} fps: {sum(s.filled for _, s in written)} frames filled by"
        f" interpolation (gaps of up to {max_gap} frames), {len(written)} segments"
        + (f", {split} {'person' if split == 1 else 'people'} split at longer gaps" if split else "")
        + (f"; {len(people) - len(with_file)} with no lifted pose have no file" if len(people) > len(with_file) else "")
    ]
    for path, segment in written[:listed]:
        lines.append(f"  person {segment.person}: frames {segment.frames[0]}-{segment.frames[-1]} ({len(segment.frames)}"
                     f" rows, {segment.filled} filled) -> {path}")  # fmt: skip
    if len(written) > listed:
        lines.append(f"  ... and {len(written) - listed} more")
    stale = sorted(set(earlier) - {path for path, _ in written})
    if stale:
        lines.append(f"  files of an earlier run not written now, left as they were: {', '.join(map(str, stale))}")
    return "\n".join(lines)
