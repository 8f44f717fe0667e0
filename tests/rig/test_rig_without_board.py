"""Several people in view, no calibration: the rig recovered from every person (`jaxpose.rig.recovered.people_rows`,
`jaxpose.calibration.matching`) through the real loader, on the example project with three people (the default
detector: 3-8 px noise, outliers, swaps, missing joints, lens distortion; no intrinsics given), checked against the
rig that made the detections."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxpose.calibration import compare_rigs
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.project import load_rig_project
from jaxpose.synthetic import ExampleProjectConfig, write_rig_project

THREE = ExampleProjectConfig(recordings=1, frames_per_recording=200, people=3, second_person_rate=0.0, desync_camera=-1,
                             motions=("walking",), false_people_rate=0.1)  # fmt: skip


@pytest.mark.slow  # a calibration: ~1-2 min on 2 busy cores
def test_the_rig_is_recovered_from_three_people_without_a_calibration(tmp_path):
    """Every instant shows three people in every view, so no instant has one person per view (what the rig was
    recovered from before: refused then); matched by their epipolar geometry, the people give the rig: every
    camera within 1 degree and 2% of the rig's size (after the similarity no calibration from images fixes)."""
    root = write_rig_project(tmp_path / "three", THREE)
    reference = read_rig_calibration(root / "calibration.toml")
    (root / "calibration.toml").unlink()
    for truth in root.glob("*/ground_truth.npz"):  # three people's ground truth: not what the loader reads today
        truth.unlink()
    data = load_rig_project(RigProjectConfig(root=root, image_size=THREE.image_size, recovery_frames=150), progress=False)
    recovered = data.recovered_calibration
    assert recovered is not None and reference.camera_names == data.camera_names
    error = compare_rigs(np.asarray(recovered.cameras.R), np.asarray(recovered.cameras.t), reference.cameras.R, reference.cameras.t)
    size = np.linalg.norm(reference.cameras.t, axis=-1).mean()
    print("rotation deg", error.rotation_deg, "centre mm", error.centre_mm, "rig size mm", size)
    assert error.rotation_deg.max() < 1.0 and error.centre_mm.max() < 0.02 * size


def test_an_occasional_passer_by_keeps_the_one_person_rows():
    """Several people means some view holds more than one detection in most instants: a passer-by in 10% of
    the instants leaves the rows those of `one_person` (the instants where each view holds one detection)."""
    from jaxpose.rig.recordings import one_person
    from jaxpose.rig.recovered import people_rows, several_people

    rng = np.random.default_rng(0)
    keypoints = rng.uniform(0, 1000, (50, 3, 2, 17, 2)).astype(np.float32)
    confidence = np.zeros((50, 3, 2, 17), np.float32)
    confidence[:, :, 0] = 0.9
    confidence[:5, 1, 1] = 0.9  # the passer-by, in view 1
    assert not several_people(confidence)
    rows = people_rows(keypoints, confidence, None)
    for got, expected in zip(rows, one_person(keypoints, confidence)):
        np.testing.assert_array_equal(got, expected)
    confidence[:30, 1, 1] = 0.9
    assert several_people(confidence)
