"""Frame numbers of detection files: read from file names and COCO image ids, and checked.

A frame file's number is the last run of digits of its name once OpenPose's ``_keypoints.json`` or
``.json`` is removed; a COCO image id is the number itself or a file name whose last digit run (its
extension removed) is.  Every reader of frames (`jaxpose.formats.keypoint_files`,
`jaxpose.formats.detections_npz`) refuses numbers no int64 arithmetic survives and a stray frame far
from the others (`check_frame_numbers`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence

import numpy as np

from jaxpose.formats.errors import DataFormatError

OPENPOSE_SUFFIX = "_keypoints.json"
_LAST_DIGITS = re.compile(r"(\d+)(?!.*\d)", re.DOTALL)


def frame_stem(name: str) -> str:
    """A frame file's name without ``_keypoints.json`` (OpenPose's suffix) or ``.json``: the frame's image id."""
    return name.removesuffix(OPENPOSE_SUFFIX) if name.endswith(OPENPOSE_SUFFIX) else name.removesuffix(".json")


MAX_FRAME_NUMBER = 2**62
"""Frame numbers at or above this are refused: they pass no int64 arithmetic safely."""
MAX_FRAME_GAP = 100_000
"""Frames of one camera more than this far apart (33 min at 50 fps) are refused, naming the stray file: a
recording is held on its whole frame axis, so one stray frame number would cost memory for every frame between."""


def frame_number(name: str) -> int:
    """The frame number of a file name: the last run of digits of its `frame_stem`.

    ``clip_000000000123_keypoints.json`` -> 123, ``cam01.0010.json`` -> 10, ``frame_00001.json`` -> 1.
    """
    match = _LAST_DIGITS.search(frame_stem(name))
    if match is None:
        raise DataFormatError(name, "a frame number in the file name (e.g. cam01.0010.json)", "no digits")
    return checked_frame_number(int(match.group(1)), name)


def checked_frame_number(number: int, where: str) -> int:
    if number >= MAX_FRAME_NUMBER:
        raise DataFormatError(where, "a frame number below 2^62", f"frame number {number}")
    return number


def check_frame_numbers(frames: np.ndarray, source: str, owners: Sequence[str]) -> None:
    """Refuse a frame number out of range or far beyond the others (`MAX_FRAME_GAP`), naming where it came from."""
    if len(frames) and (np.abs(frames) >= MAX_FRAME_NUMBER).any():
        row = int(np.argmax(np.abs(frames) >= MAX_FRAME_NUMBER))
        raise DataFormatError(source, "frame numbers below 2^62", f"{owners[row]}: frame number {frames[row]}")
    if len(frames) < 2:
        return
    order = np.argsort(frames, kind="stable")
    gaps = np.diff(frames[order])
    widest = int(np.argmax(gaps))
    if gaps[widest] > MAX_FRAME_GAP:
        before, after = order[widest], order[widest + 1]
        stray = after if len(frames) - widest - 1 <= widest + 1 else before  # the side with fewer frames is the stray
        raise DataFormatError(
            source,
            f"the frames of one camera within {MAX_FRAME_GAP:,} of each other",
            f"{owners[stray]} (frame {frames[stray]:,}) lies {int(gaps[widest]):,} frames from the next frame; a stray file?",
        )


def image_frame_number(image_id: int | str) -> int:
    """The frame number of a COCO image_id: the int itself, or the last digit run of a file-name string
    with its extension removed (``"out-002.jpg"`` -> 2)."""
    if isinstance(image_id, int):
        return checked_frame_number(image_id, f"image_id {image_id}")
    stem = os.path.splitext(image_id)[0] or image_id
    match = _LAST_DIGITS.search(stem)
    if match is None:
        raise DataFormatError(repr(image_id), "an image_id with a frame number (digits)", "no digits")
    return checked_frame_number(int(match.group(1)), repr(image_id))
