"""BVH motion capture files (`jaxpose.formats.bvh`): forward kinematics against scipy, the real CMU files, bad input."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.formats.bvh import CMU_MM_PER_UNIT, read_bvh, world_joints
from jaxpose.formats.errors import DataFormatError
import paths

CMU = paths.SHARED_DATA / "cmu_mocap"
needs_cmu = pytest.mark.skipif(not CMU.is_dir(), reason=f"{CMU} (the CMU motion capture files) is absent")
ORDERS = ["".join(order) for order in itertools.permutations("XYZ")]


def _chain(order: str, frames: list[list[float]], frame_time: str = ".0083333") -> str:
    """A root (6 channels, positions then rotations in `order`), one joint rotating in `order`, an End Site."""
    rotations = " ".join(f"{axis}rotation" for axis in order)
    motion = "\n".join(" ".join(repr(float(value)) for value in frame) for frame in frames)
    return f"""HIERARCHY
ROOT Hips
{{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition {rotations}
  JOINT Knee
  {{
    OFFSET 0 -2 0.5
    CHANNELS 3 {rotations}
    End Site
    {{
      OFFSET 0.25 -1 0
    }}
  }}
}}
MOTION
Frames: {len(frames)}
Frame Time: {frame_time}
{motion}
"""


def _write(tmp_path: Path, text: str, name: str = "motion.bvh") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("order", ORDERS)
def test_forward_kinematics_matches_scipy_in_every_channel_order(tmp_path, order):
    # 90 degrees about each axis alone, then a general pose: intrinsic composition in the listed order.
    rng = np.random.default_rng(ORDERS.index(order))
    angles = [[90, 0, 0], [0, 90, 0], [0, 0, 90], *rng.uniform(-180, 180, (3, 3)).tolist()]
    frames = [[10.0, -5.0, 2.0, *root, *knee] for root, knee in zip(angles, angles[::-1])]
    bvh = read_bvh(_write(tmp_path, _chain(order, frames)))
    assert bvh.joint_names == ("Hips", "Knee", "Knee_End") and bvh.parents == (-1, 0, 1)
    mm = 2.0
    joints = world_joints(bvh, mm_per_unit=mm)
    for frame, (root, knee) in enumerate(zip(angles, angles[::-1])):
        root_rotation = Rotation.from_euler(order, root, degrees=True)  # upper case: intrinsic
        knee_rotation = root_rotation * Rotation.from_euler(order, knee, degrees=True)
        hips = np.array([1 + 10.0, 2 - 5.0, 3 + 2.0])
        knee_at = hips + root_rotation.apply([0, -2, 0.5])
        end_at = knee_at + knee_rotation.apply([0.25, -1, 0])
        np.testing.assert_allclose(joints[frame], mm * np.stack([hips, knee_at, end_at]), atol=1e-9)


def test_a_90_degree_turn_about_each_axis_moves_the_child_where_expected(tmp_path):
    # The rotation's sense (right-handed, counterclockwise), independent of scipy.
    frames = [[0, 0, 0, 0, 0, 0, 90, 0, 0], [0, 0, 0, 0, 0, 0, 0, 90, 0], [0, 0, 0, 0, 0, 0, 0, 0, 90]]
    joints = world_joints(read_bvh(_write(tmp_path, _chain("XYZ", frames))), mm_per_unit=1.0)
    end_from_knee = joints[:, 2] - joints[:, 1]
    np.testing.assert_allclose(end_from_knee, [[0.25, 0, -1], [0, -1, -0.25], [1, 0.25, 0]], atol=1e-12)


def test_frame_selection_and_units(tmp_path):
    frames = [[float(i), 0, 0, 0, 0, 0, 0, 0, 0] for i in range(5)]
    bvh = read_bvh(_write(tmp_path, _chain("ZYX", frames, frame_time="0.02")))
    assert bvh.fps == pytest.approx(50) and bvh.frame_count == 5
    joints = world_joints(bvh, CMU_MM_PER_UNIT, frames=slice(1, 5, 2))
    np.testing.assert_allclose(joints[:, 0, 0], (1 + np.array([1, 3])) * 56.444444, rtol=1e-6)


@pytest.mark.parametrize(
    "edit, fault",
    [
        (lambda t: t.replace("HIERARCHY", "HIERARCH"), "starting with HIERARCHY"),
        (lambda t: t.replace("OFFSET 0 -2 0.5", "OFFSET 0 -2"), "line 8"),
        (lambda t: t.replace("OFFSET 0 -2 0.5", "OFFSET 0 x 0.5"), "line 8"),
        (lambda t: t.replace("CHANNELS 3", "CHANNELS 4"), "line 9"),
        (lambda t: t.replace("CHANNELS 3 Z", "CHANNELS 3 W"), "line 9"),
        (lambda t: t.replace("Frames: 2", "Frames: 3"), "3 motion lines"),
        (lambda t: t.replace("Frame Time: .0083333", "Frame Time: 0"), "positive Frame Time"),
        (lambda t: t.replace("Frame Time:", "Frame Rate:"), "Frame Time:"),
        (lambda t: t.rstrip("\n") + " 7\n", "line 20"),
        (lambda t: t.rstrip("\n")[:-1] + "nan\n", "line 20"),
        (lambda t: t.replace("    }\n  }\n}", "    }\n  }\n"), "closed hierarchy"),
        (lambda t: t.replace("      OFFSET 0.25 -1 0\n", "      OFFSET 0.25 -1 0\n      CHANNELS 1 Xrotation\n"), "line 13"),
    ],
)
def test_bad_files_name_the_file_and_the_line(tmp_path, edit, fault):
    text = _chain("ZYX", [[0] * 9, [1] * 9])
    path = _write(tmp_path, edit(text), name="bad take.bvh")
    with pytest.raises(DataFormatError) as raised:
        read_bvh(path)
    message = str(raised.value)
    assert "bad take.bvh" in message and fault in message and "\n" not in message


def test_a_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="missing.bvh"):
        read_bvh(tmp_path / "missing.bvh")


@needs_cmu
@pytest.mark.parametrize("name", ["02/02_01.bvh", "02/02_03.bvh", "05/05_02.bvh", "06/06_01.bvh"])
def test_cmu_files_keep_their_bone_lengths(name):
    bvh = read_bvh(CMU / name)
    assert bvh.fps == pytest.approx(120, rel=1e-4) and len(bvh.joint_names) == 38  # 31 joints and 7 End Sites
    assert bvh.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
    joints = world_joints(bvh, CMU_MM_PER_UNIT)
    bones = np.linalg.norm(joints[:, 1:] - joints[:, list(bvh.parents[1:])], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), atol=1e-6)
    thigh = bones[0, bvh.index("LeftLeg") - 1]
    assert 350 < thigh < 500  # a real thigh in mm: the unit scale is right


@needs_cmu
def test_cmu_jog_runs_at_the_speed_the_data_readme_states():
    bvh = read_bvh(CMU / "02" / "02_03.bvh")
    assert bvh.frame_count == 174
    hips = world_joints(bvh, CMU_MM_PER_UNIT)[:, bvh.index("Hips")][:, [0, 2]]  # Y is up
    path_m = np.linalg.norm(np.diff(hips, axis=0), axis=-1).sum() / 1000
    assert path_m / (bvh.frame_count * bvh.frame_time) == pytest.approx(2.56, abs=0.01)
