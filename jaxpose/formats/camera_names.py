"""Which camera of a calibration a name means, across the tools that name them differently.

One camera is ``cam_1`` or ``cam1`` to Anipose, ``cam_01`` in a Pose2Sim calibration, ``int_cam01_img``
in Pose2Sim's scene calibration (named after its intrinsics image folder), ``cam01_json`` or ``cam01`` as a
Pose2Sim detection folder, ``sesh_..._synced_Cam1`` to FreeMoCap (its video's name) and ``1`` or ``01`` to
EasyMocap.  `match_cameras` pairs the names a user gives (detection folders, ``predict --intrinsics
CALIBRATION CAMERA``) with a calibration's camera names, in this order of preference:

1. the same name;
2. the same `camera_key`: case, separators and leading zeros ignored, and the affixes the tools add
   dropped (``int_`` / ``ext_`` and ``_img`` of Pose2Sim's calibration folders, ``_json`` of OpenPose
   folders), so ``cam_01``, ``Cam1``, ``int_cam01_img`` and ``cam01_json`` are all ``cam 1``;
3. one key ending with the other, word by word (FreeMoCap's ``..._synced_Cam1`` is ``cam1``, EasyMocap's
   ``1`` is ``cam01``; ``1`` is never ``cam11``);
4. where the caller allows it and no name matches any camera at all, by order, as Pose2Sim pairs them:
   the names sorted by their last number, then name, against the calibration's cameras in file order,
   said in a warning.

Every name must end at exactly one camera and no two at the same one, or the match is refused
(`CameraMismatch`, whose message names the cameras and the names at fault).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence

logger = logging.getLogger(__name__)

# Words the tools add around a camera's name: Pose2Sim's intrinsics / extrinsics image folders
# (int_cam01_img, ext_cam01_img) and OpenPose's output folders (cam01_json).
_PREFIXES = ("int", "ext")
_SUFFIXES = ("img", "json")
_SYNONYMS = {"camera": "cam"}
_WORDS = re.compile(r"[a-z]+|\d+")


class CameraMismatch(ValueError):
    """The names cannot be matched to the calibration's cameras one to one; the message lists the cameras
    and says which names lack one, could be several, or share one."""


def camera_key(name: str) -> tuple[str, ...]:
    """The words of a camera name that identify it: lower case, numbers without leading zeros, the
    tools' affixes dropped (``int_cam01_img``, ``Cam_1``, ``cam01_json`` -> ("cam", "1"))."""
    words = [_SYNONYMS.get(word, str(int(word)) if word.isdigit() else word) for word in _WORDS.findall(name.lower())]
    if len(words) > 1 and words[0] in _PREFIXES:
        words = words[1:]
    if len(words) > 1 and words[-1] in _SUFFIXES:
        words = words[:-1]
    return tuple(words)


def _ends_with(longer: tuple[str, ...], shorter: tuple[str, ...]) -> bool:
    return 0 < len(shorter) <= len(longer) and longer[len(longer) - len(shorter) :] == shorter


def _candidates(name: str, cameras: Sequence[str]) -> list[str]:
    """The cameras `name` may mean, at the first rule of the module docstring that finds any."""
    if name in cameras:
        return [name]
    key = camera_key(name)
    same = [camera for camera in cameras if camera_key(camera) == key]
    if same:
        return same
    return [camera for camera in cameras if _ends_with(camera_key(camera), key) or _ends_with(key, camera_key(camera))]


def _order_key(name: str) -> tuple[int, str]:
    numbers = re.findall(r"\d+", name)
    return (int(numbers[-1]) if numbers else -1, name)


def match_cameras(cameras: Sequence[str], names: Sequence[str], source: str, by_order: bool = False) -> dict[str, str]:
    """name -> the camera of `cameras` (a calibration's, from `source`) it means, for every name of
    `names` (distinct), by the rules of the module docstring; `by_order` allows the last rule.  Raises
    `CameraMismatch`; logs where a name is not the camera's own."""
    cameras, names = tuple(cameras), tuple(names)
    found = {name: _candidates(name, cameras) for name in names}
    unmatched = [name for name, candidates in found.items() if not candidates]
    if by_order and len(unmatched) == len(names) == len(cameras) > 1:
        ordered = sorted(names, key=_order_key)
        logger.warning(
            "%s: no camera name matches %s; pairing them by order as Pose2Sim does (names by their last number, "
            "cameras in file order): %s",
            source, list(names), ", ".join(f"{name} = {camera}" for name, camera in zip(ordered, cameras)),
        )  # fmt: skip
        return dict(zip(ordered, cameras))
    ambiguous = {name: candidates for name, candidates in found.items() if len(candidates) > 1}
    chosen = {name: candidates[0] for name, candidates in found.items() if len(candidates) == 1}
    taken = {}
    for name, camera in chosen.items():
        taken.setdefault(camera, []).append(name)
    shared = {camera: sharing for camera, sharing in taken.items() if len(sharing) > 1}
    if unmatched or ambiguous or shared:
        problems = [f"which lack {unmatched}"] if unmatched else []
        problems += [f"where {name!r} could be any of {candidates}" for name, candidates in ambiguous.items()]
        problems += [f"where {sharing} would all be {camera!r}" for camera, sharing in shared.items()]
        raise CameraMismatch(f"cameras {list(cameras)}, {'; '.join(problems)}")
    renamed = {name: camera for name, camera in chosen.items() if name != camera}
    if renamed:
        pairs = ", ".join(f"{name} = {camera}" for name, camera in renamed.items())
        logger.info("%s: cameras matched by name: %s", source, pairs)
    return chosen
