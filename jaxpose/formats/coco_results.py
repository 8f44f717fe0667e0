"""COCO keypoint-results files, the one parser of them: a JSON list of ``{"image_id", "keypoints": [x, y,
score] * J, ...}`` (what COCO-style detectors write; AlphaPose's file-name image ids and extra keys too).

`jaxpose.formats.keypoint_files` groups the entries by frame, a camera's detections;
`jaxpose.formats.detection_file` keeps them a pose per entry, in file order.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats import fast_json
from jaxpose.formats.errors import DataFormatError


def load_coco_entries(path: str | Path) -> tuple[list[Any], np.ndarray]:
    """The entries of a COCO keypoint-results file in file order: (image ids as written, f32[N, J, 3]).

    Each entry must be an object with ``image_id`` (int or string) and ``keypoints`` ([x, y, score] * J,
    the same J for all); other keys (``score`` above 1, AlphaPose's ``box`` and ``idx``) are ignored.
    """
    path = Path(path)
    expected = 'a COCO keypoint-results list [{"image_id": ..., "keypoints": [x, y, score, ...]}, ...]'
    try:
        entries = fast_json.loads(path.read_bytes())
    except OSError as error:
        raise DataFormatError(path, expected, f"{type(error).__name__}: {error.strerror}") from None
    except ValueError as error:
        raise DataFormatError(path, expected, f"invalid JSON: {error}") from None
    if not isinstance(entries, list):
        found = f"a JSON {type(entries).__name__}" + (f" (keys: {sorted(entries)[:8]})" if isinstance(entries, dict) else "")
        raise DataFormatError(path, expected, found)
    image_ids, flat, length = [], [], None
    for index, entry in enumerate(entries):
        if not isinstance(entry, dict) or "image_id" not in entry or "keypoints" not in entry:
            found = f"entry {index} is " + (
                f"an object without 'image_id' or 'keypoints' (keys: {sorted(entry)})"
                if isinstance(entry, dict) else f"a {type(entry).__name__}")  # fmt: skip
            raise DataFormatError(path, expected, found)
        image_id, values = entry["image_id"], entry["keypoints"]
        if isinstance(image_id, bool) or not isinstance(image_id, int | str):
            raise DataFormatError(path, "image_id an integer or a file-name string", f"entry {index}: {image_id!r}")
        if not isinstance(values, list) or not values or len(values) % 3:
            found = f"{len(values)} values" if isinstance(values, list) else f"a {type(values).__name__}"
            raise DataFormatError(path, "keypoints a list of [x, y, score] * J values", f"entry {index}: {found}")
        if length is None:
            length = len(values)
        elif len(values) != length:
            raise DataFormatError(
                path, f"keypoints of the same length in every entry ({length} in entry 0)",
                f"{len(values)} values in entry {index} (image_id {image_id!r})",
            )  # fmt: skip
        image_ids.append(image_id)
        flat.append(values)
    try:
        keypoints = np.array(flat, np.float32).reshape(len(flat), (length or 0) // 3, 3)
    except (TypeError, ValueError):
        index = next(i for i, v in enumerate(flat) if not all(x is None or isinstance(x, int | float) for x in v))
        raise DataFormatError(path, "numbers in keypoints", f"entry {index}: {flat[index][:6]}...") from None
    return image_ids, keypoints
