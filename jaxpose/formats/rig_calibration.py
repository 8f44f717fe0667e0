"""The calibration files users already have, read as they are.

`read_rig_calibration` returns one `RigCalibration` (camera names, float64 numpy `Cameras` [C] in
the library's conventions, image sizes) from any of:

1. **Anipose-family TOML** (`*.toml`), as aniposelib (`CameraGroup.dump`), Anipose, Pose2Sim and
   FreeMoCap write it: one table per camera with `name`, `size` [width, height], `matrix` (3x3),
   `distortions` (k1 k2 p1 p2 [k3]; with `fisheye = true`, OpenCV's fisheye k1..k4), `rotation`
   (Rodrigues vector, world to camera) and `translation`.  Camera tables are recognised by their
   content (a table with `matrix`, `rotation` or `translation`), not their name: the tables are
   `[cam_0]`, `[cam_01]` or Pose2Sim's `[int_cam01_img]`, and `[metadata]` differs between tools.
   Units differ too: Pose2Sim writes metres, Anipose the ChArUco board's unit (usually mm),
   FreeMoCap mm; see `read_rig_calibration` for how "auto" tells them apart.
2. **EasyMocap / OpenCV FileStorage YAML**: `intri.yml` (`names`, `K_<cam>`, `dist_<cam>`) and
   `extri.yml` (`R_<cam>` Rodrigues 3x1 or 1x3, `Rot_<cam>` 3x3, `T_<cam>` in metres).  The rig is
   the cameras of both files.
3. **The project's camera file** (`*.json`, `jaxpose.formats.camera_file`), millimetres.
4. **Human3.6M's `cameras.h5`** (`*.h5`), millimetres, one rig per subject.

`find_calibration` finds the calibration file in a recording folder by content, and
`write_anipose_toml` writes a rig back in the Anipose/Pose2Sim layout (what most tools read).

Conventions (docs/conventions.md): `x_cam = R @ x_world + t`, t in millimetres, distortion
`dist = (k1, k2, p1, p2, k3)` of OpenCV's model, or (k1, k2, k3, k4, 0) of its fisheye model
(`jaxpose.camera`).  Every error is a `DataFormatError` naming the file and, where there is one,
the table or key and what was found there.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np
import yaml

from jaxpose.camera import Cameras, camera_centres
from jaxpose.rotations import nearest_rotation, rodrigues_from_rotation, rotation_from_rodrigues
from jaxpose.formats.camera_file import H36M_IMAGE_SIZES, _parse as _parse_camera_file, _read_h36m
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_json

__all__ = [
    "CalibrationUnit",
    "RigCalibration",
    "find_calibration",
    "opencv_from_h36m_distortion",
    "opencv_rig_from_h36m",
    "read_rig_calibration",
    "write_anipose_toml",
]

CalibrationUnit = Literal["auto", "m", "cm", "mm"]
MM_PER_UNIT = {"m": 1000.0, "cm": 10.0, "mm": 1.0}
# "auto": a rig this many file units across or more is in millimetres, a smaller one in metres.
AUTO_METRES_BELOW = 100.0
# A rig that films people: camera centres at least 10 cm and at most 200 m apart.
RIG_SIZE_RANGE_MM = (100.0, 200_000.0)
UNIT_FLAG = "--data.calibration-unit"
ACCEPTED = (
    "an Anipose/Pose2Sim/FreeMoCap calibration .toml, EasyMocap intri.yml + extri.yml (or their folder), "
    "a jaxpose camera file .json, or Human3.6M's cameras.h5"
)
# A TOML table with any of these keys is a camera table (and then must have all of them).
_CAMERA_KEYS = ("matrix", "rotation", "translation")
# find_calibration does not parse files larger than this as TOML, nor read more of a JSON file.
_FIND_MAX_TOML_BYTES = 4 << 20
_FIND_JSON_HEAD_BYTES = 4096


# ----------------------------------------------------------------------------------------------
# The rig


@dataclasses.dataclass(frozen=True, eq=False)
class RigCalibration:
    """One calibrated rig as read from a file.

    `cameras` holds float64 numpy fields with leading axis [C] in the library's conventions
    (`x_cam = R @ x_world + t`, t in millimetres; `dist` f64[C, 5] or None; `distortion_model`
    "opencv", "fisheye" or, from Human3.6M files, "h36m").  `image_size` is int64 [C, 2]
    (width, height) or None when the file has none; `source` names the file(s) read and `unit`
    the unit the file was read in ("m", "cm" or "mm").
    """

    camera_names: tuple[str, ...]
    cameras: Cameras
    image_size: np.ndarray | None
    source: str
    unit: str

    def select(self, names: Sequence[str], what: str) -> RigCalibration:
        """The cameras `names`, in that order.

        A name missing from the calibration raises `DataFormatError` naming `self.source`, listing
        the calibration's camera names and `names`; `what` says where `names` come from (e.g.
        'detection folders of recording walk1').
        """
        names = (names,) if isinstance(names, str) else tuple(str(name) for name in names)
        if not names:
            raise DataFormatError(self.source, f"at least one camera name from the {what}", "none")
        missing = [name for name in names if name not in self.camera_names]
        if missing:
            raise DataFormatError(
                self.source,
                f"a camera for every name of the {what}: {list(names)}",
                f"the calibration's cameras {list(self.camera_names)}, which lack {missing}",
            )
        repeated = sorted({name for name in names if names.count(name) > 1})
        if repeated:
            raise DataFormatError(
                self.source, f"distinct camera names from the {what}", f"{repeated} more than once in {list(names)}"
            )
        index = np.array([self.camera_names.index(name) for name in names], dtype=np.int64)
        return dataclasses.replace(
            self,
            camera_names=names,
            cameras=self.cameras[index],
            image_size=None if self.image_size is None else self.image_size[index],
        )

    def rig_size_mm(self) -> float:
        """The largest distance between two camera centres, mm (0 for a single camera)."""
        return _rig_size(np.asarray(self.cameras.R, np.float64), np.asarray(self.cameras.t, np.float64))


def _rig_size(R: np.ndarray, t: np.ndarray) -> float:
    centres = camera_centres(R, t)
    if len(centres) < 2:
        return 0.0
    return float(np.linalg.norm(centres[:, None] - centres[None], axis=-1).max())


def _check_rig_size(source: str, R: np.ndarray, t_mm: np.ndarray, unit: str, resolved_how: str) -> None:
    """Refuse a rig whose size, in mm, cannot be a rig that films people: the unit must be wrong."""
    if len(t_mm) < 2:
        return
    size = _rig_size(R, t_mm)
    low, high = RIG_SIZE_RANGE_MM
    if not low <= size <= high:
        raise DataFormatError(
            source,
            f"camera centres {low:g} mm to {high / 1000:g} m apart, a rig that films people",
            f"a rig {size:.6g} mm across when the file is read in {unit!r} ({resolved_how}); if the file is "
            f"in another unit, say which with {UNIT_FLAG} m|cm|mm",
        )


def _resolve_unit(unit: CalibrationUnit, R: np.ndarray, t_file: np.ndarray, metadata_unit: str | None) -> tuple[str, str]:
    """(unit, how it was chosen) for a TOML file whose translations are `t_file` in file units."""
    if unit != "auto":
        return unit, "as given"
    if metadata_unit is not None:
        return metadata_unit, "from the file's [metadata] unit"
    if len(t_file) >= 2:
        size, what = _rig_size(R, t_file), "rig size"
    else:
        size, what = float(np.linalg.norm(t_file[0])), "camera distance from the world origin"
    resolved = "m" if size < AUTO_METRES_BELOW else "mm"
    return resolved, f"'auto': {what} {size:.6g} file units {'<' if resolved == 'm' else '>='} {AUTO_METRES_BELOW:g}"


# ----------------------------------------------------------------------------------------------
# Entry points


def read_rig_calibration(
    path: str | Path, unit: CalibrationUnit = "auto", subject: str | None = None
) -> RigCalibration:
    """Read a calibrated rig from any of the formats of the module docstring.

    path: the file; for EasyMocap either `intri.yml`, `extri.yml` or the folder holding them; any
    other folder is searched with `find_calibration`.
    unit: the length unit of the file's translations.  Anipose-family TOML files do not state it
    (except our own `write_anipose_toml` output, whose `[metadata] unit` "auto" uses).  "auto"
    takes metres when the rig size (the largest distance between camera centres, in file units) is
    below 100 and millimetres otherwise: a rig that films people has cameras about 1 to 30 m apart,
    which is 1 to 30 in a metre file and 1,000 to 30,000 in a millimetre file, so confusing the two
    would take a rig over 100 m across or under 10 cm across.  Centimetres (100 to 3,000 for the
    same rigs) fall in the millimetre range: a centimetre file must be read with unit="cm".  For
    EasyMocap YAML "auto" means metres (EasyMocap's unit); jaxpose camera files and cameras.h5 are
    millimetres by definition, and `unit` is ignored for them.  After conversion a rig whose size
    is outside [100 mm, 200 m] is refused: the unit must be wrong (single cameras are not checked).
    subject: which subject's rig, for files holding several (camera files, cameras.h5); a file
    with a single subject needs none.  Ignored for the other formats.
    """
    if unit not in get_args(CalibrationUnit):
        raise ValueError(f"read_rig_calibration: unit must be one of {list(get_args(CalibrationUnit))}, not {unit!r}")
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, ACCEPTED, "no such file or folder")
    if path.is_dir():
        found = find_calibration(path)
        if found is None:
            if (path / "extri.yml").is_file():
                return _read_easymocap(path, unit)  # says that intri.yml is missing
            names = sorted(entry.name for entry in path.iterdir())
            raise DataFormatError(path, f"a folder holding {ACCEPTED}", f"none among {names[:30]}")
        path = found
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return _read_toml(path, unit)
    if suffix in (".yml", ".yaml"):
        return _read_easymocap(path, unit)
    if suffix in (".json", ".h5", ".hdf5"):
        if unit not in ("auto", "mm"):
            warnings.warn(f"{path}: unit {unit!r} ignored: this file's lengths are millimetres by definition", stacklevel=2)
        return _read_camera_file(path, subject) if suffix == ".json" else _read_h36m_file(path, subject)
    raise DataFormatError(path, ACCEPTED, f"a file with suffix {suffix!r}")


def find_calibration(folder: str | Path) -> Path | None:
    """The one calibration file directly inside `folder`, recognised by content; None if there is none.

    A calibration is a `.toml` with at least one camera table (so the project configs Pose2Sim's
    `Config.toml` and Anipose's `config.toml` are not), an EasyMocap `intri.yml`, or a jaxpose
    camera file `.json` (recognised from its first bytes: other JSON files such as detector output
    are not parsed).  Sub-folders are not searched.  More than one calibration raises
    `DataFormatError` listing them; a `.toml` that is not valid TOML raises too (it might be the
    calibration).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataFormatError(folder, "a folder that may hold a calibration file", "no such folder")
    found = [entry for entry in sorted(folder.iterdir()) if entry.is_file() and _is_calibration(entry)]
    if len(found) > 1:
        raise DataFormatError(
            folder, "one calibration file in the folder", f"{len(found)}: {[entry.name for entry in found]}"
        )
    return found[0] if found else None


def _is_calibration(path: Path) -> bool:
    name, suffix = path.name.lower(), path.suffix.lower()
    if suffix == ".toml":
        if path.stat().st_size > _FIND_MAX_TOML_BYTES:
            return False
        return bool(_camera_tables(_load_toml(path)))
    if name in ("intri.yml", "intri.yaml"):
        return True
    if suffix == ".json":
        try:
            with path.open("rb") as file:
                head = file.read(_FIND_JSON_HEAD_BYTES).decode("utf-8", errors="replace").lstrip("\ufeff \t\r\n")
        except OSError:
            return False
        return head.startswith("{") and re.search(r'"format"\s*:\s*"jaxpose-cameras"', head) is not None
    return False


# ----------------------------------------------------------------------------------------------
# Anipose-family TOML


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


def _check_intrinsics(K: np.ndarray, where: str) -> None:
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise DataFormatError(where, "[[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", str(K.tolist()))


def _rotation_matrix(value: Any, where: str, expected: str) -> np.ndarray:
    """A rotation given as a Rodrigues vector (3 numbers) or as a 3x3 matrix."""
    array = _numbers(value, [(3,), (3, 1), (1, 3), (3, 3)], where, expected)
    if array.shape != (3, 3):
        return rotation_from_rodrigues(array.reshape(3))
    if np.abs(array @ array.T - np.eye(3)).max() > 1e-4 or np.linalg.det(array) <= 0:
        raise DataFormatError(where, "a rotation matrix (R R^T = I, det R = +1)", str(array.tolist()))
    return nearest_rotation(array)


def _read_toml(path: Path, unit: CalibrationUnit) -> RigCalibration:
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
    _check_rig_size(str(path), R, t, resolved, how)

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
    _check_intrinsics(K, f"{where}, key 'matrix'")
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


# ----------------------------------------------------------------------------------------------
# EasyMocap / OpenCV FileStorage YAML


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


def _read_easymocap_intrinsics(intri: Path) -> tuple[list[str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """intri.yml: (names, name -> (K, dist 5-vector))."""
    document = _load_opencv_yaml(intri)
    names = _yaml_names(intri, document)
    if names is None:
        raise DataFormatError(intri, "EasyMocap intri.yml: 'names', a list of camera names", f"keys {sorted(document)[:20]}")
    cameras = {}
    for name in names:
        K = _yaml_matrix(intri, document, f"K_{name}", [(3, 3)], "a 3x3 intrinsic matrix")
        _check_intrinsics(K, f"{intri}: key 'K_{name}'")
        dist = np.zeros(5)
        if f"dist_{name}" in document:
            shapes = [(1, 5), (5, 1), (1, 4), (4, 1)]
            values = _yaml_matrix(intri, document, f"dist_{name}", shapes, "1x5 or 5x1 (or 4) coefficients k1 k2 p1 p2 [k3]")
            dist[: values.size] = values.reshape(-1)
        cameras[name] = (K, dist)
    return names, cameras


def _read_easymocap(path: Path, unit: CalibrationUnit) -> RigCalibration:
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
    intri_names, intrinsics = _read_easymocap_intrinsics(intri)
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
    _check_rig_size(source, R, t, resolved, "EasyMocap's metres" if unit == "auto" else "as given")
    K = np.array([intrinsics[name][0] for name in common])
    dist = np.array([intrinsics[name][1] for name in common])
    return RigCalibration(
        camera_names=tuple(common),
        cameras=Cameras(K=K, R=R, t=t, dist=dist if np.any(dist) else None, distortion_model="opencv"),
        image_size=None,
        source=source,
        unit=resolved,
    )


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
    if np.abs(matrix @ matrix.T - np.eye(3)).max() > 1e-4 or np.linalg.det(matrix) <= 0:
        raise DataFormatError(f"{extri}: key 'Rot_{name}'", "a rotation matrix (R R^T = I, det R = +1)", str(matrix.tolist()))
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
# jaxpose camera file and Human3.6M cameras.h5


def _pick_subject(path: Path, subjects: Sequence[str], subject: str | None) -> str:
    if subject is None:
        if len(subjects) == 1:
            return subjects[0]
        raise DataFormatError(path, "a subject to pick (the file holds several rigs)", f"subjects {list(subjects)}")
    if subject not in subjects:
        raise DataFormatError(path, f"the rig of subject {subject!r}", f"subjects {list(subjects)}")
    return subject


def _image_sizes(sizes: Sequence[tuple[int, int] | None]) -> np.ndarray | None:
    return None if any(size is None for size in sizes) else np.array(sizes, dtype=np.int64)


def _read_camera_file(path: Path, subject: str | None) -> RigCalibration:
    rigs, sizes = _parse_camera_file(read_json(path, "a jaxpose camera file"), path)
    subject = _pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    return RigCalibration(tuple(names), cameras, _image_sizes(sizes[subject]), str(path), "mm")


def _read_h36m_file(path: Path, subject: str | None) -> RigCalibration:
    rigs = _read_h36m(path)
    subject = _pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    sizes = [H36M_IMAGE_SIZES.get(name) for name in names]
    return RigCalibration(tuple(names), cameras, _image_sizes(sizes), f"{path} (subject {subject})", "mm")


# ----------------------------------------------------------------------------------------------
# Human3.6M distortion -> OpenCV


def _distort_h36m(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p0, p1, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    tangential = p0 * y + p1 * x
    return x * (radial + tangential) + p1 * r2, y * (radial + tangential) + p0 * r2


def _opencv_terms(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The OpenCV model's displacement is linear in (k1, k2, p1, p2, k3): [N, 5] for x and for y."""
    r2 = x * x + y * y
    terms_x = np.stack([x * r2, x * r2**2, 2.0 * x * y, r2 + 2.0 * x * x, x * r2**3], -1)
    terms_y = np.stack([y * r2, y * r2**2, r2 + 2.0 * y * y, 2.0 * x * y, y * r2**3], -1)
    return terms_x, terms_y


def opencv_from_h36m_distortion(
    dist_h36m: np.ndarray, K: np.ndarray, image_size: Sequence[int] | None = None, grid: int = 41
) -> tuple[np.ndarray, float]:
    """The OpenCV (k1, k2, p1, p2, k3) closest to Human3.6M's distortion, and the largest pixel error.

    Human3.6M's tangential terms (docs/conventions.md) are not OpenCV's: x gets p[0] x y + p[1] (x^2 + r^2)
    where OpenCV has 2 p1 x y + p2 (r^2 + 2 x^2), so no OpenCV vector reproduces it exactly.  Both
    models are linear in their coefficients, so the closest OpenCV vector is a linear least-squares
    fit, in pixels, over a `grid` x `grid` lattice spanning the image (mapped through K^-1 to
    normalized coordinates).  `image_size` (width, height) defaults to twice the principal point.
    Returns (dist f64[5], the largest pixel distance between the two models over the lattice).
    `dist_h36m` [C, 5] with `K` [C, 3, 3] (and `image_size` [C, 2]) gives f64[C, 5] and the
    largest error over all cameras.

    On Human3.6M's S1 cameras the largest error is 0.21 to 0.41 px, at the image corners (median
    about 0.05 px); the tangential terms themselves move the corners by 1.5 to 2.8 px.  What the
    five coefficients cannot hold is a shift of (p[1], p[0]) r^2 / 2: OpenCV's 12-coefficient model
    reproduces Human3.6M's exactly with p1 = p[0]/2, p2 = p[1]/2 and thin-prism s1 = p[1]/2,
    s3 = p[0]/2, but Anipose-family files and `jaxpose.camera` hold five.
    """
    dist_h36m, K = np.asarray(dist_h36m, np.float64), np.asarray(K, np.float64)
    if dist_h36m.ndim == 2:
        sizes = [None] * len(dist_h36m) if image_size is None else list(image_size)
        fits = [opencv_from_h36m_distortion(d, k, s, grid) for d, k, s in zip(dist_h36m, K, sizes, strict=True)]
        return np.array([fit[0] for fit in fits]), max(fit[1] for fit in fits)
    if dist_h36m.shape != (5,) or K.shape != (3, 3):
        raise ValueError(f"opencv_from_h36m_distortion: dist [5] and K [3, 3] expected, got {dist_h36m.shape}, {K.shape}")
    (fx, skew, cx), (_, fy, cy) = K[0], K[1]
    width, height = (2.0 * cx, 2.0 * cy) if image_size is None else (float(image_size[0]), float(image_size[1]))
    u, v = np.meshgrid(np.linspace(0.0, width, grid), np.linspace(0.0, height, grid))
    y = (v.ravel() - cy) / fy
    x = (u.ravel() - cx - skew * y) / fx
    x_d, y_d = _distort_h36m(x, y, dist_h36m)
    terms_x, terms_y = _opencv_terms(x, y)
    # Pixel displacements: u = fx x_d + skew y_d + cx, v = fy y_d + cy.
    A = np.concatenate([fx * terms_x + skew * terms_y, fy * terms_y])
    b = np.concatenate([fx * (x_d - x) + skew * (y_d - y), fy * (y_d - y)])
    dist_opencv = np.linalg.lstsq(A, b, rcond=None)[0]
    residual = (A @ dist_opencv - b).reshape(2, -1)
    return dist_opencv, float(np.sqrt((residual**2).sum(0)).max())


def opencv_rig_from_h36m(rig: RigCalibration) -> tuple[RigCalibration, float]:
    """A rig with Human3.6M's distortion converted to OpenCV's (`opencv_from_h36m_distortion`), and
    the largest pixel difference the conversion makes over the cameras' images."""
    if rig.cameras.distortion_model != "h36m" or rig.cameras.dist is None:
        return rig, 0.0
    dist, error = opencv_from_h36m_distortion(rig.cameras.dist, rig.cameras.K, rig.image_size)
    return dataclasses.replace(rig, cameras=rig.cameras.replace(dist=dist, distortion_model="opencv")), error


# ----------------------------------------------------------------------------------------------
# Writer


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


def _toml_array(values: np.ndarray) -> str:
    """A TOML array of floats (nested for 2-D), each written so that it reads back exactly."""
    values = np.asarray(values, np.float64)
    if values.ndim > 1:
        return "[ " + ", ".join(_toml_array(row) for row in values) + " ]"
    return "[ " + ", ".join(repr(float(value)) for value in values) + " ]"


def write_anipose_toml(path: str | Path, rig: RigCalibration, unit: Literal["m", "mm"] = "m") -> None:
    """Write `rig` in the Anipose/Pose2Sim calibration layout, translations in `unit`.

    One `[cam_<i>]` table per camera (name, size, matrix, distortions, rotation as a Rodrigues
    vector, translation, fisheye), then `[metadata]` with `unit`, which `read_rig_calibration`
    uses when reading the file with unit="auto".  Fisheye rigs are written as aniposelib writes
    them (`fisheye = true`, 4 coefficients).  A rig without image sizes is written without `size`
    (with a warning: Anipose and Pose2Sim need it).  Human3.6M's distortion model has no
    OpenCV/Anipose equivalent and is refused: convert the rig first with `opencv_rig_from_h36m`.
    """
    if unit not in ("m", "mm"):
        raise ValueError(f"write_anipose_toml: unit must be 'm' or 'mm', not {unit!r}")
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
    lines += ["[metadata]", f'unit = "{unit}"', ""]
    Path(path).write_text("\n".join(lines), encoding="utf-8")
