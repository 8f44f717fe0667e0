"""Several people and no rig: the people matched across views from the detections' epipolar geometry alone
(`jaxpose.calibration.matching`), on scenes whose truth is known: the example project's people
(`jaxpose.synthetic.capture.people_poses`) projected through its pinhole rig, 2 px noise, each view's
detections shuffled, with false detections (a real person's detection moved elsewhere in one view)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxpose.calibration import CalibrationError
from jaxpose.calibration.matching import match_people
from jaxpose.synthetic import ExampleProjectConfig
from jaxpose.synthetic.capture import people_bones, people_poses, rig_calibration

CONFIG = ExampleProjectConfig(people=3, cameras=4, distortion=False, motions=("walking",), frames_per_recording=120)


def scene(config: ExampleProjectConfig, false_rate: float, seed: int = 0):
    """keypoints f32[N, C, K, J, 2], confidence f32[N, C, K, J], owner int[N, C, K] (the person of each
    detection, -1 false or padding)."""
    rng = np.random.default_rng(seed)
    cameras = rig_calibration(config).cameras
    P = np.einsum("cij,cjk->cik", cameras.K, np.concatenate([cameras.R, cameras.t[:, :, None]], -1))
    poses = np.stack(people_poses(config, 0, people_bones(config), config.frames_per_recording), 1)  # [N, M, J, 3]
    h = np.einsum("cik,nmjk->ncmji", P, np.concatenate([poses, np.ones_like(poses[..., :1])], -1))
    pixels = h[..., :2] / h[..., 2:] + rng.normal(0, 2.0, h[..., :2].shape)  # [N, C, M, J, 2]
    N, C, M, J = pixels.shape[:4]
    K = M + 1
    keypoints = np.zeros((N, C, K, J, 2), np.float32)
    confidence = np.zeros((N, C, K, J), np.float32)
    owner = np.full((N, C, K), -1)
    for n in range(N):
        for c in range(C):
            order = rng.permutation(K)
            for m in range(M):
                keypoints[n, c, order[m]], confidence[n, c, order[m]], owner[n, c, order[m]] = pixels[n, c, m], 0.9, m
            if rng.random() < false_rate:  # somebody's detection, 300-600 px away: nobody in the other views
                shift = rng.uniform(300, 600) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
                keypoints[n, c, order[M]], confidence[n, c, order[M]] = pixels[n, c, rng.integers(M)] + shift, 0.9
    return keypoints, confidence, owner


def owners(matched, keypoints, confidence, owner):
    """int[R, C]: the person whose detection each row holds in each view (-1 false, -2 none)."""
    found = np.full(matched.confidence.shape[:2], -2)
    for r, n in enumerate(matched.instant):
        for c in range(found.shape[1]):
            if (matched.confidence[r, c] > 0).any():
                k = np.flatnonzero(np.all(keypoints[n, c] == matched.keypoints[r, c], axis=(-2, -1)) & (confidence[n, c] > 0).any(-1))
                found[r, c] = owner[n, c, k[0]]
    return found


@pytest.mark.parametrize("people", [2, 3])
def test_people_are_matched_across_views_without_a_rig(people):
    """Oracle: the truth's owner of each detection.  Every row holds one person's detections only (precision
    above 99% of the detections taken), nearly every person-instant is found in every view (recall above 95%),
    and the false detections are left out and counted."""
    config = dataclasses.replace(CONFIG, people=people)
    keypoints, confidence, owner = scene(config, false_rate=0.3)
    matched = match_people(keypoints, confidence, threshold_px=8.0, min_joints=6, min_confidence=0.3)
    found = owners(matched, keypoints, confidence, owner)
    taken = found >= -1
    real = found[taken]
    majority = np.array([np.bincount(row[row >= 0]).argmax() if (row >= 0).any() else -1 for row in found])
    correct = (found == majority[:, None]) & (found >= 0)
    assert correct.sum() >= 0.99 * taken.sum(), f"{taken.sum() - correct.sum()} of {taken.sum()} detections with another person"
    assert correct.sum() >= 0.95 * (owner >= 0).sum()
    false = int(((owner == -1) & (confidence > 0).any(-1)).sum())
    assert (real == -1).sum() <= 0.01 * taken.sum() and matched.unmatched >= 0.9 * false
    assert matched.views_estimated == 6


def test_too_few_instants_to_relate_the_views_are_refused_in_one_line():
    """Two instants of three people: 18 pairings per view pair, fewer than a fundamental matrix needs."""
    keypoints, confidence, _ = scene(dataclasses.replace(CONFIG, frames_per_recording=30), false_rate=0.0)
    with pytest.raises(CalibrationError, match="no two views see people together often enough") as error:
        match_people(keypoints[:2, :, :3], confidence[:2, :, :3], threshold_px=8.0, min_joints=6, min_confidence=0.3)
    assert "\n" not in str(error.value)


def test_a_detections_npz_with_several_people_is_read_one_row_per_person(tmp_path):
    """`jaxpose.calibrate`'s reader: a person axis is matched into rows (each a person seen by >= 2 views)."""
    from jaxpose.calibration import CalibrationConfig, read_detections_npz
    from jaxpose.formats.errors import DataFormatError

    keypoints, confidence, owner = scene(dataclasses.replace(CONFIG, frames_per_recording=40), false_rate=0.0)
    path = tmp_path / "detections.npz"
    np.savez(path, keypoints=keypoints, confidence=confidence, camera_names=np.array(CONFIG.camera_names),
             image_size=np.tile(CONFIG.image_size, (CONFIG.cameras, 1)), skeleton=np.array("h36m17"))  # fmt: skip
    detections = read_detections_npz(path, people=CalibrationConfig())
    assert detections.keypoints.shape[1:] == (CONFIG.cameras, 17, 2)
    assert len(detections.keypoints) >= 0.95 * 40 * CONFIG.people
    assert ((detections.confidence > 0).any(-1).sum(1) >= 2).all()
    with pytest.raises(DataFormatError, match="one person per view"):
        read_detections_npz(path)
