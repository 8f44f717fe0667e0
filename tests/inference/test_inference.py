"""Inference on your own detections: `jaxpose.serving.inference` (load + predict) and the CLI `jaxpose.predict`.

One tiny synthetic main job (module fixture) provides the run directory; its own test detections,
lifted through the CLI, must reproduce the P-MPJPE of the experiment's evaluation.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import shutil

import numpy as np
import pytest

from detection_helpers import body25_from_coco, coco_from_h36m, views
from help_text import assert_help_documents_every_field
from jaxpose import predict
from jaxpose.training import checkpoint, evaluation
from jaxpose.serving import inference
from jaxpose.camera import project_from_camera, world_to_camera
from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES, coco17_to_h36m17
from jaxpose.skeleton import COCO_17, H36M_17

METHOD = "Lifter, self-supervised (ours)"
IMAGE_SIZE = (1000, 1000)  # the synthetic rig's images


def _cli(*args) -> np.ndarray:
    return predict.main([str(a) for a in args])


# ---------------------------------------------------------------------------------------------
# The acceptance check: the CLI reproduces the experiment's evaluation


def test_cli_reproduces_experiment_p_mpjpe(trained_run, tmp_path):
    run_dir, test = trained_run
    keypoints, confidence, K = views(test.undistorted())
    np.savez(tmp_path / "views.npz", keypoints=keypoints, confidence=confidence, K=K, image_id=np.arange(len(K)))
    # The experiment evaluates every keypoint with a positive score: so does predict with --min-confidence 0
    # (its default 0.05 would drop the synthetic detector's lowest-scored roots).
    _cli("--checkpoint", run_dir, "--input", tmp_path / "views.npz", "--output", tmp_path / "poses.npz",
         "--min-confidence", 0)  # fmt: skip
    with np.load(tmp_path / "poses.npz") as out:
        poses, valid, image_ids = out["pose3d_mm"], out["valid"], out["image_id"]
    # As the evaluation: a view whose root was not detected is not lifted, nor counted.
    np.testing.assert_array_equal(valid, confidence[:, 0] > 0)
    assert (~valid).any() and np.isnan(poses[~valid]).all()
    np.testing.assert_array_equal(image_ids, np.arange(len(K)))
    target = evaluation.poses_in_views(test, test.samples.target3d).reshape(poses.shape)
    ours = evaluation.summarize(evaluation.compute_metrics(poses[valid], target[valid])[0])["overall"]["p_mpjpe"]
    report = json.loads((run_dir / "report.json").read_text())
    assert ours == pytest.approx(report["results"][METHOD]["overall"]["p_mpjpe"], abs=0.01)


# ---------------------------------------------------------------------------------------------
# CLI inputs


def test_cli_coco_results_round_trip_through_the_adapter(trained_run, lifter, tmp_path):
    keypoints, confidence, _ = views(trained_run[1])
    coco = coco_from_h36m(keypoints[:5])
    scores = np.full(coco.shape[:2], 0.9, np.float32)
    scores[3, COCO_17.index("left_hip")] = 0.0  # no hip -> no pelvis (the root) -> not liftable
    image_ids = [7, 7, 12, 40, 41]  # two people in image 7
    triplets = np.concatenate([coco, scores[..., None]], axis=-1).reshape(len(coco), -1)
    entries = [
        {"image_id": i, "category_id": 1, "keypoints": t.tolist(), "score": 0.9} for i, t in zip(image_ids, triplets)
    ]
    (tmp_path / "results.json").write_text(json.dumps(entries))
    _cli("--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--output", tmp_path / "poses.json",
         "--image-size", *IMAGE_SIZE, "--plot", tmp_path / "plots", "--plot-count", 2)  # fmt: skip
    records = json.loads((tmp_path / "poses.json").read_text())
    assert [r["image_id"] for r in records] == image_ids
    assert all(r["joint_names"] == list(H36M_17.joint_names) for r in records)
    assert records[3]["pose3d_mm"] is None
    lifted = np.array([r["pose3d_mm"] for i, r in enumerate(records) if i != 3])
    assert lifted.shape == (4, 17, 3) and np.all(lifted[:, 0] == 0.0)
    # The CLI is the adapter followed by the library call with the default intrinsics.
    h36m, confidence = coco17_to_h36m17(coco, scores)
    expected = lifter.predict(h36m, confidence=confidence, image_size=IMAGE_SIZE)
    np.testing.assert_allclose(lifted, np.delete(expected, 3, axis=0), atol=0.006)  # JSON keeps 0.01 mm
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == ["lifting_00000.png", "lifting_00001.png"]


def test_cli_openpose_folder(trained_run, tmp_path):
    keypoints, _, K = views(trained_run[1])
    body25 = body25_from_coco(coco_from_h36m(keypoints[:3]), 0.8)
    body25[2, OPENPOSE_25_JOINT_NAMES.index("RHip"), 2] = 0.0  # not liftable
    folder = tmp_path / "openpose"
    folder.mkdir()
    frames = {"clip_000000000000": [0, 1], "clip_000000000001": [], "clip_000000000002": [2]}
    for stem, people in frames.items():
        document = {"version": 1.3, "people": [{"pose_keypoints_2d": body25[p].ravel().tolist()} for p in people]}
        (folder / f"{stem}_keypoints.json").write_text(json.dumps(document))
    (folder / "notes.txt").write_text("not a frame")
    _cli("--checkpoint", trained_run[0], "--input", folder, "--output", tmp_path / "poses.npz", "--format", "body25",
         "--intrinsics", *K[0, [0, 1, 0, 1], [0, 1, 2, 2]])  # fmt: skip
    with np.load(tmp_path / "poses.npz") as out:
        assert out["image_id"].tolist() == ["clip_000000000000", "clip_000000000000", "clip_000000000002"]
        assert out["valid"].tolist() == [True, True, False]
        assert out["pose3d_mm"].shape == (3, 17, 3) and out["joint_names"].tolist() == list(H36M_17.joint_names)


def test_cli_npz_with_distortion_from_an_intrinsics_file(trained_run, lifter, tmp_path):
    """A camera file entry with OpenCV distortion: the CLI undistorts, matching lifting the pinhole pixels."""
    test = trained_run[1]
    K = np.asarray(test.rigs.K)[0, 0]
    camera = test.rigs[0, 0]
    dist = np.array([-0.25, 0.08, 0.001, -0.0015, 0.0], np.float32)
    in_camera = world_to_camera(camera, test.samples.target3d[:6])
    pinhole = np.asarray(project_from_camera(camera, in_camera))
    distorted = np.asarray(project_from_camera(camera.replace(dist=dist), in_camera))
    assert np.abs(distorted - pinhole).max() > 2.0  # pixels: the distortion matters
    np.savez(tmp_path / "distorted.npz", keypoints=distorted)
    camera_entry = {"K": K.tolist(), "dist": dist.tolist(), "image_size": IMAGE_SIZE}  # a camera-file entry
    (tmp_path / "camera.json").write_text(json.dumps(camera_entry))
    poses = _cli("--checkpoint", trained_run[0], "--input", tmp_path / "distorted.npz", "--output",
                 tmp_path / "poses.npz", "--intrinsics", tmp_path / "camera.json")  # fmt: skip
    np.testing.assert_allclose(poses, lifter.predict(pinhole, K), atol=0.05)


# ---------------------------------------------------------------------------------------------
# Library behaviour


def test_predict_chunking_single_pose_and_missing_root(trained_run, lifter):
    keypoints, confidence, K = views(trained_run[1].undistorted())
    rows = np.flatnonzero(confidence[:, 0] > 0)[:10]  # root detected
    keypoints, confidence, K = keypoints[rows], confidence[rows], K[rows]
    confidence[4, 0] = 0.0
    keypoints[6, 3] = np.nan  # a missing joint may be NaN when its confidence is 0
    confidence[6, 3] = 0.0
    whole = lifter.predict(keypoints, K, confidence)
    chunked = dataclasses.replace(lifter, batch_size=4).predict(keypoints, K, confidence)
    np.testing.assert_allclose(chunked, whole, atol=1e-3)
    assert np.isnan(whole[4]).all() and np.isfinite(np.delete(whole, 4, axis=0)).all()
    np.testing.assert_allclose(lifter.predict(keypoints[0], K[0], confidence[0]), whole[0], atol=1e-3)


def test_default_intrinsics():
    K = inference.default_intrinsics((1920, 1080))
    np.testing.assert_allclose(K, [[1920, 0, 960], [0, 1920, 540], [0, 0, 1]])
    with pytest.raises(ValueError, match="image_size"):
        inference.default_intrinsics((1920, -1))


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda k, c, K: (k[:, :16], c[:, :16], K), r"checkpoint .* lifts skeleton 'h36m17' with J=17"),
        (lambda k, c, K: (k, c, K[:2]), r"intrinsics: expected shape \(3, 3\) or \(3, 3, 3\)"),
        (lambda k, c, K: (k, c, np.swapaxes(K, 1, 2)), "transposed"),
        (lambda k, c, K: (k, c[:, :5], K), r"confidence: expected shape \(3, 17\)"),
        (lambda k, c, K: (k[..., :1], c, K), r"expected \[N, J, 2\]"),
        (lambda k, c, K: (np.where(np.arange(17)[:, None] == 2, np.nan, k), c, K), r"non-finite .*joint 2 \(RKnee\)"),
        (lambda k, c, K: (k, c, None), "no intrinsics"),
    ],
)
def test_predict_errors(trained_run, lifter, change, message):
    keypoints, confidence, K = views(trained_run[1])
    with pytest.raises(ValueError, match=message):
        keypoints, confidence, K = change(keypoints[:3], np.ones_like(confidence[:3]), K[:3])
        lifter.predict(keypoints, intrinsics=K, confidence=confidence)


# ---------------------------------------------------------------------------------------------
# CLI errors


def test_cli_errors(trained_run, tmp_path):
    run_dir = trained_run[0]
    keypoints, _, K = views(trained_run[1])
    np.savez(tmp_path / "j16.npz", keypoints=keypoints[:2, :16])
    np.savez(tmp_path / "j17.npz", keypoints=keypoints[:2], K=K[:2])
    base = ["--checkpoint", run_dir, "--output", tmp_path / "out.json"]
    size = ["--image-size", 1000, 1000]
    cases = [
        (["--input", tmp_path / "j16.npz", *size], "lifts skeleton 'h36m17' with J=17"),
        (["--input", tmp_path / "j16.npz", "--format", "coco17", *size], r"coco17: expected keypoints .*17, 2\]"),
        (["--input", tmp_path / "j17.npz", "--intrinsics", 1000, 1000, 500], "4 numbers"),
        (["--input", tmp_path / "j17.npz", "--intrinsics", 1000, 1000, 500, 500], "camera per pose"),
        (["--input", tmp_path / "missing.json"], "does not exist"),
        (["--input", tmp_path / "j17.npz", "--output", tmp_path / "out.xlsx"], "suffix"),
    ]  # fmt: skip
    for args, message in cases:
        with pytest.raises(SystemExit, match=message):
            _cli(*base, *args)
    # Run directories: missing, without checkpoints, with an empty checkpoints folder.
    incomplete = tmp_path / "incomplete"
    incomplete.mkdir()
    shutil.copy(run_dir / "config.json", incomplete)
    bare = tmp_path / "bare"
    bare.mkdir()
    runs = [(tmp_path / "nowhere", "does not exist"), (incomplete, "no checkpoints/"), (bare, "no checkpoints/")]
    for run, message in runs:
        with pytest.raises(SystemExit, match=message):
            _cli("--checkpoint", run, "--input", tmp_path / "j17.npz", "--output", tmp_path / "o.json")
    # The output inside the run folder given as --checkpoint: the run is an input (issue 42).
    with pytest.raises(SystemExit, match="is inside this command's input folder"):
        _cli("--checkpoint", run_dir, "--input", tmp_path / "j17.npz", "--output", run_dir / "o.json")
    (incomplete / "checkpoints").mkdir()
    with pytest.raises(SystemExit, match="holds no checkpoint"):
        _cli("--checkpoint", incomplete / "checkpoints", "--input", tmp_path / "j17.npz", "--output", tmp_path / "o.npz")


def _newest_step(checkpoints) -> pathlib.Path:
    return max((p for p in checkpoints.iterdir() if p.name.isdigit()), key=lambda p: int(p.name))


def test_a_checkpoint_alone_rebuilds_its_lifter(trained_run, lifter, tmp_path):
    """The checkpoint records its network: without config.json (or anything else of the run) the
    checkpoints folder loads to the same lifter."""
    checkpoints = tmp_path / "copy" / "checkpoints"
    shutil.copytree(trained_run[0] / "checkpoints", checkpoints)
    alone = inference.load(checkpoints)
    assert (alone.skeleton, alone.model_config, alone.step) == (lifter.skeleton, lifter.model_config, lifter.step)
    keypoints, confidence, K = (a[:64] for a in views(trained_run[1]))
    np.testing.assert_array_equal(alone.predict(keypoints, K, confidence), lifter.predict(keypoints, K, confidence))
    # Only the variables are restored: a step whose optimizer state is unreadable still loads.
    shutil.rmtree(_newest_step(checkpoints) / "state")
    assert inference.load(checkpoints).step == lifter.step


def test_a_checkpoint_without_a_matching_lifter_record_is_refused(trained_run, tmp_path):
    checkpoints = tmp_path / "checkpoints"
    shutil.copytree(trained_run[0] / "checkpoints", checkpoints)
    steps = sorted((p for p in checkpoints.iterdir() if p.name.isdigit()), key=lambda p: int(p.name))
    for step in steps:  # a record whose network is not the one saved
        record_file = next((step / "lifter").glob("*"))
        record = json.loads(record_file.read_text())
        record["model"]["width"] = 32
        record_file.write_text(json.dumps(record))
    with pytest.raises(checkpoint.CheckpointError, match="do not match the network of its 'lifter' item"), pytest.warns(UserWarning):
        inference.load(checkpoints)
    shutil.rmtree(steps[-1] / "lifter")  # written before checkpoints recorded their network
    with pytest.raises(checkpoint.CheckpointError, match="no 'lifter' item"), pytest.warns(UserWarning):
        inference.load(checkpoints)


def test_cli_help_documents_every_flag(capsys):
    assert_help_documents_every_field(capsys, predict.main, predict.PredictArgs)
