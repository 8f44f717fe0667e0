"""The calibration files users already have, read as they are.

`read_rig_calibration` returns one `RigCalibration` (`jaxpose.formats.rig_cameras`: camera names,
float64 numpy `Cameras` [C] in the library's conventions, image sizes) from any of:

1. **Anipose-family TOML** (`*.toml`, `jaxpose.formats.anipose_toml`), as aniposelib, Anipose,
   Pose2Sim and FreeMoCap write it, in metres, millimetres or the calibration board's unit (see
   `read_rig_calibration` for how "auto" tells them apart).  `anipose_toml.write_anipose_toml`
   writes a rig back in that layout (what most tools read).
2. **EasyMocap / OpenCV FileStorage YAML** (`intri.yml` + `extri.yml`, `jaxpose.formats.easymocap_yaml`),
   in metres.
3. **The project's camera file** (`*.json`, `jaxpose.formats.camera_file`), millimetres.
4. **Human3.6M's `cameras.h5`** (`*.h5`, `jaxpose.formats.h36m_cameras`), millimetres, one rig per subject.

`find_calibration` finds the calibration file in a recording folder by content.  Every error is a
`DataFormatError` naming the file and, where there is one, the table or key and what was found there.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import get_args

import numpy as np

from jaxpose.formats import anipose_toml, camera_file, easymocap_yaml, h36m_cameras
from jaxpose.formats.rig_cameras import CalibrationUnit, RigCalibration, check_distinct_centres
from jaxpose.formats.errors import DataFormatError

__all__ = ["CalibrationUnit", "RigCalibration", "find_calibration", "read_rig_calibration"]

ACCEPTED = (
    "an Anipose/Pose2Sim/FreeMoCap calibration .toml, EasyMocap intri.yml + extri.yml (or their folder), "
    "a jaxpose camera file .json, or Human3.6M's cameras.h5"
)


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
    if not path.is_dir() and not path.is_file():  # a device (a link to /dev/zero would be read without end), a pipe
        raise DataFormatError(path, ACCEPTED, "not a regular file")
    if path.is_dir():
        found = find_calibration(path)
        if found is None:
            if (path / "extri.yml").is_file():
                return easymocap_yaml.read_easymocap(path, unit)  # says that intri.yml is missing
            names = sorted(entry.name for entry in path.iterdir())
            raise DataFormatError(path, f"a folder holding {ACCEPTED}", f"none among {names[:30]}")
        path = found
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return anipose_toml.read_anipose_toml(path, unit)
    if suffix in (".yml", ".yaml"):
        return easymocap_yaml.read_easymocap(path, unit)
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
    return (
        anipose_toml.is_anipose_calibration(path)
        or easymocap_yaml.is_easymocap_intrinsics(path)
        or camera_file.is_camera_file(path)
    )


# ----------------------------------------------------------------------------------------------
# Files holding one rig per subject


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
    rigs = camera_file.load_cameras(path, np.float64)
    subject = _pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    check_distinct_centres(str(path), names, cameras.R, cameras.t)
    sizes = camera_file.load_image_sizes(path)[subject]
    return RigCalibration(tuple(names), cameras, _image_sizes(sizes), str(path), "mm")


def _read_h36m_file(path: Path, subject: str | None) -> RigCalibration:
    rigs = h36m_cameras.read_h36m_cameras(path, np.float64)
    subject = _pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    check_distinct_centres(f"{path} (subject {subject})", names, cameras.R, cameras.t)
    sizes = [h36m_cameras.H36M_IMAGE_SIZES.get(name) for name in names]
    return RigCalibration(tuple(names), cameras, _image_sizes(sizes), f"{path} (subject {subject})", "mm")
