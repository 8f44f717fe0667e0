"""OpenSim marker files (``.trc``): read the ones real tools write, and write ones OpenSim reads.

A TRC file is tab-separated text: five header lines, then one row per frame::

    PathFileType  4  (X/Y/Z)  <file name>
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    60  60  100  21  m  60  0  100
    Frame#  Time  RHip  <empty>  <empty>  RKnee  ...            (each marker name spans its 3 columns)
    <empty>  <empty>  X1  Y1  Z1  X2  Y2  Z2  ...
    1  0.0  x  y  z  x  y  z  ...                             (an empty field is a missing value)

`read_trc` takes the variations of real writers as they are (Pose2Sim, OpenCap, FreeMoCap): a blank line
or none after the header, ``NumFrames`` different from the number of rows, ``Frame#`` from 0 or 1,
trailing tabs, ``PathFileType  4`` with spaces.  `write_trc` writes the five lines as Pose2Sim does (no
blank line), every marker name in 3 columns and missing values as empty fields.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.outputs import atomic_output

HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate", "OrigDataStartFrame",
               "OrigNumFrames")  # fmt: skip
_UNSAFE_NAME = re.compile(r"[^A-Za-z0-9_.\-]")


@dataclasses.dataclass(frozen=True)
class TrcFile:
    """The contents of a TRC file."""

    header: dict[str, str]
    """The key/value pairs of lines 2 and 3, as written (DataRate, NumFrames, Units, ...)."""
    path_line: str
    """Line 1 as written (``PathFileType 4 (X/Y/Z) <file name>``)."""
    marker_names: tuple[str, ...]
    frame_numbers: np.ndarray
    """int64[N] the Frame# column."""
    times: np.ndarray
    """float64[N] seconds, the Time column."""
    markers: np.ndarray
    """float64[N, M, 3] in `units`; NaN where a field is empty."""

    @property
    def rate(self) -> float:
        """DataRate, frames per second."""
        return float(self.header["DataRate"])

    @property
    def units(self) -> str:
        return self.header["Units"]


def marker_name(name: str) -> str:
    """A joint name as an OpenSim marker name: characters other than letters, digits, ``_ . -`` become
    ``_`` (OpenSim component names cannot hold ``/``): ``Neck/Nose`` -> ``Neck_Nose``."""
    return _UNSAFE_NAME.sub("_", name)


def read_trc(path: str | Path) -> TrcFile:
    """Read a TRC file; malformed ones raise `DataFormatError` naming the line."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as error:
        raise DataFormatError(path, "a readable TRC file", f"{type(error).__name__}: {error.strerror}") from None
    if len(lines) < 5:
        raise DataFormatError(path, "a TRC file of 5 header lines and data rows", f"{len(lines)} lines")
    if not lines[0].split() or lines[0].split()[0] != "PathFileType":
        raise DataFormatError(path, "line 1 starting with PathFileType", repr(lines[0][:60]))
    keys = [field.strip() for field in lines[1].split("\t") if field.strip()]
    values = [field.strip() for field in lines[2].split("\t")][: len(keys)]
    header = dict(zip(keys, values))
    for key in ("DataRate", "NumMarkers", "Units"):
        if not header.get(key):
            raise DataFormatError(path, f"lines 2-3 holding {key} and its value", f"keys {keys}, values {values}")
    try:
        count = int(header["NumMarkers"])
        float(header["DataRate"])
    except ValueError:
        raise DataFormatError(path, "numbers for DataRate and NumMarkers (line 3)", str(values)) from None
    names_row = lines[3].split("\t")
    if [field.strip() for field in names_row[:2]] != ["Frame#", "Time"]:
        raise DataFormatError(path, "line 4 starting with Frame#, Time", repr(lines[3][:60]))
    names = tuple(field.strip() for field in names_row[2:] if field.strip())
    if len(names) != count:
        raise DataFormatError(path, f"{count} marker names on line 4 (NumMarkers)", f"{len(names)}: {names[:5]}...")
    width = 2 + 3 * count
    rows = []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        fields = line.rstrip("\r\n").split("\t")
        if len(fields) > width and any(field.strip() for field in fields[width:]):
            raise DataFormatError(path, f"{width} fields per data row (2 + 3 x {count} markers)",
                                  f"{len(fields)} on line {number}")  # fmt: skip
        fields = (fields + [""] * width)[:width]  # writers may drop trailing empty fields
        try:
            rows.append(np.array(fields, np.float64))
        except ValueError:
            try:
                rows.append(np.array([float(field) if field.strip() else np.nan for field in fields], np.float64))
            except ValueError as error:
                raise DataFormatError(path, "numbers or empty fields in the data rows", f"line {number}: {error}") from None
    table = np.stack(rows) if rows else np.zeros((0, width))
    if not np.isfinite(table[:, :2]).all():
        line = 6 + int(np.flatnonzero(~np.isfinite(table[:, :2]).all(1))[0])
        raise DataFormatError(path, "a Frame# and a Time on every data row", f"an empty one on data row near line {line}")
    return TrcFile(
        header=header,
        path_line=lines[0],
        marker_names=names,
        frame_numbers=table[:, 0].astype(np.int64),
        times=table[:, 1].copy(),
        markers=table[:, 2:].reshape(len(table), count, 3),
    )


def write_trc(
    path: str | Path,
    markers: np.ndarray,
    marker_names: Sequence[str],
    rate: float,
    units: str = "m",
    path_note: str = "",
    first_frame: int = 1,
    decimals: int | None = None,
    time_zero_frame: int | None = None,
) -> Path:
    """Write markers f[N, M, 3] (in `units`; NaN = missing, written as empty fields) as a TRC file.

    Frame# runs from `first_frame` (also OrigDataStartFrame), Time = (Frame# - `time_zero_frame`) / rate, the
    frame at Time 0 being the first row's unless given (Pose2Sim numbers Frame# from 1 and writes Time =
    Frame# / rate, which is `time_zero_frame=0`).  Names are made OpenSim-safe by `marker_name`.  The
    file is written to a temporary name and renamed into place (`jaxpose.formats.outputs.atomic_output`).
    Line 1 is ``PathFileType\\t4\\t(X/Y/Z)\\t<file name>`` with `path_note` after the name in the same
    field (no tab), where the file can state its axes.  `decimals` defaults to 6 for m, 3 otherwise.
    """
    path = Path(path)
    markers = np.asarray(markers, np.float64)
    if markers.ndim != 3 or markers.shape[-1] != 3 or markers.shape[1] != len(marker_names):
        raise ValueError(f"markers must be [N, {len(marker_names)}, 3], got {markers.shape}")
    if not rate > 0:
        raise ValueError(f"rate must be positive, got {rate}")
    if "\t" in path_note or "\n" in path_note:
        raise ValueError("path_note must not hold tabs or line breaks")
    decimals = (6 if units == "m" else 3) if decimals is None else decimals
    count, markers_count = markers.shape[:2]
    names = [marker_name(name) for name in marker_names]
    rate_text = f"{rate:g}"
    # A file name with a tab or line break (a recording folder so named) would break the header's fields.
    path_field = "".join(" " if ch.isspace() else ch for ch in path.name) + (f" {path_note}" if path_note else "")
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path_field}",
        "\t".join(HEADER_KEYS),
        "\t".join([rate_text, rate_text, str(count), str(markers_count), units, rate_text, str(first_frame), str(count)]),
        "Frame#\tTime\t" + "\t".join(f"{name}\t\t" for name in names),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, markers_count + 1)),
    ]
    flat = markers.reshape(count, -1)
    finite = np.isfinite(flat)
    text = np.char.mod(f"%.{decimals}f", np.where(finite, flat, 0.0))
    text = np.where(finite, text, "")
    zero = first_frame if time_zero_frame is None else time_zero_frame
    for row in range(count):
        lines.append(f"{first_frame + row}\t{(first_frame + row - zero) / rate:.6f}\t" + "\t".join(text[row]))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
