"""Anipose-family calibration TOML, read and written.

aniposelib (`CameraGroup.dump`), Anipose, Pose2Sim and FreeMoCap write one table per camera with
`name`, `size` [width, height], `matrix` (3x3), `distortions` (k1 k2 p1 p2 [k3]; with
`fisheye = true`, OpenCV's fisheye k1..k4), `rotation` (Rodrigues vector, world to camera) and
`translation`.  Camera tables are recognised by their content (a table with `matrix`, `rotation` or
`translation`), not their name: the tables are `[cam_0]`, `[cam_01]` or Pose2Sim's
`[int_cam01_img]`, and `[metadata]` differs between tools.  Units differ too: Pose2Sim writes
metres, Anipose the ChArUco board's unit (usually mm), FreeMoCap mm; `read_anipose_toml` with
unit="auto" tells them apart, and `write_anipose_toml` records the unit it wrote in `[metadata]`.

Every error is a `DataFormatError` naming the file and, where there is one, the table or key and
what was found there.
"""

from __future__ import annotations

import tomllib
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.formats.rig_cameras import (
    MM_PER_UNIT, CalibrationFormat, CalibrationUnit, RigCalibration, check_intrinsics, check_rig_size, check_rotation, rig_size,
)  # fmt: skip
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.outputs import OutputError, atomic_output
from jaxpose.rotations import nearest_rotation, rodrigues_from_rotation, rotation_from_rodrigues

__all__ = ["FORMAT", "is_anipose_calibration", "read_anipose_toml", "write_anipose_toml"]

# "auto": a rig this many file units across or more is in millimetres, a smaller one in metres.
AUTO_METRES_BELOW = 100.0
# A TOML table with any of these keys is a camera table (and then must have all of them).
_CAMERA_KEYS = ("matrix", "rotation", "translation")
# is_anipose_calibration does not parse larger files (a calibration is a few kilobytes).
_MAX_CALIBRATION_BYTES = 4 << 20


def is_anipose_calibration(path: Path) -> bool:
    """Whether `path` is a `.toml` with at least one camera table (Pose2Sim's `Config.toml` and
    Anipose's `config.toml` are not).  A `.toml` that is not valid TOML raises: it might be the calibration."""
    if path.suffix.lower() != ".toml" or path.stat().st_size > _MAX_CALIBRATION_BYTES:
        return False
    return bool(_camera_tables(_load_toml(path)))


def read_anipose_toml(path: Path, unit: CalibrationUnit) -> RigCalibration:
    """An Anipose-family calibration TOML; `unit` as `read_rig_calibration` takes it ("auto": `_resolve_unit`)."""
    document = _load_toml(path)
    tables = _camera_tables(document)
    if not tables:
        found = [key for key, value in document.items() if isinstance(value, dict)]
        raise DataFormatError(
            path,
            "camera tables ([cam_0], [cam_01], [int_cam01_img], ...) each with matrix, rotation and translation",
            f"no camera table; tables {found}",
        )
    cameras = [_toml_camera(path, key, table) for key, table in tables]

    names = [camera["name"] for camera in cameras]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise DataFormatError(path, "distinct camera names", f"{repeated} more than once in {names}")
    fisheye = {camera["fisheye"] for camera in cameras}
    if len(fisheye) > 1:
        which = [key for (key, _), camera in zip(tables, cameras) if camera["fisheye"]]
        raise DataFormatError(
            path, "one lens model for the whole rig", f"fisheye = true in {which} only (mixed rigs are not supported)"
        )
    sizes = [camera["size"] for camera in cameras]
    if any(size is None for size in sizes) and any(size is not None for size in sizes):
        which = [key for (key, _), size in zip(tables, sizes) if size is None]
        raise DataFormatError(path, "`size` in every camera table or in none", f"no `size` in {which}")

    R = np.array([camera["R"] for camera in cameras])
    t_file = np.array([camera["t"] for camera in cameras])
    resolved, how = _resolve_unit(unit, R, t_file, _metadata_unit(path, document))
    t = t_file * MM_PER_UNIT[resolved]
    check_rig_size(str(path), names, R, t, resolved, how)

    model = "fisheye" if fisheye.pop() else "opencv"
    dist = np.array([camera["dist"] for camera in cameras])
    if model == "opencv" and not np.any(dist):
        dist = None  # a pinhole rig: projection skips the distortion
    return RigCalibration(
        camera_names=tuple(names),
        cameras=Cameras(K=np.array([camera["K"] for camera in cameras]), R=R, t=t, dist=dist, distortion_model=model),
        image_size=None if sizes[0] is None else np.array(sizes, dtype=np.int64),
        source=str(path),
        unit=resolved,
    )


FORMAT = CalibrationFormat(
    "an Anipose/Pose2Sim/FreeMoCap calibration .toml", (".toml",), is_anipose_calibration,
    lambda path, unit, _subject: read_anipose_toml(path, unit),
)


def write_anipose_toml(
    path: str | Path,
    rig: RigCalibration,
    unit: Literal["m", "mm"] = "m",
    *,
    metadata: Mapping[str, str | float | bool | Sequence[float]] | None = None,
    overwrite: bool = False,
) -> None:
    """Write `rig` in the Anipose/Pose2Sim calibration layout, translations in `unit`.

    One `[cam_<i>]` table per camera (name, size, matrix, distortions, rotation as a Rodrigues
    vector, translation, fisheye), then `[metadata]` with `unit`, which `read_rig_calibration`
    uses when reading the file with unit="auto", and the entries of `metadata` (strings, numbers,
    booleans or lists of numbers; Pose2Sim and aniposelib skip the table).  Pose2Sim reads metres
    (its own files, and the default here); Anipose the board's unit (mm for most).  The file is
    written whole or not at all (`jaxpose.formats.outputs.atomic_output`), and an existing file
    only with `overwrite` (else `OutputError`).  Fisheye rigs are written as aniposelib writes
    them (`fisheye = true`, 4 coefficients).  A rig without image sizes is written without `size`
    (with a warning: Anipose and Pose2Sim need it).  Human3.6M's distortion model has no
    OpenCV/Anipose equivalent and is refused: convert the rig first with
    `jaxpose.formats.h36m_cameras.opencv_rig_from_h36m`.
    """
    if unit not in ("m", "mm"):
        raise ValueError(f"write_anipose_toml: unit must be 'm' or 'mm', not {unit!r}")
    if Path(path).exists() and not overwrite:
        raise OutputError(f"{path}: exists; pass overwrite=True (--overwrite) to replace it")
    extra = dict(metadata or {})
    if "unit" in extra:
        raise ValueError("write_anipose_toml: metadata 'unit' is the translations' unit; pass it as `unit`")
    cameras = rig.cameras
    model = cameras.distortion_model
    if model == "h36m" and cameras.dist is not None:
        raise ValueError(
            f"write_anipose_toml: {rig.source} uses Human3.6M's distortion model, whose tangential terms "
            "differ from OpenCV's (the only lens model, besides fisheye, that Anipose/Pose2Sim files hold); "
            "convert it first with opencv_rig_from_h36m, which fits the closest OpenCV coefficients and "
            "reports the largest pixel difference"
        )
    if model not in ("opencv", "fisheye", "h36m"):
        raise ValueError(f"write_anipose_toml: unknown distortion model {model!r}")
    K, R, t = (np.asarray(field, np.float64) for field in (cameras.K, cameras.R, cameras.t))
    count = len(rig.camera_names)
    if K.shape != (count, 3, 3) or R.shape != (count, 3, 3) or t.shape != (count, 3):
        raise ValueError(
            f"write_anipose_toml: {count} camera names but K {K.shape}, R {R.shape}, t {t.shape} (expected [C] cameras)"
        )
    dist = np.zeros((count, 5)) if cameras.dist is None else np.asarray(cameras.dist, np.float64)
    if rig.image_size is None:
        warnings.warn(
            f"write_anipose_toml: {rig.source} has no image sizes; {path} is written without `size`, "
            "which Anipose and Pose2Sim need (add it by hand)",
            stacklevel=2,
        )
    rotation = rodrigues_from_rotation(R)
    lines = []
    for c, name in enumerate(rig.camera_names):
        lines.append(f"[cam_{c}]")
        lines.append(f"name = {_toml_string(name)}")
        if rig.image_size is not None:
            width, height = (int(value) for value in rig.image_size[c])
            lines.append(f"size = [ {width}, {height} ]")
        lines.append(f"matrix = {_toml_array(K[c])}")
        lines.append(f"distortions = {_toml_array(dist[c, :4] if model == 'fisheye' else dist[c])}")
        lines.append(f"rotation = {_toml_array(rotation[c])}")
        lines.append(f"translation = {_toml_array(t[c] / MM_PER_UNIT[unit])}")
        lines.append(f"fisheye = {'true' if model == 'fisheye' else 'false'}")
        lines.append("")
    lines += ["[metadata]", f'unit = "{unit}"']
    lines += [f"{_toml_key(key)} = {_toml_value(value)}" for key, value in extra.items()]
    with atomic_output(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")


# ----------------------------------------------------------------------------------------------
# Reading


def _resolve_unit(unit: CalibrationUnit, R: np.ndarray, t_file: np.ndarray, metadata_unit: str | None) -> tuple[str, str]:
    """(unit, how it was chosen) for a TOML file whose translations are `t_file` in file units.

    "auto" takes the file's `[metadata] unit` (written by `write_anipose_toml`), else metres for a
    rig (or, for one camera, a distance from the origin) under `AUTO_METRES_BELOW` file units and
    millimetres otherwise: `jaxpose.formats.calibration_files.read_rig_calibration` says why.
    """
    if unit != "auto":
        return unit, "as given"
    if metadata_unit is not None:
        return metadata_unit, "from the file's [metadata] unit"
    if len(t_file) >= 2:
        size, what = rig_size(R, t_file), "rig size"
    else:
        size, what = float(np.linalg.norm(t_file[0])), "camera distance from the world origin"
    resolved = "m" if size < AUTO_METRES_BELOW else "mm"
    return resolved, f"'auto': {what} {size:.6g} file units {'<' if resolved == 'm' else '>='} {AUTO_METRES_BELOW:g}"


def _metadata_unit(path: Path, document: dict[str, Any]) -> str | None:
    """The `unit` of `[metadata]` (written by `write_anipose_toml`), if there is one."""
    metadata = document.get("metadata")
    if not isinstance(metadata, dict) or "unit" not in metadata:
        return None
    if metadata["unit"] not in MM_PER_UNIT:
        raise DataFormatError(f"{path}: table [metadata], key 'unit'", f"one of {list(MM_PER_UNIT)}", repr(metadata["unit"]))
    return metadata["unit"]


def _toml_camera(path: Path, key: str, table: dict[str, Any]) -> dict[str, Any]:
    """One camera table: name, size, K, dist (the 5-vector of its model), fisheye, R, t (file units)."""
    where = f"{path}: table [{key}]"
    missing = [field for field in _CAMERA_KEYS if field not in table]
    if missing:
        raise DataFormatError(
            where,
            "a camera table with matrix, rotation and translation (and name, size, distortions)",
            f"no {', '.join(repr(field) for field in missing)}; keys {sorted(table)}",
        )
    name = table.get("name", key)
    if not isinstance(name, str) or not name:
        raise DataFormatError(f"{where}, key 'name'", "a non-empty string", repr(name))
    size = table.get("size")
    if size is not None:
        size_array = _numbers(size, [(2,)], f"{where}, key 'size'", "[width, height] in pixels")
        if np.any(size_array <= 0) or np.any(size_array != np.round(size_array)) or isinstance(size[0], bool):
            raise DataFormatError(f"{where}, key 'size'", "[width, height]: two positive whole numbers", repr(size))
        size = (int(size_array[0]), int(size_array[1]))
    K = _numbers(table["matrix"], [(3, 3)], f"{where}, key 'matrix'", "a 3x3 intrinsic matrix")
    check_intrinsics(K, f"{where}, key 'matrix' (camera {name!r})")
    fisheye = table.get("fisheye", False)
    if not isinstance(fisheye, bool):
        raise DataFormatError(f"{where}, key 'fisheye'", "true or false", repr(fisheye))
    if fisheye:
        coefficients = _numbers(
            table.get("distortions", [0.0] * 4), [(4,)], f"{where}, key 'distortions'", "4 fisheye coefficients k1 k2 k3 k4"
        )
    else:
        coefficients = _numbers(
            table.get("distortions", [0.0] * 5),
            [(4,), (5,)],
            f"{where}, key 'distortions'",
            "4 or 5 OpenCV coefficients k1 k2 p1 p2 [k3]",
        )
    dist = np.zeros(5)
    dist[: len(coefficients)] = coefficients
    R = _rotation_matrix(table["rotation"], f"{where}, key 'rotation'", "a Rodrigues rotation vector (3 numbers)")
    t = _numbers(table["translation"], [(3,)], f"{where}, key 'translation'", "3 numbers")
    return {"name": name, "size": size, "K": K, "dist": dist, "fisheye": fisheye, "R": R, "t": t}


def _load_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as file:
            return tomllib.load(file)
    except OSError as error:
        raise DataFormatError(path, "a readable TOML file", f"an unreadable file ({error})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise DataFormatError(path, "a TOML file", f"invalid TOML ({error})") from None


def _camera_tables(document: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(table name, table) of the top-level tables that describe a camera, in file order."""
    return [
        (key, value)
        for key, value in document.items()
        if isinstance(value, dict) and key != "metadata" and any(field in value for field in _CAMERA_KEYS)
    ]


def _numbers(value: Any, shapes: Sequence[tuple[int, ...]], where: str, expected: str) -> np.ndarray:
    """A finite float64 array of one of `shapes` from a parsed value, or a DataFormatError."""
    array = None
    if not isinstance(value, (str, bytes, dict)):
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            array = None
    if array is None or array.shape not in shapes or not np.all(np.isfinite(array)):
        shape = "not an array of numbers" if array is None else f"shape {list(array.shape)}"
        if array is not None and array.shape in shapes:
            shape = "non-finite numbers"
        raise DataFormatError(where, expected, f"{shape}: {repr(value)[:200]}")
    return array


def _rotation_matrix(value: Any, where: str, expected: str) -> np.ndarray:
    """A rotation given as a Rodrigues vector (3 numbers) or as a 3x3 matrix."""
    array = _numbers(value, [(3,), (3, 1), (1, 3), (3, 3)], where, expected)
    if array.shape != (3, 3):
        return rotation_from_rodrigues(array.reshape(3))
    check_rotation(array, where)
    return nearest_rotation(array)


# ----------------------------------------------------------------------------------------------
# Writing


def _toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for char in text:
        if char in '"\\':
            out.append("\\" + char)
        elif ord(char) < 0x20 or ord(char) == 0x7F:
            out.append(f"\\u{ord(char):04x}")
        else:
            out.append(char)
    return '"' + "".join(out) + '"'


def _toml_key(key: str) -> str:
    """A bare TOML key when it is one (letters, digits, - and _), else a quoted one."""
    return key if key and all(char.isascii() and (char.isalnum() or char in "-_") for char in key) else _toml_string(key)


def _toml_value(value) -> str:
    """A metadata value: a string, a boolean, a number or a (nested) list of numbers."""
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    array = np.asarray(value, np.float64)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"write_anipose_toml: metadata value {value!r} is not finite (TOML has no NaN for Pose2Sim)")
    return repr(float(array)) if array.ndim == 0 else _toml_array(array)


def _toml_array(values: np.ndarray) -> str:
    """A TOML array of floats (nested for 2-D), each written so that it reads back exactly."""
    values = np.asarray(values, np.float64)
    if values.ndim > 1:
        return "[ " + ", ".join(_toml_array(row) for row in values) + " ]"
    return "[ " + ", ".join(repr(float(value)) for value in values) + " ]"
