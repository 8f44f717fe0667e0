"""One rule for detector scores, whichever file brings them (OpenPose and COCO JSON through
`jaxpose.formats.keypoint_files`, ``detections.npz`` through `jaxpose.formats.detections_npz`).

- A score is a number >= 0; 0 means "not detected".  A negative score is refused, naming the file and
  where: no detector means anything by it, and read as "missing" it would hide a broken writer.
- A score above 1 is clipped to 1, and the reader counts how many it clipped (`normalise_scores`), so that
  the project's table can show it.  Some detectors give heatmap or SimCC maxima that pass 1 a little
  (RTMPose in Pose2Sim's demo: up to 1.015), and COCO results files may hold 0/1/2 visibility flags
  (pycocotools' demo results): left as they are they would weigh one camera up to 2x in the
  triangulation.  Clipping rather than dividing by a file's or a camera's largest score, because a
  division would change every score of that camera by how high its single best one happened to be (the
  same detection would weigh differently in two cameras, and `--data.min-confidence` would cut at a
  different quality in each), while clipping leaves every score in [0, 1] as it was and only makes the
  over-confident ones equal (`jaxpose.layouts` clipped there before the lifting already).
- A keypoint with a non-finite coordinate or score: in a JSON file it is undetected (score 0), as
  OpenPose-style writers that print NaN mean it; a ``detections.npz`` must say so with confidence 0.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jaxpose.formats.errors import DataFormatError

MAX_SCORE = 1.0
EXPECTED = "detector scores >= 0 (0 = not detected; above 1 clipped to 1)"


def normalise_scores(scores: np.ndarray, locate: Callable[[tuple[int, ...]], tuple[str, str]]) -> tuple[np.ndarray, int]:
    """`scores` (finite) by the rule of the module docstring: (scores clipped to `MAX_SCORE`, how many were
    above it).  A negative score raises `DataFormatError`; `locate(index)` gives the (file, where in it)
    of the score at `index` for the message."""
    negative = scores < 0
    if negative.any():
        index = tuple(int(i) for i in np.argwhere(negative)[0])
        where, place = locate(index)
        found = f"{scores[index]:g} at {place} ({int(negative.sum())} negative scores in all)"
        raise DataFormatError(where, EXPECTED, found)
    above = scores > MAX_SCORE
    return (np.minimum(scores, np.float32(MAX_SCORE)) if above.any() else scores), int(above.sum())
