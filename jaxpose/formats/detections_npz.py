"""``detections.npz``: one recording's synchronized multi-view 2D detections, as any detector pipeline
can write them.

Rig calibration reads one (`python -m jaxpose.calibrate`, `jaxpose.calibration.read_detections_npz`),
and so does a rig project, as a recording (`jaxpose.rig`).  Its arrays:

- ``keypoints`` f32[N, C, J, 2]: pixels as detected (distorted); N synchronized frames, C views; or,
  with several people, f32[N, C, P, J, 2]: up to P people per view, in any order in each view (a rig
  project matches them across views, `jaxpose.rig.association`); a slot without a person has confidence 0;
- ``confidence`` f32[N, C, J] (optional, default 1), f32[N, C, P, J] with a person axis: finite and >= 0,
  0 = not detected; a keypoint whose confidence is positive must be finite;
- ``camera_names`` str[C]: distinct;
- ``frames`` int[N] (optional, default 0 .. N-1): distinct frame numbers;
- ``image_size`` int[C, 2]: (width, height) pixels, positive; calibration needs it, and so does a rig
  project whose rig is recovered from its recordings;
- ``skeleton``: the keypoints' layout, a name of `jaxpose.layouts.LAYOUTS` (a jaxpose skeleton such as
  "h36m16", "h36m17" or "coco17", or a detector's layout such as "body25"); calibration needs a
  jaxpose skeleton, a rig project without it infers the layout from J;
- ``K`` f32[C, 3, 3], ``dist`` f32[C, 5] (k1, k2, p1, p2, k3; needs K) and ``distortion_model``
  ("opencv", the default, or "h36m"), all optional, where the intrinsics are known.

Calibration reads one person per view (no person axis). `read` checks all of this (`check`, which in-memory detections go through too), and every refusal is
a `DataFormatError` naming the file and the array.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.camera_file import DISTORTION_MODELS
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_npz_arrays
from jaxpose.formats.frame_numbers import check_frame_numbers
from jaxpose.layouts import LAYOUTS, layout_joint_names

REQUIRED = ("keypoints", "camera_names")


@dataclasses.dataclass(frozen=True)
class MultiViewDetections:
    """A ``detections.npz`` as read and checked (the arrays of the module docstring, numpy)."""

    keypoints: np.ndarray  # f32[N, C, J, 2], or f32[N, C, P, J, 2] where `read` allowed a person axis
    confidence: np.ndarray  # f32[N, C, J] or f32[N, C, P, J]
    camera_names: tuple[str, ...]
    frames: np.ndarray  # int64[N]
    image_size: np.ndarray | None  # int64[C, 2]
    skeleton: str | None
    K: np.ndarray | None  # f64[C, 3, 3]
    dist: np.ndarray | None  # f64[C, 5]
    distortion_model: str
    source: str


def check(
    source: str,
    keypoints: np.ndarray,
    confidence: np.ndarray,
    camera_names: Sequence[str],
    *,
    skeleton: str | None = None,
    joint_names: Sequence[str] | None = None,
    image_size: np.ndarray | None = None,
    K: np.ndarray | None = None,
    dist: np.ndarray | None = None,
    distortion_model: str = "opencv",
    people: bool = False,
) -> None:
    """Refuse detections that break the rules of the module docstring, naming `source` and the field
    at fault.  With `joint_names` (those of the layout `skeleton`), J must be their number; `people`:
    a person axis (keypoints [N, C, P, J, 2]) is allowed."""

    def fail(field: str, expected: str, found: str):
        raise DataFormatError(f"{source}, field {field!r}", expected, found)

    if keypoints.ndim not in ((4, 5) if people else (4,)) or keypoints.shape[-1] != 2:
        shapes = "[N, C, J, 2] or [N, C, P, J, 2] (P people per view)" if people else "[N, C, J, 2] (one person per view)"
        fail("keypoints", f"shape {shapes}, pixels", f"shape {keypoints.shape}")
    N, C, J = keypoints.shape[0], keypoints.shape[1], keypoints.shape[-2]
    if joint_names is not None and J != len(joint_names):
        fail("keypoints", f"{len(joint_names)} joints of skeleton {skeleton!r}", f"J = {J}")
    if confidence.shape != keypoints.shape[:-1]:
        axes = "[N, C, P, J]" if keypoints.ndim == 5 else "[N, C, J]"
        fail("confidence", f"shape {axes} = {keypoints.shape[:-1]} as keypoints", f"shape {confidence.shape}")
    if not np.all(np.isfinite(confidence)) or np.any(confidence < 0):
        fail("confidence", "finite values >= 0", "NaN, infinite or negative values")
    bad = (confidence > 0) & ~np.all(np.isfinite(keypoints), axis=-1)
    if bad.any():
        n, c, *_, j = np.argwhere(bad)[0]
        fail(
            "keypoints",
            "finite pixels wherever confidence > 0 (give a missing joint confidence 0)",
            f"{int(bad.sum())} NaN/infinite keypoints with positive confidence, the first at frame {n},"
            f" view {c} ({camera_names[c] if c < len(camera_names) else c}),"
            f" joint {joint_names[j] if joint_names is not None else int(j)!r}",
        )
    if len(camera_names) != C:
        fail("camera_names", f"{C} names (one per view)", f"{len(camera_names)}")
    if len(set(camera_names)) != C:
        fail("camera_names", "distinct names", f"{list(camera_names)}")
    if image_size is not None and (image_size.shape != (C, 2) or np.any(image_size <= 0)):
        fail("image_size", f"[C, 2] = {(C, 2)} positive (width, height) pixels", f"{image_size.tolist()}")
    if K is not None and (K.shape != (C, 3, 3) or not np.all(np.isfinite(K))):
        fail("K", f"finite [C, 3, 3] = {(C, 3, 3)} intrinsics", f"shape {K.shape}, finite: {bool(np.all(np.isfinite(K)))}")
    if dist is not None:
        if K is None:
            fail("dist", "intrinsics K as well (distortion is applied in K's normalized coordinates)", "no K")
        if dist.shape != (C, 5) or not np.all(np.isfinite(dist)):
            fail("dist", f"finite [C, 5] = {(C, 5)} (k1, k2, p1, p2, k3)", f"shape {dist.shape}, finite: {bool(np.all(np.isfinite(dist)))}")
    if distortion_model not in DISTORTION_MODELS:
        fail("distortion_model", f"one of {DISTORTION_MODELS}", repr(distortion_model))


def read_camera_names(path: str | Path) -> tuple[str, ...]:
    """The ``camera_names`` of a ``detections.npz``, reading no other array (`read` reads and checks them all)."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            names = archive["camera_names"]
    except Exception:  # a file numpy cannot read, or no camera_names: `read` says which, naming the file
        return read(path).camera_names
    return tuple(str(name) for name in np.atleast_1d(names))


def read(path: str | Path, required: Sequence[str] = (), people: bool = False) -> MultiViewDetections:
    """Read and check a ``detections.npz``; `required` names optional arrays the caller needs; `people`:
    a person axis is allowed (a rig project's recordings; calibration takes one person per view)."""
    path = Path(path)
    arrays = read_npz_arrays(path, "synchronized multi-view detections (a detections.npz)")
    missing = [name for name in (*REQUIRED, *required) if name not in arrays]
    if missing:
        raise DataFormatError(
            path,
            f"arrays {missing} of a detections.npz (keypoints [N, C, J, 2], camera_names [C]; calibration needs"
            " image_size [C, 2] and skeleton too)",
            f"only {sorted(arrays)}",
        )
    skeleton = str(arrays["skeleton"]) if "skeleton" in arrays else None
    if skeleton is not None and skeleton not in LAYOUTS:
        raise DataFormatError(f"{path}, array 'skeleton'", f"one of {list(LAYOUTS)}", repr(skeleton))
    keypoints = np.asarray(arrays["keypoints"], np.float32)
    confidence = arrays.get("confidence")
    confidence = np.ones(keypoints.shape[:-1], np.float32) if confidence is None else np.asarray(confidence, np.float32)
    camera_names = tuple(str(name) for name in np.atleast_1d(arrays["camera_names"]))
    image_size = None if "image_size" not in arrays else np.asarray(arrays["image_size"]).astype(np.int64)
    K = None if "K" not in arrays else np.asarray(arrays["K"], np.float64)
    dist = None if "dist" not in arrays else np.asarray(arrays["dist"], np.float64)
    distortion_model = str(arrays.get("distortion_model", "opencv"))
    joint_names = None if skeleton is None else layout_joint_names(skeleton)
    check(str(path), keypoints, confidence, camera_names, skeleton=skeleton, joint_names=joint_names, image_size=image_size,
          K=K, dist=dist, distortion_model=distortion_model, people=people)  # fmt: skip
    N = len(keypoints)
    frames = np.asarray(arrays.get("frames", np.arange(N)), np.int64)
    if frames.shape != (N,) or len(np.unique(frames)) != N:
        raise DataFormatError(f"{path}, field 'frames'", f"{N} distinct frame numbers", f"shape {frames.shape}")
    check_frame_numbers(frames, f"{path}, field 'frames'", [f"row {row}" for row in range(N)])
    return MultiViewDetections(
        keypoints=keypoints, confidence=confidence, camera_names=camera_names, frames=frames, image_size=image_size,
        skeleton=skeleton, K=K, dist=dist, distortion_model=distortion_model, source=str(path),
    )  # fmt: skip
