"""benchmarks/peers.py: its scores against numpy oracles, its driver's file formats, and that it
skips the peers cleanly without their environment (and, where the environment exists, that both peers
give back the truth from noise-free detections through the driver)."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks import peers, peers_driver, peers_scores
from jaxpose.camera import Cameras
from jaxpose.reconstruction.recording import RecordingInput
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, make_rig, project_points
from jaxpose.synthetic.config import Stream, stream_rng


def walk(frames: int = 60, joints: int = 17, seed: int = 0) -> np.ndarray:
    """A smooth random trajectory f64[frames, joints, 3] (mm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None] / 50.0
    return rng.normal(0, 300, (1, joints, 3)) + 200 * np.sin(2 * np.pi * rng.uniform(0.2, 2, (1, joints, 3)) * t)


def test_the_acceleration_error_of_an_added_constant_acceleration_is_its_size():
    truth = walk()
    acceleration = np.array([3.0, -4.0, 12.0])  # |a| = 13 mm/frame^2
    t = np.arange(len(truth))[:, None, None]
    total, count = peers_scores.acceleration_error(truth + 0.5 * acceleration * t**2, truth)
    assert count == (len(truth) - 2) * truth.shape[1]
    np.testing.assert_allclose(total / count, 13.0, rtol=1e-9)


def test_the_acceleration_error_matches_a_loop_and_skips_triples_with_a_missing_point():
    rng = np.random.default_rng(1)
    truth = walk(30, 5)
    points = truth + rng.normal(0, 10, truth.shape)
    points[7, 2] = np.nan
    truth[20, 4] = np.nan
    errors = [
        np.linalg.norm((points[t + 1, j] - 2 * points[t, j] + points[t - 1, j]) - (truth[t + 1, j] - 2 * truth[t, j] + truth[t - 1, j]))
        for t in range(1, len(truth) - 1) for j in range(truth.shape[1])
    ]  # fmt: skip
    known = [e for e in errors if np.isfinite(e)]
    total, count = peers_scores.acceleration_error(points, truth)
    assert count == len(errors) - 6  # each missing cell is in three triples
    np.testing.assert_allclose(total, np.sum(known), rtol=1e-9)


def test_limb_spread_is_the_standard_deviation_of_each_limbs_length_over_the_instants_with_both_ends():
    rng = np.random.default_rng(2)
    points = walk(40, 17) + rng.normal(0, 5, (40, 17, 3))
    points[3, 2] = np.nan
    limbs = H36M_17.bones
    found = peers_scores.limb_spread(points, limbs)
    for (a, b), spread in zip(limbs, found):
        lengths = [np.linalg.norm(points[t, a] - points[t, b]) for t in range(40) if np.isfinite(points[t, [a, b]]).all()]
        np.testing.assert_allclose(spread, np.std(lengths), rtol=1e-9)
    rigid = np.broadcast_to(points[:1], points.shape)  # the same pose at every instant: no spread
    np.testing.assert_allclose(peers_scores.limb_spread(rigid[:, :3], [(0, 1), (1, 2)]), 0.0, atol=1e-9)


def test_scores_of_a_rotated_scaled_copy_have_no_procrustes_error_and_count_buckets_and_gaps():
    truth = walk(20, 17)
    centre = truth.mean(1, keepdims=True)
    moved = 1.1 * (truth - centre) @ Rotation.from_euler("z", 20, degrees=True).as_matrix().T + centre + 50.0
    moved[5, 3] = np.nan  # one gap at an instant a camera sees
    views = np.tile(np.arange(17) % 5, (20, 1))  # 0, 1, 2, 3, 4 views -> buckets 0, 1, 2, 3+
    seen = np.ones(20, bool)
    scores = peers_scores.Scores(np.array([name not in ("Spine", "Head") for name in H36M_17.joint_names]))
    scores.add(moved, truth, views, seen, H36M_17.bones)
    summary = scores.summary()
    error = np.linalg.norm(moved - truth, axis=-1)
    np.testing.assert_allclose(summary["mpjpe_mm"], np.nanmean(error), rtol=1e-6)
    assert summary["covered_pct"] == pytest.approx(100 * (1 - 1 / (20 * 17)))
    assert summary["p_mpjpe_mm"] == pytest.approx(0.0, abs=1e-2)  # float32 Procrustes on world mm
    assert summary["complete_frames"] == 19 and summary["instants_with_a_gap"] == 1
    for b, label in enumerate(peers_scores.BUCKETS):
        cells = np.minimum(views, 3) == b
        assert summary["buckets"][label]["cells"] == cells.sum()
        np.testing.assert_allclose(summary["buckets"][label]["mpjpe_mm"], np.nanmean(error[cells]), rtol=1e-6)


def test_the_error_splits_into_each_joints_offset_and_what_varies_about_it():
    """A constant offset per joint plus noise of zero mean over the recording, one cell missing: the
    offset (the error's mean over each joint's covered instants) and the noise about it come back, each
    averaged over the cells of two recordings."""
    rng = np.random.default_rng(0)
    scores = peers_scores.Scores(np.ones(17, bool))
    offsets, noises = [], []
    for _ in range(2):
        truth = walk(30, 17)
        offset = rng.normal(0.0, 40.0, (17, 3))
        noise = rng.normal(0.0, 5.0, truth.shape)
        noise -= noise.mean(0)
        points = truth + offset + noise
        points[7, 4] = np.nan  # joint 4's offset is then its mean over the other 29 instants
        have = np.isfinite(points).all(-1)
        mean_noise = np.stack([noise[have[:, j], j].mean(0) for j in range(17)])
        scores.add(points, truth, np.full((30, 17), 4), np.ones(30, bool), H36M_17.bones)
        offsets.append(np.where(have, np.linalg.norm(offset + mean_noise, axis=-1), np.nan))
        noises.append(np.where(have, np.linalg.norm(noise - mean_noise, axis=-1), np.nan))
    summary = scores.summary()
    np.testing.assert_allclose(summary["offset_mm"], np.nanmean(offsets), rtol=1e-9)
    np.testing.assert_allclose(summary["about_offset_mm"], np.nanmean(noises), rtol=1e-9)
    assert summary["about_offset_mm"] < 10.0 < 40.0 < summary["offset_mm"]


def test_the_driver_reads_a_pose2sim_trc_back_into_the_world_it_turned_to_y_up(tmp_path):
    names = ["Hip", "RHip", "Neck_Nose"]
    world = np.arange(4 * 3 * 3, dtype=float).reshape(4, 3, 3) * 10.0  # mm
    rows = ["PathFileType\t4\t(X/Y/Z)\tx.trc", "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits", "50\t50\t3\t3\tm",
            "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t\t", "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\t"]  # fmt: skip
    for frame in (1, 2, 3):  # Pose2Sim trims: frame 0 absent
        yup = world[frame][:, [1, 2, 0]] / 1000.0  # its zup2yup: X=y, Y=z, Z=x
        rows.append(f"{frame}\t{frame / 50}\t" + "\t".join(f"{v:.6f}" for v in yup.ravel()))
    path = tmp_path / "trial_0-3.trc"
    path.write_text("\n".join(rows) + "\n")
    found = peers_driver.read_trc(path, ["Neck_Nose", "Hip", "RHip"], 4)
    assert np.isnan(found[0]).all()
    np.testing.assert_allclose(found[1:], world[1:][:, [2, 0, 1]], atol=1e-3)


def test_the_custom_tree_holds_every_joint_once_under_its_parent():
    tree = peers_driver.custom_tree(list(H36M_17.joint_names), list(H36M_17.parents))
    found = {}

    def visit(node, parent):
        assert node["id"] not in found and H36M_17.joint_names[node["id"]] == node["name"]
        found[node["id"]] = parent
        for child in node.get("children", []):
            visit(child, node["id"])

    visit(tree, -1)
    assert [found[j] for j in range(H36M_17.num_joints)] == list(H36M_17.parents)


def test_without_the_environment_the_peers_are_skipped_in_one_line(tmp_path):
    args = peers.PeersArgs(output=tmp_path / "out", checkpoint=tmp_path, venv=tmp_path / "absent", install=False)
    python, why = peers.peer_python(args)
    assert python is None and "\n" not in why and str(tmp_path / "absent") in why
    fake = tmp_path / "fake" / "bin"
    fake.mkdir(parents=True)
    (fake / "python").symlink_to(sys.executable)  # a python without the peers
    python, why = peers.peer_python(dataclasses.replace(args, venv=tmp_path / "fake"))
    assert python is None and "\n" not in why and "not importable" in why


@pytest.mark.slow
def test_the_command_measures_jaxpose_and_says_why_the_peers_were_skipped(trained_run, tmp_path, capsys):
    report = peers.main(["--output", str(tmp_path / "out"), "--checkpoint", str(trained_run[0]), "--part", "timing",
                         "--cameras", "3", "--timing-frames", "20", "--repeats", "1", "--venv", str(tmp_path / "none"), "--no-install"])  # fmt: skip
    assert "peers skipped: no virtual environment at" in capsys.readouterr().err
    row = report["timing"]["cameras"][3]
    assert list(row) == list(peers.JAXPOSE_METHODS) and len(row["jaxpose per-instant fusion"]["times"]) == 2
    assert (tmp_path / "out" / "report.md").is_file()


VENV = peers.PeersArgs.__dataclass_fields__["venv"].default


@pytest.mark.slow
@pytest.mark.skipif(not (VENV / "bin" / "python").exists(), reason=f"no peers' environment at {VENV}")
def test_both_peers_return_the_truth_from_noise_free_detections_of_twelve_cameras(tmp_path):
    """Twelve cameras: aniposelib's own CameraGroup.load would put cam_10 before cam_2."""
    config = SyntheticConfig(num_views=12)
    rig = make_rig(stream_rng(config, Stream.ROOM), config)
    truth = walk(30, 17) * 0.3 + np.array([0.0, 0.0, 1000.0])
    pixels = project_points(rig, truth)[0].astype(np.float32)
    inputs = RecordingInput("clean", np.arange(30), rig, pixels, np.ones(pixels.shape[:3], np.float32), truth)
    args = peers.PeersArgs(output=tmp_path, checkpoint=tmp_path)
    python, _ = peers.peer_python(args)
    calibration = peers.write_calibration(tmp_path / "calibration.toml", [f"c{c}" for c in range(12)], Cameras(K=rig.K, R=rig.R, t=rig.t),
                                          np.tile(config.image_size, (12, 1)), "test")  # fmt: skip
    for family, methods in (("aniposelib", ["triangulate"]), ("pose2sim", ["triangulation"])):
        found, times, problem = peers.run_peer(python, family, methods, tmp_path / family, calibration, {"clean": inputs}, H36M_17, args)
        assert problem == "" and len(times[methods[0]]) == 1
        np.testing.assert_allclose(found["clean"][methods[0]], truth, atol=1.0)
