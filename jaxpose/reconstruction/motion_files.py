"""A recording's reconstructed motion in the files people open next: OpenSim's .trc .csv, .npz.

Per recording (RecordingMotion, `jaxpose.reconstruction.recording`), in the output folder:
- ``<recording>.trc``: OpenSim markers in Pose2Sim's header and layout (`jaxpose.formats.trc`), metres, Y up
  (OpenSim's convention): the calibration's world turned by the rotation `opensim_rotation` gives of
  the --up-axis, stated in line 1.  Frame# is the project's frame number and Time = frame / fps (as
  Pose2Sim writes Time = Frame# / rate), so the segments of one recording keep their times.  One file
  per segment, the maximal runs of complete frames (no empty cell: OpenSim cannot read one): the
  first ``<recording>.trc``, the later ``<recording>.seg<S>.trc``.  With ``c3d``, a ``.c3d`` beside each
  (`jaxpose.formats.c3d`, the optional ezc3d): the same markers and axes in millimetres, C3D's usual unit.
- ``<recording>.csv`` and ``<recording>.npz``: every frame of the recording, in the calibration's world
  frame in millimetres, with each joint's provenance (triangulated / fused / lifted / interpolated /
  none), uncertainty (the posterior RMS error, mm: the trajectory's, or with --no-smoothing the fusion's,
  empty where not fused) and agreeing views.
"""

from __future__ import annotations

import csv
import glob
import pathlib
from collections.abc import Sequence

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.formats import trc
from jaxpose.formats.c3d import write_c3d
from jaxpose.formats.outputs import atomic_output
from jaxpose.reconstruction.fusion import Provenance
from jaxpose.reconstruction.recording import RecordingMotion

UP_AXES = ("auto", "+x", "-x", "+y", "-y", "+z", "-z")
MIN_UP_AGREEMENT = np.cos(np.radians(30.0))
"""--up-axis auto: the cameras' mean up direction must lie within 30 degrees of a world axis."""
PROVENANCE_NAMES = tuple(p.name.lower() for p in sorted(Provenance))  # indexed by the Provenance value
_AXIS_NAMES = "xyz"


def camera_up_axis(cameras: Cameras) -> str:
    """The world axis the cameras' image "up" points along, on average ("+z" for Human3.6M): an upright
    camera's up, -y of its axes, is -R[1] in world axes.  Refused when no axis is within 30 degrees."""
    up = -np.asarray(cameras.R, np.float64).reshape(-1, 3, 3)[:, 1].mean(0)
    up /= np.linalg.norm(up)
    axis = int(np.abs(up).argmax())
    if abs(up[axis]) < MIN_UP_AGREEMENT:
        raise ValueError(
            f"--up-axis auto: the cameras' mean up direction {np.round(up, 2).tolist()} lies along no world axis"
            " (within 30 degrees); name the calibration's up axis with --up-axis (e.g. +z)"
        )
    return ("+" if up[axis] > 0 else "-") + _AXIS_NAMES[axis]


def opensim_rotation(up_axis: str) -> np.ndarray:
    """f64[3, 3] the rotation from the calibration's world axes to OpenSim's (Y up): Y = the up axis,
    X and Z the next axes in cyclic order, as Pose2Sim turns a Z-up world (X = y, Y = z, Z = x); a
    negative up axis turned half around X besides."""
    if up_axis not in UP_AXES[1:]:
        raise ValueError(f"--up-axis: expected one of {UP_AXES[1:]}, got {up_axis!r}")
    index = _AXIS_NAMES.index(up_axis[1])
    rotation = np.zeros((3, 3))
    for row, source in enumerate(((index + 2) % 3, index, (index + 1) % 3)):
        rotation[row, source] = 1.0
    return rotation if up_axis[0] == "+" else np.diag([1.0, -1.0, -1.0]) @ rotation


def rotation_note(rotation: np.ndarray, up_axis: str) -> str:
    """Line 1's statement of the axes, e.g. "(jaxpose: X=y Y=z Z=x of the calibration's world, +z up)"."""
    terms = []
    for name, row in zip("XYZ", rotation):
        source = int(np.abs(row).argmax())
        terms.append(f"{name}={'-' if row[source] < 0 else ''}{_AXIS_NAMES[source]}")
    return f"(jaxpose: {' '.join(terms)} of the calibration's world, {up_axis} up)"


def segment_paths(folder: pathlib.Path, name: str, count: int, suffix: str) -> list[pathlib.Path]:
    """The file of each of `count` segments: <name><suffix>, then <name>.seg<S><suffix>."""
    return [folder / (name + (f".seg{index}" if index else "") + suffix) for index in range(count)]


def colliding_names(names: Sequence[str]) -> tuple[str, str] | None:
    """Two recordings whose files could be one (`walking01`'s second segment and `walking01.seg1`), or None."""
    known = set(names)
    for name in names:
        for marker in (".seg", ".person"):  # a later segment's or a person's files
            stem, _, number = name.rpartition(marker)
            if stem in known and number.split(".")[0].isdigit():
                return stem, name
    return None


def existing_outputs(folder: pathlib.Path, name: str) -> list[pathlib.Path]:
    """The files of recording `name` already in `folder`: what this command would write, or did (its people's
    ``<name>.person<k>.*`` too)."""
    found = [folder / f"{name}{suffix}" for suffix in (".csv", ".npz", ".trc", ".c3d")]
    segments = [path for suffix in (".trc", ".c3d") for path in sorted(folder.glob(f"{glob.escape(name)}.seg*{suffix}"))]
    people = [path for suffix in (".csv", ".npz", ".trc", ".c3d") for path in sorted(folder.glob(f"{glob.escape(name)}.person*{suffix}"))
              if path.name[len(name) + len(".person"):].split(".")[0].isdigit()]  # fmt: skip
    return [path for path in found if path.exists()] + segments + people


def write_motion(
    folder: pathlib.Path, motion: RecordingMotion, joint_names: Sequence[str], fps: float, up_axis: str, c3d: bool = False
) -> list[pathlib.Path]:
    """The recording's files (the module docstring); returns their paths, the .csv and .npz first."""
    rotation = opensim_rotation(up_axis)
    written = [
        _write_csv(folder / f"{motion.name}.csv", motion, joint_names, fps),
        _write_npz(folder / f"{motion.name}.npz", motion, joint_names, fps, rotation, up_axis),
    ]
    metres = motion.points.astype(np.float64) @ rotation.T / 1000.0
    note = rotation_note(rotation, up_axis)
    for path, (start, stop) in zip(segment_paths(folder, motion.name, len(motion.segments), ".trc"), motion.segments):
        frame = int(motion.frames[start])
        written.append(
            trc.write_trc(path, metres[start:stop], joint_names, fps, units="m", path_note=note, first_frame=frame, time_zero_frame=0)
        )
    if c3d:
        for path, (start, stop) in zip(segment_paths(folder, motion.name, len(motion.segments), ".c3d"), motion.segments):
            written.append(write_c3d(path, metres[start:stop] * 1000.0, joint_names, fps, "mm", int(motion.frames[start])))
    return written


def _segment_of_frames(motion: RecordingMotion) -> np.ndarray:
    """i64[F]: each frame's segment, -1 outside every segment."""
    index = np.full(len(motion.frames), -1, np.int64)
    for number, (start, stop) in enumerate(motion.segments):
        index[start:stop] = number
    return index


def _write_npz(path, motion: RecordingMotion, joint_names, fps: float, rotation: np.ndarray, up_axis: str) -> pathlib.Path:
    """Keys: points_mm [F, J, 3], provenance [F, J] (codes of provenance_names), uncertainty_mm [F, J], views
    [F, J], frame [F], time_s [F], seen [F] (a camera sees the person), segment [F] (-1: in none),
    segment_frames [S, 2] (first frame, frame after the last), joint_names, trc_rotation [3, 3] (the
    .trc's metres are trc_rotation @ points_mm / 1000), up_axis, fps."""
    first = motion.frames[motion.segments[:, 0]]
    segment_frames = np.stack([first, first + motion.segments[:, 1] - motion.segments[:, 0]], -1)
    with atomic_output(path) as temporary:
        np.savez(
            temporary, points_mm=motion.points, provenance=motion.provenance, provenance_names=np.asarray(PROVENANCE_NAMES),
            uncertainty_mm=motion.uncertainty, views=motion.views, frame=motion.frames, time_s=motion.frames / fps,
            seen=motion.seen, segment=_segment_of_frames(motion), segment_frames=segment_frames,
            joint_names=np.asarray(joint_names), trc_rotation=rotation, up_axis=np.asarray(up_axis), fps=np.float64(fps),
        )  # fmt: skip
    return path


def _write_csv(path, motion: RecordingMotion, joint_names, fps: float) -> pathlib.Path:
    header = ["frame", "time_s", "segment"]
    for joint in joint_names:
        header += [f"{joint}_{axis}_mm" for axis in "xyz"] + [f"{joint}_provenance", f"{joint}_uncertainty_mm", f"{joint}_views"]
    points = np.round(motion.points.astype(np.float64), 2)  # 0.01 mm: far below any error
    uncertainty = np.round(motion.uncertainty.astype(np.float64), 2)
    segment = _segment_of_frames(motion)
    with atomic_output(path) as temporary, open(temporary, "w", newline="") as file:
        writer = csv.writer(file, lineterminator="\n")
        writer.writerow(header)
        for row, frame in enumerate(motion.frames.tolist()):
            fields = [frame, round(frame / fps, 6), segment[row] if segment[row] >= 0 else ""]
            for joint in range(len(joint_names)):
                xyz = points[row, joint]
                fields += xyz.tolist() if np.isfinite(xyz).all() else ["", "", ""]
                spread = uncertainty[row, joint]
                fields += [PROVENANCE_NAMES[motion.provenance[row, joint]], spread if np.isfinite(spread) else "", int(motion.views[row, joint])]
            writer.writerow(fields)
    return path
