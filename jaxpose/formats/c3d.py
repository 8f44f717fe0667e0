"""C3D marker files, written with ezc3d (the optional extra ``pip install 'jaxpose[reconstruct]'``).

`write_c3d` writes markers with their labels, rate, unit and first frame; a frame's missing marker
(NaN) is written as C3D's invalid point (residual -1, as ezc3d does for NaN).

C3D numbers frames from 1 (ezc3d's ``first_frame`` from 0: the recording's frame F is the C3D frame F + 1)
and its header holds the first and last frame in 16-bit words, 65535 at most.  The frame range is
therefore also written as the 32-bit TRIAL:ACTUAL_START_FIELD and TRIAL:ACTUAL_END_FIELD (each two
unsigned 16-bit words, the low one first: the parameters readers such as Vicon's and the ``c3d`` package
take when present); a range past 65535 is written in the header as 1 to the number of frames, as the
C3D user guide advises, never as a number that wrapped around.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.outputs import atomic_output
from jaxpose.formats.trc import marker_name

HEADER_LIMIT = 0xFFFF
"""The largest frame number the header's 16-bit words hold."""


def long_frame_words(frame: int) -> list[int]:
    """A C3D frame number as the two 16-bit words of TRIAL:ACTUAL_*_FIELD, low word first; each as the
    signed 16-bit integer that holds its bits (C3D integer parameters are signed, these are read unsigned)."""
    if not 0 <= frame <= 0xFFFFFFFF:
        raise ValueError(f"C3D frame numbers lie in [0, {0xFFFFFFFF}], got {frame}")
    return [int(np.uint16(word).view(np.int16)) for word in (frame & 0xFFFF, frame >> 16)]


def write_c3d(path: str | Path, markers: np.ndarray, marker_names: Sequence[str], rate: float, units: str, first_frame: int) -> Path:
    """Write markers f[N, M, 3] (in `units`, e.g. "mm") as a C3D file whose first frame is the recording's
    frame `first_frame` (counted from 0, as the .trc's OrigDataStartFrame)."""
    try:
        import ezc3d
    except ImportError:
        raise ImportError("writing .c3d needs ezc3d: pip install 'jaxpose[reconstruct]' (or pip install ezc3d)") from None
    path = Path(path)
    markers = np.asarray(markers, np.float64)
    if markers.ndim != 3 or markers.shape[-1] != 3 or markers.shape[1] != len(marker_names):
        raise ValueError(f"markers must be [N, {len(marker_names)}, 3], got {markers.shape}")
    first, last = int(first_frame) + 1, int(first_frame) + len(markers)  # C3D's frame numbers
    file = ezc3d.c3d()
    file["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    file["parameters"]["POINT"]["LABELS"]["value"] = tuple(marker_name(name) for name in marker_names)
    file.add_parameter("POINT", "UNITS", [units])
    for name, frame in (("ACTUAL_START_FIELD", first), ("ACTUAL_END_FIELD", last)):
        file.add_parameter("TRIAL", name, [0, 0])
        # ezc3d's add_parameter stores a list of integers as floats; these are integers.
        file["parameters"]["TRIAL"][name] |= {"type": ezc3d.ezc3d.INT, "value": np.array(long_frame_words(frame))}
    points = np.ones((4, markers.shape[1], markers.shape[0]))
    points[:3] = markers.transpose(2, 1, 0)
    file["data"]["points"] = points
    file["header"]["points"]["first_frame"] = first - 1 if last <= HEADER_LIMIT else 0
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as temporary:
        file.write(str(temporary))
    return path
