"""Rig calibration from the person in view (`jaxpose.calibration`, `python -m jaxpose.calibrate`).

The accuracy tests calibrate one subject of the synthetic data set (its rig and bodies are known
exactly) and, where `../shared` is present, the real Human3.6M S1 against its cameras.h5.  The
rest checks the pieces against oracles: the rig comparison against known similarities, the
limb-length scale against scaled skeletons, and every refusal's message.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxpose import calibrate as calibrate_cli
from jaxpose.calibration import (
    CalibrationConfig, CalibrationError, LensConfig, RigDetections, calibrate, compare_rigs, from_dataset,
    read_detections_npz,
)  # fmt: skip
from jaxpose.calibration.scale import LIMBS, limb_joints, metric_scale, prior_scale_error
from jaxpose.camera import Cameras, camera_centres
from jaxpose.formats.camera_file import load_cameras, save_cameras
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.synthetic import SyntheticConfig, generate
from jaxpose.skeleton import SKELETONS, H36M_17
from compilations import compilations
from help_text import assert_every_flag_documented
import paths

S1_DIR = paths.H36M_S1
NAMES = ("c0", "c1", "c2", "c3")
FAST = CalibrationConfig(max_frames=300)


@pytest.fixture(scope="module")
def synthetic_subject():
    """Subject S2 of the default synthetic generator (default detector noise, outliers and swaps),
    1,500 instants; its body is within 1% of the default limb prior."""
    dataset = generate(SyntheticConfig(num_train_subjects=2, num_test_subjects=0, samples_per_subject=1500))
    return dataset.where(subject=["S2"])


def own_rig(dataset: MultiViewDataset) -> Cameras:
    """The rig of a one-subject data set (`where` keeps every subject's rig; S2's is not the first)."""
    return dataset.rigs[int(dataset.samples.rig_index[0])]


def write_npz(path, dataset: MultiViewDataset, with_intrinsics: bool) -> None:
    arrays = dict(
        keypoints=dataset.samples.keypoints2d, confidence=dataset.samples.confidence, camera_names=np.array(NAMES),
        image_size=np.tile(np.array([1000, 1000], np.int32), (4, 1)), skeleton=np.array(dataset.skeleton.name),
    )  # fmt: skip
    if with_intrinsics:
        arrays["K"] = np.asarray(own_rig(dataset).K, np.float32)
    np.savez(path, **arrays)


@pytest.mark.slow  # ~22 s: the whole command; the same calibration is tested through the library below
def test_synthetic_rig_is_recovered_through_the_command_line(synthetic_subject, tmp_path):
    rig = own_rig(synthetic_subject)
    reference = tmp_path / "reference.json"
    save_cameras(reference, {"S2": (list(NAMES), rig)})
    write_npz(tmp_path / "detections.npz", synthetic_subject, with_intrinsics=True)
    output = tmp_path / "recovered.json"
    calibration, comparison = calibrate_cli.main([
        "--input", str(tmp_path / "detections.npz"), "--output", str(output), "--subject", "S2",
        "--reference", str(reference), "--calibration.max-frames", "300",
    ])  # fmt: skip

    distance = np.linalg.norm(
        camera_centres(np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64))
        - np.median(synthetic_subject.samples.target3d[:, 0], axis=0), axis=-1,
    )  # fmt: skip
    assert comparison.rotation_deg.max() < 0.5
    assert (comparison.centre_mm / distance).max() < 0.01
    # The scale is as right as the prior is for this body: the error is the body's deviation from it.
    expected = prior_scale_error(synthetic_subject.samples.target3d, synthetic_subject.skeleton)
    assert abs(comparison.scale_error - expected) < 0.015
    assert abs(comparison.scale_error) < 0.03
    assert np.all(calibration.reprojection_median_px < 6.0)  # the detector's noise is 3-8 px

    # The written file is a valid camera file with the given intrinsics and a stated world frame.
    names, cameras = load_cameras(output)["S2"]
    assert names == list(NAMES)
    np.testing.assert_allclose(cameras.K, rig.K, rtol=1e-6)
    document = json.loads(output.read_text())
    assert "view 0's camera frame" in document["comment"] and "millimetres" in document["comment"]
    report = output.with_suffix(".md").read_text()
    assert "rotation error" in report and "scale error" in report
    assert output.with_suffix(".png").stat().st_size > 10_000


def test_unknown_focal_lengths_are_estimated(synthetic_subject):
    rig = own_rig(synthetic_subject)
    detections = from_dataset(synthetic_subject, "S2", NAMES, np.full((4, 2), 1000)).without_intrinsics()
    focal_only = LensConfig(estimate_principal_point=False, estimate_distortion=False)
    calibration = calibrate(detections, dataclasses.replace(FAST, lens=focal_only))
    assert calibration.focal_estimated and (calibration.lens.state[:, 1:] == "held").all()
    # The start is 1.2 x 1000 px; the true focal lengths are ~1150 px.
    np.testing.assert_allclose(calibration.cameras.K[:, 0, 0], np.asarray(rig.K)[:, 0, 0], rtol=0.02)
    comparison = compare_rigs(calibration.cameras.R, calibration.cameras.t, np.asarray(rig.R), np.asarray(rig.t))
    assert comparison.rotation_deg.max() < 1.5


def test_a_calibration_compiles_at_most_30_programs(synthetic_subject):
    """Fixed shapes in calibration as on the loading path: a call compiles a few whole programs (the
    undistortion, the triangulation, the adjustment's round and posterior), not one per operation run
    eagerly (~230 before), nor one per view registered; the same call again compiles nothing."""
    detections = from_dataset(synthetic_subject, "S2", NAMES, np.full((4, 2), 1000)).without_intrinsics()
    config = dataclasses.replace(FAST, max_frames=80, robust_rounds=1)  # a frame count no other test compiles for
    with compilations() as first:
        calibrate(detections, config)
    with compilations() as again:
        calibrate(detections, config)
    print(f"compilations of a calibration {first}, of the same one again {again}")
    assert first["compiled"] <= 30 and first["lowered"] <= 30, first
    assert again["compiled"] == 0, again


def test_two_views_with_occluded_joints(synthetic_subject):
    """The smallest rig, with a third of one view's joints missing (some joints then seen by one view only)."""
    rig = own_rig(synthetic_subject)
    views = np.array([0, 2])
    confidence = synthetic_subject.samples.confidence[:, views].copy()
    confidence[:, 1][np.random.default_rng(0).random(confidence[:, 1].shape) < 0.33] = 0.0
    detections = RigDetections(
        keypoints=synthetic_subject.samples.keypoints2d[:, views], confidence=confidence, camera_names=("c0", "c2"),
        image_size=np.full((2, 2), 1000), skeleton=synthetic_subject.skeleton, K=np.asarray(rig.K, np.float64)[views],
    )  # fmt: skip
    calibration = calibrate(detections, FAST)
    comparison = compare_rigs(calibration.cameras.R, calibration.cameras.t, np.asarray(rig.R)[views], np.asarray(rig.t)[views])
    assert comparison.rotation_deg.max() < 0.5
    assert np.all(calibration.reprojection_median_px < 6.0)  # joints seen once are not counted as errors


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.01, 100.0), num_cameras=st.integers(2, 6))
def test_rig_comparison_sees_through_any_similarity(seed, scale, num_cameras):
    rng = np.random.default_rng(seed)
    R_ref = Rotation.random(num_cameras, random_state=seed).as_matrix()
    t_ref = rng.normal(0.0, 3000.0, (num_cameras, 3))
    Q = Rotation.random(random_state=seed + 1).as_matrix()
    shift = rng.normal(0.0, 1000.0, 3)
    # The same rig in a world X' with X_ref = scale Q X' + shift: R' = R_ref Q, t' = (R_ref shift + t_ref) / scale.
    R = R_ref @ Q
    t = (np.einsum("cij,j->ci", R_ref, shift) + t_ref) / scale
    comparison = compare_rigs(R, t, R_ref, t_ref)
    assert comparison.rotation_deg.max() < 1e-4
    assert comparison.centre_mm.max() < 1e-6 * np.abs(t_ref).max()
    assert comparison.scale_error == pytest.approx(1.0 / scale - 1.0, rel=1e-6, abs=1e-9)

    # A known error in one camera shows up there, by its size.
    R_bad = R.copy()
    R_bad[0] = Rotation.from_rotvec([0.0, 0.0, np.radians(2.0)]).as_matrix() @ R[0]
    assert compare_rigs(R_bad, t, R_ref, t_ref).rotation_deg[0] == pytest.approx(2.0, abs=2.0 / num_cameras + 0.01)


@pytest.mark.parametrize("name", sorted(SKELETONS))
def test_every_skeleton_has_all_four_limbs_on_both_sides(name):
    limbs = limb_joints(SKELETONS[name])
    assert sorted(limbs) == sorted(LIMBS) and all(len(pairs) == 2 for pairs in limbs.values())


def test_metric_scale_recovers_a_scaled_skeleton():
    dataset = generate(SyntheticConfig(num_train_subjects=1, num_test_subjects=0, samples_per_subject=50))
    points = dataset.samples.target3d.astype(np.float64)
    true = metric_scale(points, np.ones(points.shape[:2], bool), H36M_17).mm_per_unit
    shrunk = metric_scale(points / 7.5, np.ones(points.shape[:2], bool), H36M_17)
    assert shrunk.mm_per_unit == pytest.approx(7.5 * true, rel=1e-9)
    # With its own limb lengths as the prior, a skeleton's scale is exactly 1.
    measured = [shrunk.measured_mm[limb] / true for limb in LIMBS]
    assert metric_scale(points, np.ones(points.shape[:2], bool), H36M_17, measured).mm_per_unit == pytest.approx(1.0)


def detections(keypoints, confidence=None, **fields) -> RigDetections:
    N, C, J, _ = keypoints.shape
    return RigDetections(
        keypoints=keypoints, confidence=np.ones((N, C, J), np.float32) if confidence is None else confidence,
        camera_names=tuple(f"c{c}" for c in range(C)), image_size=np.full((C, 2), 1000), skeleton=H36M_17, **fields,
    )  # fmt: skip


def test_npz_refusals_name_the_file_and_array(tmp_path):
    path = tmp_path / "d.npz"
    np.savez(path, keypoints=np.zeros((5, 2, 17, 2), np.float32), camera_names=np.array(["a", "b"]))
    with pytest.raises(ValueError, match=r"d.npz: expected arrays \['image_size', 'skeleton'\]"):
        read_detections_npz(path)
    np.savez(path, keypoints=np.zeros((5, 2, 17, 2), np.float32), camera_names=np.array(["a", "b"]),
             image_size=np.full((2, 2), 640), skeleton=np.array("smpl"))  # fmt: skip
    with pytest.raises(ValueError, match=r"array 'skeleton'.*'smpl'"):
        read_detections_npz(path)
    np.savez(path, keypoints=np.zeros((5, 2, 17, 2), np.float32), camera_names=np.array(["a", "b"]),
             image_size=np.full((2, 2), 640), skeleton=np.array("h36m17"), K=np.eye(3)[None])  # fmt: skip
    with pytest.raises(ValueError, match=r"field 'K'.*\[C, 3, 3\] = \(2, 3, 3\)"):
        read_detections_npz(path)


def test_one_view_is_refused():
    with pytest.raises(ValueError, match="at least 2 views"):
        detections(np.zeros((10, 1, 17, 2), np.float32))


def test_nan_keypoint_with_positive_confidence_is_named(synthetic_subject):
    keypoints = synthetic_subject.samples.keypoints2d[:20].copy()
    keypoints[3, 2, 5] = np.nan
    with pytest.raises(ValueError, match=r"frame 3, view 2 \(c2\), joint 'LKnee'"):
        detections(keypoints)
    confidence = np.ones(keypoints.shape[:-1], np.float32)
    confidence[3, 2, 5] = 0.0
    detections(keypoints, confidence)  # a missing joint is fine


def test_a_person_standing_still_is_refused(synthetic_subject):
    still = np.repeat(synthetic_subject.samples.keypoints2d[:1], 200, axis=0)
    still = still + np.random.default_rng(0).normal(0.0, 1.0, still.shape).astype(np.float32)
    with pytest.raises(CalibrationError, match="barely moves"):
        calibrate(detections(still, K=np.asarray(own_rig(synthetic_subject).K, np.float64)))


def test_too_few_shared_frames_are_refused(synthetic_subject):
    confidence = synthetic_subject.samples.confidence.copy()
    confidence[20:] = 0.0
    with pytest.raises(CalibrationError, match=r"only 20 frames .* needs >= 30"):
        calibrate(detections(synthetic_subject.samples.keypoints2d, confidence))


def test_a_view_that_never_sees_the_person_with_the_others_is_named(synthetic_subject):
    confidence = synthetic_subject.samples.confidence.copy()
    confidence[:, 3, :] = 0.0
    confidence[:40, :3, :] = 0.0
    confidence[:40, 3, :] = 1.0  # c3 sees the person only in frames nobody else does
    with pytest.raises(CalibrationError, match="view c3 cannot be placed"):
        calibrate(detections(synthetic_subject.samples.keypoints2d, confidence, K=np.asarray(own_rig(synthetic_subject).K, np.float64)))


def test_recalibrated_dataset_uses_the_new_rigs_and_drops_the_ground_truth(synthetic_subject):
    rig = own_rig(synthetic_subject)
    moved = Cameras(K=np.asarray(rig.K), R=np.asarray(rig.R), t=np.asarray(rig.t) + 100.0)  # another rig
    recalibrated = synthetic_subject.recalibrated({"S2": moved})
    np.testing.assert_array_equal(recalibrated.cameras_for(np.arange(3)).t, np.broadcast_to(moved.t, (3, 4, 3)))
    assert recalibrated.samples.target3d is None
    with pytest.raises(ValueError, match=r"no rig for subjects \['S2'\]"):
        synthetic_subject.recalibrated({"S9": moved})


def test_help_documents_every_flag(capsys):
    with pytest.raises(SystemExit) as stop:
        calibrate_cli.main(["--help"])
    assert stop.value.code == 0
    flags = [f"--{field.name}".replace("_", "-") for field in dataclasses.fields(calibrate_cli.CalibrateArgs) if field.name != "calibration"]
    assert_every_flag_documented(capsys.readouterr().out, flags + calibration_flags())


@pytest.mark.skipif(not (S1_DIR / "cameras.h5").is_file(), reason=f"the real Human3.6M S1 development set is not at {S1_DIR}")
def test_real_s1_rig_from_stacked_hourglass_detections(tmp_path):
    _, comparison = calibrate_cli.main([
        "--input", str(S1_DIR), "--subject", "S1", "--output", str(tmp_path / "s1.json"),
        "--reference", str(S1_DIR / "cameras.h5"),
    ])  # fmt: skip
    assert comparison.rotation_deg.max() < 1.0
    assert comparison.centre_mm.max() < 50.0


def test_synthetic_calibration_experiment_help_documents_every_flag(capsys):
    from experiments import calibration_study as experiment
    with pytest.raises(SystemExit) as stop:
        experiment.main(["--help"])
    assert stop.value.code == 0
    assert_every_flag_documented(capsys.readouterr().out, ["--unknown-intrinsics"] + calibration_flags())


def calibration_flags() -> list[str]:
    """The flags of `CalibrationConfig`, its nested lens settings included."""
    flags = [f"--calibration.{field.name}" for field in dataclasses.fields(CalibrationConfig) if field.name != "lens"]
    # A switch's help follows its "--no-" form, which long names push onto a line of its own.
    flags += [f"--calibration.lens.{'no-' if field.type == 'bool' else ''}{field.name}" for field in dataclasses.fields(LensConfig)]
    return [flag.replace("_", "-") for flag in flags]
