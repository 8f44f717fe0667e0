"""The calibration files users already have, read as they are.

`read_rig_calibration` returns one `RigCalibration` (`jaxpose.formats.rig_cameras`: camera names,
float64 numpy `Cameras` [C] in the library's conventions, image sizes) from any of the `FORMATS`, each
a module that recognises and reads its kind (a `CalibrationFormat`):

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

from pathlib import Path
from typing import get_args

from jaxpose.formats import anipose_toml, camera_file, easymocap_yaml, h36m_cameras
from jaxpose.formats.rig_cameras import CalibrationFormat, CalibrationUnit, RigCalibration
from jaxpose.formats.errors import DataFormatError

__all__ = ["FORMATS", "CalibrationUnit", "RigCalibration", "find_calibration", "read_rig_calibration"]

FORMATS: tuple[CalibrationFormat, ...] = (anipose_toml.FORMAT, easymocap_yaml.FORMAT, camera_file.FORMAT, h36m_cameras.FORMAT)
ACCEPTED = ", ".join(kind.description for kind in FORMATS[:-1]) + f", or {FORMATS[-1].description}"


def read_rig_calibration(
    path: str | Path, unit: CalibrationUnit = "auto", subject: str | None = None
) -> RigCalibration:
    """Read a calibrated rig from any of the `FORMATS`, told by the file's suffix.

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
        if found is None and (path / "extri.yml").is_file():
            found = path / "extri.yml"  # EasyMocap's reader says that intri.yml is missing
        if found is None:
            names = sorted(entry.name for entry in path.iterdir())
            raise DataFormatError(path, f"a folder holding {ACCEPTED}", f"none among {names[:30]}")
        path = found
    suffix = path.suffix.lower()
    kind = next((kind for kind in FORMATS if suffix in kind.suffixes), None)
    if kind is None:
        raise DataFormatError(path, ACCEPTED, f"a file with suffix {suffix!r}")
    return kind.read(path, unit, subject)


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
    found = [
        entry for entry in sorted(folder.iterdir())
        if entry.is_file() and any(kind.recognise is not None and kind.recognise(entry) for kind in FORMATS)
    ]  # fmt: skip
    if len(found) > 1:
        raise DataFormatError(
            folder, "one calibration file in the folder", f"{len(found)}: {[entry.name for entry in found]}"
        )
    return found[0] if found else None
