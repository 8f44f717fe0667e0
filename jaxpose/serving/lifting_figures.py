"""The figures `jaxpose.predict` draws of what it lifted: a PNG per pose (`--plot`) and an animation of
one pose per frame (`--animation`), each written atomically."""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Any

import numpy as np

from jaxpose import viz
from jaxpose.formats import detection_file
from jaxpose.formats.outputs import atomic_output

PLOT_PATTERN = "lifting_*.png"


@dataclasses.dataclass(frozen=True)
class LiftedInput:
    """The input as the lifter took it and the poses it gave, a row per input pose, for the figures."""

    keypoints: np.ndarray
    """f32[N, J, 2] pixels in the lifter's joints."""
    confidence: np.ndarray
    """f32[N, J]: 0 where a joint was lifted as missing."""
    poses: np.ndarray
    """f32[N, J, 3] mm; NaN rows were not lifted."""
    image_ids: list[Any]
    frame_ids: list[Any] | None
    """As `detection_file.DetectionFile.frame_ids`."""


def save_plots(
    directory: pathlib.Path, lifted: LiftedInput, skeleton, image_size: tuple[float, float] | None, count: int
) -> list[pathlib.Path]:
    """`viz.figure_lifting` PNGs of the first `count` lifted poses, named by their input index."""
    keypoints, confidence, poses = lifted.keypoints, lifted.confidence, lifted.poses
    saved = []
    for i in np.flatnonzero(np.isfinite(poses).all((1, 2)))[:count]:
        title = f"image {lifted.image_ids[i]} (pose {i})"
        figure = viz.figure_lifting(keypoints[i], poses[i], skeleton, image_size, title, confidence[i])
        path = directory / PLOT_PATTERN.replace("*", f"{i:05d}")
        with atomic_output(path) as temporary:
            viz.save_figure(figure, temporary)
        saved.append(path)
    return saved


def animation_frames(
    image_ids: list[Any], confidence: np.ndarray, lifted: np.ndarray, frame_ids: list[Any] | None
) -> tuple[list[Any], list[int | None]]:
    """The frames in sequence order and the pose each one shows (None: no pose in that frame).

    A frame with several poses shows the one with the highest mean keypoint confidence, lifted ones
    (bool[N] `lifted`) first.
    """
    rank = list(zip(np.asarray(lifted, bool), confidence.mean(1)))
    shown: dict[Any, int] = {}
    for index, image_id in enumerate(image_ids):
        if image_id not in shown or rank[index] > rank[shown[image_id]]:
            shown[image_id] = index
    frames = frame_ids if frame_ids is not None else sorted(shown, key=detection_file.sequence_order)
    return frames, [shown.get(frame) for frame in frames]


def save_animation(
    path: pathlib.Path, lifted: LiftedInput, skeleton, image_size: tuple[float, float] | None, fps: float
) -> pathlib.Path:
    """`viz.save_pose_animation` of one pose per frame (`animation_frames`); a frame without one is blank."""
    keypoints, confidence, poses = lifted.keypoints, lifted.confidence, lifted.poses
    frames, shown = animation_frames(lifted.image_ids, confidence, np.isfinite(poses).all((1, 2)), lifted.frame_ids)
    blank = len(poses)  # the index of a row appended for frames without a pose
    rows = [blank if index is None else index for index in shown]
    joints = keypoints.shape[1]
    keypoints = np.concatenate([keypoints, np.full((1, joints, 2), np.nan, np.float32)])[rows]
    confidence = np.concatenate([confidence, np.zeros((1, joints), np.float32)])[rows]
    poses = np.concatenate([poses, np.full((1, joints, 3), np.nan, np.float32)])[rows]
    titles = [f"image {frame}" + (" (no pose)" if index is None else "") for frame, index in zip(frames, shown)]
    with atomic_output(path) as temporary:
        viz.save_pose_animation(temporary, poses, skeleton, keypoints, confidence, image_size, titles, fps)
    return path
