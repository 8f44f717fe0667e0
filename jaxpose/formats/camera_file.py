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

    python -m jaxpose.formats.camera_file convert cameras.h5 cameras.json   # Human3.6M calibration
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
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import h5_dataset, open_h5, read_json

FORMAT_NAME = "jaxpose-cameras"
FORMAT_VERSION = 1
DISTORTION_MODELS = ("opencv", "h36m", "fisheye")

# Video resolution (width, height) of the four Human3.6M cameras; cameras.h5 does not store it.
H36M_IMAGE_SIZES = {
    "54138969": (1000, 1002),
    "55011271": (1000, 1000),
    "58860488": (1000, 1000),
    "60457274": (1000, 1002),
}

SubjectCameras = tuple[list[str], Cameras]
ImageSize = tuple[int, int] | None


def load_cameras(path: str | Path) -> dict[str, SubjectCameras]:
    """Read and validate a camera file: subject -> (camera names, float32 numpy `Cameras` [C]).

    If any camera of the file has `dist`, the cameras whose `dist` is null get zeros (no
    distortion) so that every subject's `Cameras` has the same structure.
    """
    rigs, _ = _parse(read_json(Path(path), "a jaxpose camera file"), Path(path))
    return {subject: (names, _as_float32(cameras)) for subject, (names, cameras) in rigs.items()}


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


def read_h36m_cameras(path: str | Path) -> dict[str, SubjectCameras]:
    """Human3.6M's `cameras.h5` as subject ('S1') -> (camera names, float32 numpy `Cameras` [4]).

    The file stores, per `subject{S}/camera{i}`, a rotation R and the camera centre T with
    `x_cam = R^T (X - T)` as h5py reads them (docs/conventions.md), so our world-to-camera rotation
    is R^T and our translation -R^T T.  Distortion uses the "h36m" model, dist = (k1, k2, p[0],
    p[1], k3).  Cameras are in the file's camera-number order.
    """
    return {subject: (names, _as_float32(cameras)) for subject, (names, cameras) in _read_h36m(Path(path)).items()}


def read_calibration(path: str | Path) -> dict[str, SubjectCameras]:
    """A calibration of either kind: a jaxpose camera file (.json) or Human3.6M's cameras.h5."""
    path = Path(path)
    return load_cameras(path) if path.suffix == ".json" else read_h36m_cameras(path)


def convert_h36m_cameras(cameras_h5: str | Path, out_json: str | Path) -> None:
    """Convert Human3.6M's `cameras.h5` into a camera file (exact float64 values, known image sizes)."""
    rigs = _read_h36m(Path(cameras_h5))
    sizes = {subject: [H36M_IMAGE_SIZES.get(name) for name in names] for subject, (names, _) in rigs.items()}
    save_cameras(out_json, rigs, sizes)


def _as_float32(cameras: Cameras) -> Cameras:
    return cameras.replace(
        K=cameras.K.astype(np.float32),
        R=cameras.R.astype(np.float32),
        t=cameras.t.astype(np.float32),
        dist=None if cameras.dist is None else cameras.dist.astype(np.float32),
    )


def _numbered(group, prefix: str) -> list[tuple[int, str]]:
    """(number, key) of the members named `<prefix><number>`, by number."""
    found = ((re.fullmatch(rf"{prefix}(\d+)", key), key) for key in group.keys())
    return sorted((int(match.group(1)), key) for match, key in found if match)


def _read_h36m(path: Path) -> dict[str, SubjectCameras]:
    """`cameras.h5` in float64 (the converter keeps full precision)."""
    what = "Human3.6M cameras.h5 with groups subject<S>/camera<i>"
    sizes = {"R": 9, "T": 3, "f": 2, "c": 2, "k": 3, "p": 2}
    rigs = {}
    with open_h5(path, what) as file:
        subjects = _numbered(file, "subject")
        if not subjects:
            raise DataFormatError(path, f"{what}", f"top-level members {sorted(file.keys())}")
        for number, subject_key in subjects:
            cameras = _numbered(file[subject_key], "camera")
            if not cameras:
                raise DataFormatError(f"{path}:/{subject_key}", "groups camera1..camera4", "no camera groups")
            names, K, R, t, dist = [], [], [], [], []
            for _, camera_key in cameras:
                group = file[subject_key][camera_key]
                values = {}
                for field, size in sizes.items():
                    value = np.asarray(h5_dataset(group, field, path, what), np.float64).reshape(-1)
                    if value.size != size or not np.all(np.isfinite(value)):
                        raise DataFormatError(
                            f"{path}:/{subject_key}/{camera_key}/{field}",
                            f"{size} finite numbers",
                            f"shape {value.shape} with values {value[:9].tolist()}",
                        )
                    values[field] = value
                names.append(_camera_name(h5_dataset(group, "Name", path, what), f"{path}:/{subject_key}/{camera_key}/Name"))
                rotation = values["R"].reshape(3, 3)
                (fx, fy), (cx, cy) = values["f"], values["c"]
                K.append([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
                R.append(rotation.T)
                t.append(-rotation.T @ values["T"])
                k, p = values["k"], values["p"]
                dist.append([k[0], k[1], p[0], p[1], k[2]])
            rigs[f"S{number}"] = (
                names,
                Cameras(K=np.array(K), R=np.array(R), t=np.array(t), dist=np.array(dist), distortion_model="h36m"),
            )
    return rigs


def _camera_name(codes, where: str) -> str:
    """A camera name stored as character codes.  The real cameras.h5 stores them as float64 [8, 1]
    (e.g. 53., 52., ... for "54138969"); any numeric dtype is accepted as long as every code is a
    whole number that is a valid character."""
    codes = np.asarray(codes).reshape(-1)
    if codes.dtype.kind not in "biuf" or codes.size == 0:
        raise DataFormatError(where, "a camera name as character codes (numbers)", f"dtype {codes.dtype}, shape {codes.shape}")
    valid = np.isfinite(codes) & (codes == np.round(codes)) & (codes >= 32) & (codes < 0x110000)
    if not np.all(valid):
        raise DataFormatError(
            where, "character codes: whole numbers of printable characters", f"{codes.dtype} values {codes[:8].tolist()}"
        )
    return "".join(map(chr, codes.astype(np.int64).tolist()))


def _parse(document, path: Path) -> tuple[dict[str, SubjectCameras], dict[str, list[ImageSize]]]:
    """Validate a camera-file document; float64 rigs and image sizes per subject."""
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
            dist = np.array([np.zeros(5) if e["dist"] is None else e["dist"] for e in camera_list])
        rigs[subject] = (
            [e["name"] for e in camera_list],
            Cameras(
                K=np.array([e["K"] for e in camera_list]),
                R=np.array([e["R"] for e in camera_list]),
                t=np.array([e["t"] for e in camera_list]),
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
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
            raise DataFormatError(
                f"{where}, field 'K'", "[[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", str(K.tolist())
            )
        R = _matrix(camera, "R", (3, 3), where)
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) <= 0:
            raise DataFormatError(
                f"{where}, field 'R'", "a rotation matrix (R R^T = I, det R = +1)", str(R.tolist())
            )
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
    """The camera file to write."""


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
            convert_h36m_cameras(command.cameras_h5, command.out_json)
            path = command.out_json
        else:
            path = command.path
        for subject, (names, cameras) in load_cameras(path).items():
            distortion = "none" if cameras.dist is None else cameras.distortion_model
            print(f"{subject}: {len(names)} cameras {names}, distortion {distortion}")
    except DataFormatError as error:
        raise SystemExit(f"error: {error}") from None


if __name__ == "__main__":
    main()
