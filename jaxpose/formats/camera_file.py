"""The project's camera file: one JSON file holding the calibrated rig of every subject.

Schema (version 1)::

    {
      "format": "jaxpose-cameras",
      "version": 1,
      "comment": "...",                      # optional free text, e.g. how the rig was obtained
      "distortion_model": "opencv" | "h36m" | "fisheye",
      "subjects": {
        "S1": [
          {
            "name": "54138969",
            "K": [[fx, skew, cx], [0, fy, cy], [0, 0, 1]],   # pixels
            "R": [[...], [...], [...]],      # world-to-camera rotation: x_cam = R @ x_world + t
            "t": [tx, ty, tz],               # millimetres
            "dist": [k1, k2, p1, p2, k3],    # or null for a pinhole camera
            "image_size": [width, height]    # pixels; optional (null or absent when unknown)
          },
          ...                                # one entry per camera, in the rig's view order
        ],
        ...
      }
    }

`distortion_model` says how `dist` is applied (see `jaxpose.camera`): "opencv" is OpenCV's
Brown-Conrady model, "h36m" the variant Human3.6M was calibrated with, its `dist` holding
(k1, k2, p[0], p[1], k3) of `cameras.h5`, and "fisheye" OpenCV's fisheye model, its `dist` holding
(k1, k2, k3, k4, 0).  The camera order of a subject is its view order.

Command line::

    python -m jaxpose.formats.camera_file convert cameras.h5 cameras.json   # Human3.6M calibration (--overwrite to replace)
    python -m jaxpose.formats.camera_file check cameras.json                # validate and summarize
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from jaxpose.camera import Cameras
from jaxpose.formats import h36m_cameras
from jaxpose.formats.h36m_cameras import H36M_IMAGE_SIZES
from jaxpose.formats.rig_cameras import (
    CalibrationFormat, CalibrationUnit, RigCalibration, check_distinct_centres, check_intrinsics, check_rotation,
    known_image_sizes, millimetres_by_definition, pick_subject,
)  # fmt: skip
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_json
from jaxpose.formats.outputs import OutputError, atomic_output, check_output

FORMAT_NAME = "jaxpose-cameras"
FORMAT_VERSION = 1
DISTORTION_MODELS = ("opencv", "h36m", "fisheye")
# is_camera_file reads no more of a JSON file than this.
_HEAD_BYTES = 4096

SubjectCameras = tuple[list[str], Cameras]
ImageSize = tuple[int, int] | None


def load_cameras(path: str | Path, dtype: type = np.float32) -> dict[str, SubjectCameras]:
    """Read and validate a camera file: subject -> (camera names, numpy `Cameras` [C] of `dtype`).

    float32 is what the data sets train with; np.float64 keeps the file's values exactly
    (`read_rig_calibration`).  If any camera of the file has `dist`, the cameras whose `dist` is
    null get zeros (no distortion) so that every subject's `Cameras` has the same structure.
    """
    return _parse(read_json(Path(path), "a jaxpose camera file"), Path(path), dtype)[0]


def load_image_sizes(path: str | Path) -> dict[str, list[ImageSize]]:
    """The `image_size` of every camera, (width, height) or None, per subject in camera order."""
    return _parse(read_json(Path(path), "a jaxpose camera file"), Path(path))[1]


def save_cameras(
    path: str | Path,
    rigs: Mapping[str, tuple[Sequence[str], Cameras]],
    image_sizes: Mapping[str, Sequence[ImageSize]] | None = None,
    comment: str | None = None,
) -> None:
    """Write rigs (subject -> (camera names, `Cameras` [C])) as a camera file, with an optional comment.

    All rigs must share one distortion model.  The document is validated before it is written, so
    this never produces a file that `load_cameras` rejects.
    """
    path = Path(path)
    models = {cameras.distortion_model for _, cameras in rigs.values()}
    if len(models) > 1:
        raise ValueError(f"save_cameras: rigs mix distortion models {sorted(models)}; a camera file holds one")
    subjects = {}
    for subject, (names, cameras) in rigs.items():
        sizes = (image_sizes or {}).get(subject) or [None] * len(names)
        subjects[subject] = [
            {
                "name": name,
                "K": np.asarray(cameras.K[c], np.float64).tolist(),
                "R": np.asarray(cameras.R[c], np.float64).tolist(),
                "t": np.asarray(cameras.t[c], np.float64).tolist(),
                "dist": None if cameras.dist is None else np.asarray(cameras.dist[c], np.float64).tolist(),
                "image_size": None if sizes[c] is None else [int(sizes[c][0]), int(sizes[c][1])],
            }
            for c, name in enumerate(names)
        ]
    document = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "distortion_model": models.pop() if models else "opencv",
        "subjects": subjects,
    }
    if comment is not None:
        document["comment"] = comment
    _parse(document, path)
    path.write_text(json.dumps(document, indent=1) + "\n")


def read_calibration(path: str | Path) -> dict[str, SubjectCameras]:
    """A calibration of either kind, float32: a jaxpose camera file (.json) or Human3.6M's cameras.h5."""
    path = Path(path)
    return load_cameras(path) if path.suffix == ".json" else h36m_cameras.read_h36m_cameras(path)


def convert_h36m_cameras(cameras_h5: str | Path, out_json: str | Path) -> None:
    """Convert Human3.6M's `cameras.h5` into a camera file (exact float64 values, known image sizes)."""
    rigs = h36m_cameras.read_h36m_cameras(cameras_h5, np.float64)
    sizes = {subject: [H36M_IMAGE_SIZES.get(name) for name in names] for subject, (names, _) in rigs.items()}
    save_cameras(out_json, rigs, sizes)


def read_rig(path: Path, unit: CalibrationUnit, subject: str | None) -> RigCalibration:
    """One subject's rig of a camera file, float64, in millimetres whatever `unit` says."""
    millimetres_by_definition(path, unit)
    rigs = load_cameras(path, np.float64)
    subject = pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    check_distinct_centres(str(path), names, cameras.R, cameras.t)
    return RigCalibration(tuple(names), cameras, known_image_sizes(load_image_sizes(path)[subject]), str(path), "mm")


def is_camera_file(path: Path) -> bool:
    """Whether `path` is a jaxpose camera file, from its first bytes: other JSON files, such as a
    detector's output, are not parsed."""
    if path.suffix.lower() != ".json":
        return False
    try:
        with path.open("rb") as file:
            head = file.read(_HEAD_BYTES).decode("utf-8", errors="replace").lstrip("\ufeff \t\r\n")
    except OSError:
        return False
    return head.startswith("{") and re.search(rf'"format"\s*:\s*"{re.escape(FORMAT_NAME)}"', head) is not None


FORMAT = CalibrationFormat("a jaxpose camera file .json", (".json",), is_camera_file, read_rig)


def _parse(
    document, path: Path, dtype: type = np.float64
) -> tuple[dict[str, SubjectCameras], dict[str, list[ImageSize]]]:
    """Validate a camera-file document; rigs of `dtype` and image sizes per subject."""
    if not isinstance(document, dict) or document.get("format") != FORMAT_NAME:
        found = document.get("format") if isinstance(document, dict) else type(document).__name__
        raise DataFormatError(path, f'a JSON object with "format": "{FORMAT_NAME}"', repr(found))
    if document.get("version") != FORMAT_VERSION:
        raise DataFormatError(path, f'"version": {FORMAT_VERSION}', repr(document.get("version")))
    if not isinstance(document.get("comment", ""), str):
        raise DataFormatError(path, '"comment": a string, if present', repr(document["comment"])[:200])
    model = document.get("distortion_model")
    if model not in DISTORTION_MODELS:
        raise DataFormatError(path, f'"distortion_model" one of {list(DISTORTION_MODELS)}', repr(model))
    subjects = document.get("subjects")
    if not isinstance(subjects, dict) or not subjects:
        raise DataFormatError(path, '"subjects": a non-empty object subject -> list of cameras', repr(subjects))

    entries = {subject: _parse_subject(path, subject, cameras) for subject, cameras in subjects.items()}
    has_dist = any(entry["dist"] is not None for camera_list in entries.values() for entry in camera_list)
    rigs, sizes = {}, {}
    for subject, camera_list in entries.items():
        dist = None
        if has_dist:
            dist = np.array([np.zeros(5) if e["dist"] is None else e["dist"] for e in camera_list], dtype)
        rigs[subject] = (
            [e["name"] for e in camera_list],
            Cameras(
                K=np.array([e["K"] for e in camera_list], dtype),
                R=np.array([e["R"] for e in camera_list], dtype),
                t=np.array([e["t"] for e in camera_list], dtype),
                dist=dist,
                distortion_model=model,
            ),
        )
        sizes[subject] = [e["image_size"] for e in camera_list]
    return rigs, sizes


def _parse_subject(path: Path, subject: str, cameras) -> list[dict]:
    if not isinstance(cameras, list) or not cameras:
        raise DataFormatError(f"{path}: subject {subject!r}", "a non-empty list of cameras", repr(cameras)[:200])
    parsed, names = [], set()
    for index, camera in enumerate(cameras):
        where = f"{path}: subject {subject!r}, camera {index}"
        if not isinstance(camera, dict):
            raise DataFormatError(where, "a JSON object", repr(camera)[:200])
        name = camera.get("name")
        if not isinstance(name, str) or not name:
            raise DataFormatError(where, 'field "name": a non-empty string', repr(name))
        if name in names:
            raise DataFormatError(where, "camera names unique within a subject", f"{name!r} twice")
        names.add(name)
        where = f"{path}: subject {subject!r}, camera {index} ({name!r})"
        K = _matrix(camera, "K", (3, 3), where)
        check_intrinsics(K, f"{where}, field 'K'")
        R = _matrix(camera, "R", (3, 3), where)
        check_rotation(R, f"{where}, field 'R'")
        dist = None if camera.get("dist") is None else _matrix(camera, "dist", (5,), where)
        size = camera.get("image_size")
        if size is not None and not (
            isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)
        ):
            expected = "[width, height] as positive integers, or null"
            raise DataFormatError(f"{where}, field 'image_size'", expected, repr(size))
        parsed.append(
            {
                "name": name,
                "K": K,
                "R": R,
                "t": _matrix(camera, "t", (3,), where),
                "dist": dist,
                "image_size": None if size is None else (size[0], size[1]),
            }
        )
    return parsed


def _matrix(camera: dict, field: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A finite float64 array of exactly `shape` from a camera entry."""
    value = camera.get(field)
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != shape or not np.all(np.isfinite(array)):
        expected = f"{'x'.join(map(str, shape))} finite numbers"
        raise DataFormatError(f"{where}, field {field!r}", expected, repr(value)[:200])
    return array


def select_views(
    calibration: dict[str, tuple[list[str], Cameras]], path, subject: str, camera_names: tuple[str, ...]
) -> Cameras:
    """One subject's cameras in the order `camera_names` (the data set's view order).

    `calibration` is what `load_cameras` returns; a missing subject or camera raises
    `DataFormatError` naming `path`.
    """
    if subject not in calibration:
        raise DataFormatError(path, f"cameras of subject {subject!r}", f"subjects {sorted(calibration)}")
    names, cameras = calibration[subject]
    if not set(camera_names) <= set(names):
        raise DataFormatError(path, f"subject {subject!r}: cameras {list(camera_names)}", f"cameras {names}")
    return cameras[np.array([names.index(camera) for camera in camera_names])]


@dataclasses.dataclass(frozen=True)
class Convert:
    """Convert Human3.6M's cameras.h5 into a jaxpose camera file."""

    cameras_h5: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="CAMERAS_H5")]
    """Human3.6M cameras.h5 (from h36m.zip)."""
    out_json: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="OUT_JSON")]
    """The camera file to write (through a temporary file renamed into place)."""
    overwrite: bool = False
    """Replace OUT_JSON if it exists; without it the command stops.  CAMERAS_H5 is never replaced."""


@dataclasses.dataclass(frozen=True)
class Check:
    """Validate a camera file and list its subjects and cameras."""

    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="CAMERAS_JSON")]
    """The camera file to check."""


def main(argv: Sequence[str] | None = None) -> None:
    command = tyro.cli(
        Annotated[Convert, tyro.conf.subcommand("convert")] | Annotated[Check, tyro.conf.subcommand("check")],
        args=argv,
        prog="python -m jaxpose.formats.camera_file",
        description="Convert and check jaxpose camera files.",
    )
    try:
        if isinstance(command, Convert):
            path = check_output(command.out_json, command.overwrite, [command.cameras_h5], flag="OUT_JSON")
            with atomic_output(path) as temporary:
                convert_h36m_cameras(command.cameras_h5, temporary)
        else:
            path = command.path
        for subject, (names, cameras) in load_cameras(path).items():
            distortion = "none" if cameras.dist is None else cameras.distortion_model
            print(f"{subject}: {len(names)} cameras {names}, distortion {distortion}")
    except (DataFormatError, OutputError) as error:
        raise SystemExit(f"error: {error}") from None


if __name__ == "__main__":
    main()
