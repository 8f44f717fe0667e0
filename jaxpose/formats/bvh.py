"""Biovision hierarchy files (``.bvh``, motion capture): the skeleton, its motion and forward kinematics.

A BVH file is text in two parts::

    HIERARCHY
    ROOT Hips
    {
        OFFSET 0 0 0
        CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
        JOINT LeftUpLeg
        {
            OFFSET 1.65 -1.80 0.62
            CHANNELS 3 Zrotation Yrotation Xrotation
            End Site
            {
                OFFSET 0 -1 0
            }
        }
    }
    MOTION
    Frames: 174
    Frame Time: .0083333
    <one line per frame: every joint's channel values, in the order the hierarchy lists them>

A joint's OFFSET is its origin in its parent's frame (file units); its rotation channels are Euler angles in
degrees, composed in the order listed as intrinsic rotations (``Zrotation Yrotation Xrotation`` is
R = Rz @ Ry @ Rx), and a point p in the joint's frame is at ``parent_rotation @ (OFFSET + translation + R @ p)``
in its parent's.  Position channels (the root's, usually) translate the joint in its parent's frame.  An
``End Site`` is a point with an offset and no channels (a toe tip, the head's top); `read_bvh` keeps it as a
joint named ``<parent>_End``.  The file's units are its own: the caller gives their size in mm to
`world_joints` (CMU's files: 1 unit = 1/0.45 inch = 56.444 mm, `CMU_MM_PER_UNIT`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from jaxpose.formats.errors import DataFormatError

CMU_MM_PER_UNIT = 25.4 / 0.45
"""The size of one unit of the CMU motion capture database's BVH files in mm (1/0.45 inch)."""
ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")
POSITIONS = ("Xposition", "Yposition", "Zposition")


@dataclasses.dataclass(frozen=True)
class BvhFile:
    """The contents of a BVH file, joints in the order the hierarchy lists them (End Sites included)."""

    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    """Each joint's parent's index, -1 for the root; a parent comes before its children."""
    offsets: np.ndarray
    """float64[J, 3] each joint's origin in its parent's frame, file units."""
    channels: tuple[tuple[str, ...], ...]
    """Each joint's channel names in the file's order (empty for an End Site)."""
    frame_time: float
    """Seconds between frames (``Frame Time``)."""
    motion: np.ndarray
    """float64[F, C] the MOTION lines: every joint's channel values in hierarchy order (degrees, file units)."""

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def frame_count(self) -> int:
        return len(self.motion)

    def index(self, name: str) -> int:
        return self.joint_names.index(name)


def _rotation(axis: str, degrees: np.ndarray) -> np.ndarray:
    """float64[F, 3, 3] rotations by `degrees` f[F] about axis ``X``, ``Y`` or ``Z``."""
    radians = np.deg2rad(degrees)
    cos, sin = np.cos(radians), np.sin(radians)
    one, zero = np.ones_like(radians), np.zeros_like(radians)
    rows = {
        "X": ((one, zero, zero), (zero, cos, -sin), (zero, sin, cos)),
        "Y": ((cos, zero, sin), (zero, one, zero), (-sin, zero, cos)),
        "Z": ((cos, -sin, zero), (sin, cos, zero), (zero, zero, one)),
    }[axis]
    return np.stack([np.stack(row, -1) for row in rows], -2)


def forward_kinematics(bvh: BvhFile, mm_per_unit: float, frames: slice | np.ndarray = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """(float64[F, J, 3] every joint's position in the file's world frame in mm, float64[F, J, 3, 3] its
    world rotation: a point p in the joint's frame is at position + rotation @ p) for the chosen `frames`.

    A joint's world rotation is its parent's times its own channels' rotations composed in the file's
    order; its world position is the parent's plus the parent's world rotation applied to (OFFSET + its
    position channels).  The axes are the file's (CMU: Y up, in the mocap studio's frame).
    """
    motion = bvh.motion[frames]
    count = len(motion)
    rotations = np.empty((count, len(bvh.joint_names), 3, 3))
    positions = np.empty((count, len(bvh.joint_names), 3))
    column = 0
    for joint, (parent, names) in enumerate(zip(bvh.parents, bvh.channels)):
        local = np.broadcast_to(np.eye(3), (count, 3, 3))
        translation = np.broadcast_to(bvh.offsets[joint], (count, 3)).copy()
        for name in names:
            values = motion[:, column]
            column += 1
            if name in POSITIONS:
                translation[:, POSITIONS.index(name)] += values
            else:
                local = local @ _rotation(name[0], values)  # intrinsic: the first listed is outermost
        if parent < 0:
            rotations[:, joint], positions[:, joint] = local, translation
        else:
            rotations[:, joint] = rotations[:, parent] @ local
            positions[:, joint] = positions[:, parent] + np.einsum("fij,fj->fi", rotations[:, parent], translation)
    return positions * mm_per_unit, rotations


def world_joints(bvh: BvhFile, mm_per_unit: float, frames: slice | np.ndarray = slice(None)) -> np.ndarray:
    """float64[F, J, 3] every joint's position in the file's world frame, in mm (`forward_kinematics`)."""
    return forward_kinematics(bvh, mm_per_unit, frames)[0]


def _fail(path: Path, expected: str, found: str, line: int | None = None) -> DataFormatError:
    return DataFormatError(path, expected, f"{found} on line {line}" if line is not None else found)


def read_bvh(path: str | Path) -> BvhFile:
    """Read a BVH file; a malformed one raises `DataFormatError` naming the line and field at fault."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as error:
        raise DataFormatError(path, "a readable BVH file", f"{type(error).__name__}: {error.strerror}") from None
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    stack: list[int] = []  # the joints whose braces are open
    pending: int | None = None  # a joint declared, its "{" not yet read
    end_sites: set[int] = set()
    number = 0
    first = next((i for i, line in enumerate(lines) if line.strip()), None)
    if first is None or lines[first].strip() != "HIERARCHY":
        raise _fail(path, "a BVH file starting with HIERARCHY", repr(lines[first][:40]) if first is not None else "an empty file")
    motion_line = None
    for number in range(first + 2, len(lines) + 1):
        words = lines[number - 1].split()
        if not words:
            continue
        key = words[0]
        if key in ("ROOT", "JOINT") or (key == "End" and words[1:2] == ["Site"]):
            if (key == "ROOT") != (not stack) or pending is not None:
                raise _fail(path, "one ROOT, JOINT and End Site only inside a joint's braces", key, number)
            if key == "End":
                end_sites.add(len(names))
                names.append(f"{names[stack[-1]]}_End")
            elif len(words) != 2:
                raise _fail(path, f"{key} followed by one joint name", repr(" ".join(words)), number)
            else:
                names.append(words[1])
            parents.append(stack[-1] if stack else -1)
            offsets.append([])
            channels.append(())
            pending = len(names) - 1
        elif key == "{":
            if pending is None:
                raise _fail(path, "{ after a ROOT, JOINT or End Site line", "{", number)
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                raise _fail(path, "a } closing an open joint", "}", number)
            joint = stack.pop()
            if len(offsets[joint]) != 3:
                raise _fail(path, f"an OFFSET line in joint {names[joint]}", "none", number)
        elif key == "OFFSET":
            if not stack or offsets[stack[-1]]:
                raise _fail(path, "one OFFSET per joint, inside its braces", "OFFSET", number)
            try:
                offsets[stack[-1]] = [float(word) for word in words[1:]]
            except ValueError:
                raise _fail(path, "OFFSET followed by 3 numbers", repr(" ".join(words[1:])), number) from None
            if len(offsets[stack[-1]]) != 3 or not np.isfinite(offsets[stack[-1]]).all():
                raise _fail(path, "OFFSET followed by 3 finite numbers", repr(" ".join(words[1:])), number)
        elif key == "CHANNELS":
            if not stack or stack[-1] in end_sites or channels[stack[-1]]:
                raise _fail(path, "one CHANNELS line per joint, inside its braces (none in an End Site)", "CHANNELS", number)
            if len(words) < 2 or not words[1].isdigit() or int(words[1]) != len(words) - 2:
                raise _fail(path, "CHANNELS, their count, then that many channel names", repr(" ".join(words[1:])), number)
            unknown = [word for word in words[2:] if word not in ROTATIONS + POSITIONS]
            if unknown or len(set(words[2:])) != len(words) - 2:
                raise _fail(path, f"distinct channel names among {ROTATIONS + POSITIONS}", repr(" ".join(words[2:])), number)
            channels[stack[-1]] = tuple(words[2:])
        elif key == "MOTION":
            motion_line = number
            break
        else:
            raise _fail(path, "ROOT, JOINT, End Site, OFFSET, CHANNELS, braces or MOTION", repr(key[:40]), number)
    if motion_line is None or stack or pending is not None or not names:
        raise _fail(path, "a closed hierarchy of at least one joint, then a MOTION line", "the file ending early")
    header: dict[str, str] = {}
    data_start = motion_line
    for label in ("Frames:", "Frame Time:"):
        while data_start < len(lines) and not lines[data_start].strip():
            data_start += 1
        line = lines[data_start] if data_start < len(lines) else ""
        if not line.strip().startswith(label):
            raise _fail(path, f"a '{label}' line after MOTION", repr(line[:40]), data_start + 1)
        header[label] = line.strip()[len(label):].strip()
        data_start += 1
    try:
        frame_count, frame_time = int(header["Frames:"]), float(header["Frame Time:"])
    except ValueError:
        raise _fail(path, "a whole number of Frames and a number for Frame Time", str(header), motion_line + 1) from None
    if not (frame_time > 0 and np.isfinite(frame_time)):
        raise _fail(path, "a positive Frame Time", header["Frame Time:"], data_start)
    width = sum(len(names) for names in channels)
    rows = [(index + 1, line) for index, line in enumerate(lines[data_start:], start=data_start) if line.strip()]
    if len(rows) != frame_count:
        raise _fail(path, f"{frame_count} motion lines (Frames)", f"{len(rows)}")
    motion = np.empty((frame_count, width))
    for row, (number, line) in enumerate(rows):
        words = line.split()
        if len(words) != width:
            raise _fail(path, f"{width} channel values per motion line (the hierarchy's CHANNELS)", f"{len(words)}", number)
        try:
            motion[row] = np.array(words, np.float64)
        except ValueError:
            raise _fail(path, "numbers in the motion lines", repr(line.strip()[:40]), number) from None
    if not np.isfinite(motion).all():
        number = rows[int(np.flatnonzero(~np.isfinite(motion).all(1))[0])][0]
        raise _fail(path, "finite channel values", "NaN or infinity", number)
    return BvhFile(
        joint_names=tuple(names),
        parents=tuple(parents),
        offsets=np.array(offsets, np.float64),
        channels=tuple(channels),
        frame_time=frame_time,
        motion=motion,
    )
