"""EasyMocap's calibration: OpenCV FileStorage YAML, `intri.yml` and `extri.yml`.

`intri.yml` holds `names`, `K_<cam>` and `dist_<cam>` (k1 k2 p1 p2 [k3]); `extri.yml` holds each
camera's pose, `R_<cam>` (Rodrigues, 3x1 or 1x3) and/or `Rot_<cam>` (3x3), and `T_<cam>` in metres.
The rig is the cameras of both files.  Every error is a `DataFormatError` naming the file, the key
and, for matrices, its line.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from jaxpose.camera import Cameras
from jaxpose.formats.rig_cameras import (
    MM_PER_UNIT, CalibrationFormat, CalibrationUnit, RigCalibration, check_intrinsics, check_rig_size, check_rotation,
)  # fmt: skip
from jaxpose.formats.errors import DataFormatError
from jaxpose.rotations import nearest_rotation, rodrigues_from_rotation, rotation_from_rodrigues

__all__ = ["FORMAT", "is_easymocap_intrinsics", "read_easymocap", "read_easymocap_intrinsics"]


def is_easymocap_intrinsics(path: Path) -> bool:
    """Whether `path` is named as EasyMocap's intrinsics file (the one `find_calibration` picks)."""
    return path.name.lower() in ("intri.yml", "intri.yaml")


def read_easymocap(path: Path, unit: CalibrationUnit) -> RigCalibration:
    """The rig of EasyMocap's intri.yml + extri.yml, from either file or their folder; "auto" means metres."""
    intri, extri = _easymocap_paths(path)
    if not intri.is_file():
        raise DataFormatError(intri, "EasyMocap intri.yml (names, K_<cam>, dist_<cam>) beside extri.yml", "no such file")
    if not extri.is_file():
        raise DataFormatError(
            extri,
            f"EasyMocap extri.yml (R_<cam> or Rot_<cam>, T_<cam>) beside {intri.name}: a rig needs the cameras' "
            f"poses, which {intri.name} does not hold",
            "no such file",
        )
    source = f"{intri} + {extri}"
    intri_names, intrinsics = read_easymocap_intrinsics(intri)
    document = _load_opencv_yaml(extri)
    extri_names = _yaml_names(extri, document)
    if extri_names is None:
        extri_names = [key[2:] for key in document if key.startswith("T_")]
    common = [name for name in intri_names if name in extri_names]
    if not common:
        raise DataFormatError(source, "cameras present in both files", f"intri.yml {intri_names}, extri.yml {extri_names}")
    left_out = [name for name in intri_names if name not in common] + [name for name in extri_names if name not in common]
    if left_out:
        warnings.warn(
            f"{source}: cameras {left_out} are in only one of the two files and are left out of the rig "
            f"({len(common)} cameras: {common})",
            stacklevel=3,
        )

    R, t_file = [], []
    for name in common:
        R.append(_extri_rotation(extri, document, name))
        t_file.append(_yaml_matrix(extri, document, f"T_{name}", [(3, 1), (1, 3)], "a 3x1 translation").reshape(3))
    R, t_file = np.array(R), np.array(t_file)
    resolved = "m" if unit == "auto" else unit
    t = t_file * MM_PER_UNIT[resolved]
    check_rig_size(source, common, R, t, resolved, "EasyMocap's metres" if unit == "auto" else "as given")
    K = np.array([intrinsics[name][0] for name in common])
    dist = np.array([intrinsics[name][1] for name in common])
    return RigCalibration(
        camera_names=tuple(common),
        cameras=Cameras(K=K, R=R, t=t, dist=dist if np.any(dist) else None, distortion_model="opencv"),
        image_size=None,
        source=source,
        unit=resolved,
    )


FORMAT = CalibrationFormat(
    "EasyMocap intri.yml + extri.yml (or their folder)", (".yml", ".yaml"), is_easymocap_intrinsics,
    lambda path, unit, _subject: read_easymocap(path, unit),
)


def read_easymocap_intrinsics(intri: Path) -> tuple[list[str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """intri.yml: (names, name -> (K, dist 5-vector))."""
    document = _load_opencv_yaml(intri)
    names = _yaml_names(intri, document)
    if names is None:
        raise DataFormatError(intri, "EasyMocap intri.yml: 'names', a list of camera names", f"keys {sorted(document)[:20]}")
    cameras = {}
    for name in names:
        K = _yaml_matrix(intri, document, f"K_{name}", [(3, 3)], "a 3x3 intrinsic matrix")
        check_intrinsics(K, f"{intri}: key 'K_{name}'")
        dist = np.zeros(5)
        if f"dist_{name}" in document:
            shapes = [(1, 5), (5, 1), (1, 4), (4, 1)]
            values = _yaml_matrix(intri, document, f"dist_{name}", shapes, "1x5 or 5x1 (or 4) coefficients k1 k2 p1 p2 [k3]")
            dist[: values.size] = values.reshape(-1)
        cameras[name] = (K, dist)
    return names, cameras


def _easymocap_paths(path: Path) -> tuple[Path, Path]:
    """(intri.yml, extri.yml) from either file or their folder."""
    if path.is_dir():
        return path / "intri.yml", path / "extri.yml"
    name = path.name
    if name.lower().startswith("intri"):
        return path, path.with_name("extri" + name[5:])
    if name.lower().startswith("extri"):
        return path.with_name("intri" + name[5:]), path
    raise DataFormatError(path, "EasyMocap's intri.yml or extri.yml, or the folder holding them", f"a file named {name!r}")


def _extri_rotation(extri: Path, document: dict[str, Any], name: str) -> np.ndarray:
    """The camera's rotation: `Rot_<cam>` when present (checked against `R_<cam>`), else `R_<cam>`."""
    rodrigues = None
    if f"R_{name}" in document:
        vector = _yaml_matrix(extri, document, f"R_{name}", [(3, 1), (1, 3)], "a 3x1 or 1x3 Rodrigues vector")
        rodrigues = rotation_from_rodrigues(vector.reshape(3))
    if f"Rot_{name}" not in document:
        if rodrigues is None:
            raise DataFormatError(extri, f"'Rot_{name}' (3x3) or 'R_{name}' (Rodrigues) for camera {name!r}", "neither")
        return rodrigues
    matrix = _yaml_matrix(extri, document, f"Rot_{name}", [(3, 3)], "a 3x3 rotation matrix")
    check_rotation(matrix, f"{extri}: key 'Rot_{name}'")
    matrix = nearest_rotation(matrix)
    if rodrigues is not None:
        angle = float(np.linalg.norm(rodrigues_from_rotation(matrix @ rodrigues.T)))
        if angle > 1e-3:
            raise DataFormatError(
                f"{extri}: keys 'Rot_{name}' and 'R_{name}'",
                "the same rotation twice (3x3 and Rodrigues)",
                f"rotations {math.degrees(angle):.4g} degrees apart",
            )
    return matrix


# ----------------------------------------------------------------------------------------------
# OpenCV FileStorage YAML


class _OpenCVMatrix:
    """An `!!opencv-matrix` node as parsed: its mapping (rows, cols, dt, data) and its key's line."""

    def __init__(self, fields: dict[str, Any], line: int):
        self.fields = fields
        self.line = line


class _OpenCVLoader(yaml.SafeLoader):
    """PyYAML's safe loader, plus OpenCV's `!!opencv-matrix` tag; every plain scalar stays a string.

    No implicit typing: camera names such as `01` or `1` stay the strings the file wrote (the keys
    K_01, K_1 are built from them), and matrix entries are converted with `float` where they are
    read (which also accepts `1e-05`, which YAML 1.1 would leave a string).
    """


_OpenCVLoader.yaml_implicit_resolvers = {}
_OpenCVLoader.add_constructor(
    "tag:yaml.org,2002:opencv-matrix",
    lambda loader, node: _OpenCVMatrix(loader.construct_mapping(node, deep=True), node.start_mark.line + 1),
)


def _load_opencv_yaml(path: Path) -> dict[str, Any]:
    """An OpenCV FileStorage YAML file as a dict (matrices as `_OpenCVMatrix`)."""
    what = "an OpenCV FileStorage YAML file (%YAML:1.0)"
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise DataFormatError(path, what, f"an unreadable file ({error})") from None
    first, _, rest = text.partition("\n")
    # OpenCV writes the directive as "%YAML:1.0", which YAML parsers reject; line numbers stay those
    # of the file (the directive line is replaced by an empty one).
    if first.startswith("%YAML:"):
        text = "\n" + rest
    try:
        document = yaml.load(text, Loader=_OpenCVLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as error:
        raise DataFormatError(path, what, f"invalid YAML ({error})") from None
    if not isinstance(document, dict):
        raise DataFormatError(path, f"{what} holding a mapping of keys", f"{type(document).__name__}")
    return document


def _yaml_matrix(
    path: Path, document: dict[str, Any], key: str, shapes: Sequence[tuple[int, int]], expected: str
) -> np.ndarray:
    """The `!!opencv-matrix` at `key`, float64 of one of `shapes`."""
    node = document.get(key)
    where = f"{path}: key '{key}'"
    if not isinstance(node, _OpenCVMatrix):
        raise DataFormatError(where, f"an !!opencv-matrix: {expected}", "no such key" if node is None else repr(node)[:200])
    where = f"{path}: key '{key}' (line {node.line})"
    fields = node.fields
    try:
        rows, cols = int(fields["rows"]), int(fields["cols"])
        data = fields["data"]
        values = np.array([float(value) for value in data], dtype=np.float64) if isinstance(data, list) else None
    except (KeyError, TypeError, ValueError) as error:
        raise DataFormatError(where, "an !!opencv-matrix with rows, cols and a data list of numbers", repr(error)) from None
    if values is None or values.size != rows * cols:
        raise DataFormatError(where, f"rows x cols = {rows} x {cols} numbers in data", f"{repr(data)[:200]}")
    if (rows, cols) not in shapes or not np.all(np.isfinite(values)):
        raise DataFormatError(where, expected, f"a {rows}x{cols} matrix {values.tolist()}")
    return values.reshape(rows, cols)


def _yaml_names(path: Path, document: dict[str, Any]) -> list[str] | None:
    names = document.get("names")
    if names is None:
        return None
    if not isinstance(names, list) or not all(isinstance(name, str) and name for name in names):
        raise DataFormatError(f"{path}: key 'names'", "a list of camera names", repr(names)[:200])
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise DataFormatError(f"{path}: key 'names'", "distinct camera names", f"{repeated} more than once")
    return names
