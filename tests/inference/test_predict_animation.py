"""`python -m jaxpose.predict --animation`: a sequence of detections in, a GIF or MP4 of the 2D input
beside the lifted 3D pose out, one frame per image id in sequence order."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from matplotlib import animation
from PIL import Image, ImageSequence

from detection_helpers import body25_from_coco, coco_from_h36m, views
from jaxpose import predict, viz
from jaxpose.serving import lifting_figures
from jaxpose.skeleton import COCO_17

IMAGE_SIZE = (1000, 1000)  # the synthetic rig's images


def _cli(*args) -> np.ndarray:
    return predict.main([str(a) for a in args])


def _gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as gif:
        return [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(gif)]


def _all_differ(frames: list[np.ndarray]) -> bool:
    return all(not np.array_equal(a, b) for i, a in enumerate(frames) for b in frames[i + 1 :])


def _write_coco_results(trained_run, path, image_ids) -> None:
    """One COCO-17 pose per image id, each from another test sample (so the skeleton moves); the one at
    index 1 has no left hip, so it cannot be lifted."""
    keypoints = views(trained_run[1])[0]
    coco = coco_from_h36m(keypoints[: len(image_ids)])
    scores = np.full(coco.shape[:2], 0.9, np.float32)
    scores[1, COCO_17.index("left_hip")] = 0.0
    triplets = np.concatenate([coco, scores[..., None]], axis=-1).reshape(len(coco), -1)
    entries = [
        {"image_id": i, "category_id": 1, "keypoints": t.tolist(), "score": 0.9} for i, t in zip(image_ids, triplets)
    ]
    path.write_text(json.dumps(entries))


def test_gif_of_coco_results_has_a_frame_per_image_id(trained_run, tmp_path):
    image_ids = [10, 9, 9, 2, 1]  # image 9 holds two people, one not liftable
    _write_coco_results(trained_run, tmp_path / "results.json", image_ids)
    _cli("--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--output", tmp_path / "poses.json",
         "--image-size", *IMAGE_SIZE, "--animation", tmp_path / "clip.gif", "--fps", 5)  # fmt: skip
    frames = _gif_frames(tmp_path / "clip.gif")
    assert len(frames) == 4 and _all_differ(frames)
    assert frames[0].shape == (400, 800, 3)  # 2D and 3D panels side by side
    with Image.open(tmp_path / "clip.gif") as gif:
        assert gif.info["duration"] == 200  # ms, at --fps 5


def test_frames_in_sequence_order_one_pose_each():
    image_ids = [10, 9, 9, 2, "b", "a", 9]
    confidence = np.array([0.9, 0.5, 0.8, 0.9, 0.9, 0.9, 0.95])[:, None] * np.ones((1, 17))
    poses = np.zeros((7, 17, 3))
    poses[6] = np.nan  # the best-scored pose of image 9, but not lifted
    frames, shown = lifting_figures.animation_frames(image_ids, confidence, np.isfinite(poses).all((1, 2)), None)
    assert frames == [2, 9, 10, "a", "b"]  # numbers numerically, then names
    assert shown == [3, 2, 0, 5, 4]
    frames, shown = lifting_figures.animation_frames(["f0", "f2"], confidence[:2], np.isfinite(poses[:2]).all((1, 2)), ["f0", "f1", "f2"])
    assert frames == ["f0", "f1", "f2"] and shown == [0, None, 1]  # OpenPose: an empty frame stays


def test_gif_of_an_openpose_folder_keeps_its_empty_frames(trained_run, tmp_path):
    keypoints = views(trained_run[1])[0]
    body25 = body25_from_coco(coco_from_h36m(keypoints[:3]), 0.8)
    folder = tmp_path / "openpose"
    folder.mkdir()
    people_per_frame = {"clip_000000000000": [0], "clip_000000000001": [], "clip_000000000002": [1, 2]}
    for stem, people in people_per_frame.items():
        document = {"version": 1.3, "people": [{"pose_keypoints_2d": body25[p].ravel().tolist()} for p in people]}
        (folder / f"{stem}_keypoints.json").write_text(json.dumps(document))
    # No --image-size: the camera is given, and the 2D panel frames the keypoints of the whole sequence.
    _cli("--checkpoint", trained_run[0], "--input", folder, "--output", tmp_path / "poses.npz", "--format", "body25",
         "--intrinsics", 1150, 1150, 500, 500, "--animation", tmp_path / "clip.gif")  # fmt: skip
    frames = _gif_frames(tmp_path / "clip.gif")
    assert len(frames) == 3 and _all_differ(frames)


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # read_frames starts ffmpeg, as the writer does
def test_mp4(trained_run, tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="reading an .mp4 back needs the 'video' extra")
    image_ids = [3, 1, 2]
    _write_coco_results(trained_run, tmp_path / "results.json", image_ids)
    _cli("--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--output", tmp_path / "poses.json",
         "--image-size", *IMAGE_SIZE, "--animation", tmp_path / "clip.mp4")  # fmt: skip
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "clip.mp4"))
    meta = next(reader)
    frames = [np.frombuffer(frame, np.uint8) for frame in reader]
    assert meta["size"] == (800, 400) and meta["fps"] == 10
    assert len(frames) == len(image_ids) and _all_differ(frames)


def test_mp4_without_an_encoder_says_what_to_install(trained_run, tmp_path, monkeypatch):
    monkeypatch.setattr(animation.FFMpegWriter, "isAvailable", classmethod(lambda cls: False))  # none on PATH
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # and the video extra not installed
    _write_coco_results(trained_run, tmp_path / "results.json", [1, 2])
    base = ["--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--output", tmp_path / "poses.json"]
    with pytest.raises(SystemExit, match=r"--animation .*clip\.mp4: .*ffmpeg.*pip install 'jaxpose\[video\]'"):
        _cli(*base, "--animation", tmp_path / "clip.mp4")
    assert not (tmp_path / "poses.json").exists()  # refused before lifting
    with pytest.raises(ValueError, match="ffmpeg"):
        viz.check_animation_path(tmp_path / "clip.mp4")


def test_animation_flag_errors(trained_run, tmp_path):
    _write_coco_results(trained_run, tmp_path / "results.json", [1, 2])
    base = ["--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--output", tmp_path / "poses.json"]
    with pytest.raises(SystemExit, match=r"--animation .*clip\.avi: the suffix must be one of \('\.gif', '\.mp4'\)"):
        _cli(*base, "--animation", tmp_path / "clip.avi")
    with pytest.raises(SystemExit, match="fps must be a positive finite number, got 0.0"):
        _cli(*base, "--animation", tmp_path / "clip.gif", "--fps", 0)
