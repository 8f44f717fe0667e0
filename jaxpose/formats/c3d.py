"""C3D marker files, written with ezc3d (the optional extra ``pip install 'jaxpose[reconstruct]'``).

`write_c3d` writes markers with their labels, rate, unit and first frame; a frame's missing marker
(NaN) is written as C3D's invalid point (residual -1, as ezc3d does for NaN).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.outputs import atomic_output
from jaxpose.formats.trc import marker_name


def write_c3d(path: str | Path, markers: np.ndarray, marker_names: Sequence[str], rate: float, units: str, first_frame: int) -> Path:
    """Write markers f[N, M, 3] (in `units`, e.g. "mm") as a C3D file whose first frame is `first_frame`."""
    try:
        import ezc3d
    except ImportError:
        raise ImportError("writing .c3d needs ezc3d: pip install 'jaxpose[reconstruct]' (or pip install ezc3d)") from None
    path = Path(path)
    markers = np.asarray(markers, np.float64)
    if markers.ndim != 3 or markers.shape[-1] != 3 or markers.shape[1] != len(marker_names):
        raise ValueError(f"markers must be [N, {len(marker_names)}, 3], got {markers.shape}")
    file = ezc3d.c3d()
    file["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    file["parameters"]["POINT"]["LABELS"]["value"] = tuple(marker_name(name) for name in marker_names)
    file.add_parameter("POINT", "UNITS", [units])
    points = np.ones((4, markers.shape[1], markers.shape[0]))
    points[:3] = markers.transpose(2, 1, 0)
    file["data"]["points"] = points
    file["header"]["points"]["first_frame"] = int(first_frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as temporary:
        file.write(str(temporary))
    return path
