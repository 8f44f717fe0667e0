"""The sessions of a project without any calibration: its recordings grouped by rig, and each
session's rig recovered from its own recordings.

Labs record over days and cameras get bumped between them; one rig recovered from every recording
is then wrong for each.  The recordings are grouped (`group_recordings`):

- given by the user (--data.sessions SESSION=REC1,REC2 ...: every recording named once);
- else found from the data (`jaxpose.calibration.sessions.find_sessions`, where there are two recordings or
  more: rigs recovered from single recordings, on `SESSION_FRAMES` of their instants, those where the
  person moves most first, until every recording is explained by one: its detections re-project through
  that rig within 3 px of what the rig leaves on its own recording; then grouped as that module says);
- or all in one session (--data.no-find-sessions: one rig for every recording).

A recording that no rig explains (its own calibration failed, and no session's rig re-projects it as
well as that session's recordings) is refused with one line naming it: leaving it out would change
the training data behind the user's back, and its session can be given (--data.sessions) or the
recording left out (--data.recordings).  Each session's rig is then recovered from all its recordings
pooled (`jaxpose.rig.recovered.recover_rig`), each into its own upright metric world.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import re
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.rig.recovered import recover_rig, rig_detections
from jaxpose.skeleton import Skeleton

log = logging.getLogger(__name__)

SESSION_FRAMES = 150
"""Instants of each recording its own rig is recovered from to find the sessions (the synthetic study
of docs/calibration.md, "Sessions", found every session with 150): a rig that tells one session from
another need not be the session's best, which is recovered from all its recordings afterwards."""
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")  # a session name is part of a file name


@dataclasses.dataclass(frozen=True)
class RecoveredSession:
    """One session of a project without calibration: its recordings and the rig recovered from them."""

    name: str
    recordings: tuple[str, ...]
    reprojection_px: float
    """The rig's worst camera's median re-projection error (px) over the session's detections."""
    found: str
    """How the session was had: "labels" (--data.sessions), "data" (found) or "one" (one rig for all)."""
    calibration: object
    """The `jaxpose.calibration.Calibration` recovered from the session's recordings."""

    def summary(self) -> dict:
        """The session without its rig, JSON-ready (the prepared project's metadata)."""
        return {"name": self.name, "recordings": list(self.recordings), "reprojection_px": self.reprojection_px, "found": self.found}


def parse_sessions(entries: Sequence[str], names: Sequence[str]) -> dict[str, str]:
    """--data.sessions entries SESSION=REC1,REC2 as {recording: session} over the recordings `names`
    loaded; every recording must be named exactly once (names of recordings not loaded, e.g. left out
    by --data.recordings, are passed over)."""
    labels: dict[str, str] = {}
    unknown = []
    for entry in entries:
        session, _, members = entry.partition("=")
        if not _NAME.fullmatch(session) or not members:
            raise ValueError(f"--data.sessions {entry!r}: expected SESSION=RECORDING[,RECORDING...], SESSION of letters, digits, '_', '-', '.'")
        for member in (member.strip() for member in members.split(",")):
            if member in labels:
                raise ValueError(f"--data.sessions: recording {member!r} is in sessions {labels[member]!r} and {session!r}")
            labels[member] = session
            if member not in names:
                unknown.append(member)
    missing = [name for name in names if name not in labels]
    if missing:
        raise ValueError(f"--data.sessions names no session for the recordings {missing} (every recording needs one)")
    if unknown:
        log.info("--data.sessions: recordings %s are not loaded (--data.recordings): passed over", unknown)
    return {name: labels[name] for name in names}


def group_recordings(detections: Mapping[str, object], labels: Mapping[str, str] | None, find: bool, root: pathlib.Path):
    """The `jaxpose.calibration.sessions.SessionGrouping` of the recordings (`detections`: name ->
    `RigDetections`): by `labels` where given, else found from the data when `find` and there are two
    recordings or more, else one session of all.  A recording no rig explains is a `DataFormatError`."""
    from jaxpose.calibration import CalibrationConfig
    from jaxpose.calibration.sessions import Session, SessionGrouping, find_sessions, group_by_label

    names = tuple(detections)
    if labels is not None:
        return group_by_label(names, [labels[name] for name in names])
    if not find or len(names) < 2:
        return SessionGrouping((Session("session1", names, None),), (), "one", names)
    spread = {name: _spread(rows, 2 * SESSION_FRAMES) for name, rows in detections.items()}
    grouping = find_sessions(spread, CalibrationConfig(max_frames=SESSION_FRAMES), until_explained=True)
    log.info("sessions searched with %d of %d recordings calibrated alone", len(grouping.calibrations) + len(grouping.failures), len(names))
    for name, why in grouping.failures.items():
        session = grouping.session_of(name)
        log.info("recording %s: no rig of its own (%s); %s", name, why, f"its detections fit {session}'s rig" if session else "no rig fits it")
    if grouping.unfitted:
        name = grouping.unfitted[0]
        raise DataFormatError(
            root / name,
            "recordings that one of the rigs recovered from the recordings explains (sessions found from the data)",
            f"recording {name!r} fits no rig (its own: {grouping.failures.get(name, 'none')}); give its session with"
            f" --data.sessions or leave it out with --data.recordings",
        )
    return grouping


def recover_sessions(
    names: Sequence[str],
    known: Sequence[Mapping[str, dict]],
    aligned: Sequence[tuple[np.ndarray, np.ndarray]],
    camera_order: Sequence[str],
    skeleton: Skeleton,
    *,
    sessions: Sequence[str],
    find: bool,
    image_size: tuple[int, int] | None,
    max_frames: int,
    root: pathlib.Path,
    height_mm: float | None = None,
) -> tuple[tuple[RecoveredSession, ...], dict[str, RigCalibration]]:
    """Each session's rig, recovered from its recordings pooled on at most `max_frames` instants
    (`sessions`: --data.sessions entries, else grouped as `group_recordings` says); and every recording's rig
    by name.  `known` and `aligned`: each recording's known cameras and keypoints (`rig_detections`')."""
    names = list(names)
    detections = {
        name: rig_detections([name], [cameras], [part], camera_order, skeleton, image_size=image_size, root=root)
        for name, cameras, part in zip(names, known, aligned)
    }
    labels = parse_sessions(sessions, names) if sessions else None
    grouping = group_recordings(detections, labels, find, root)
    if len(grouping.sessions) > 1 or grouping.method != "one":
        log.info("sessions (%s): %s", grouping.method, "; ".join(f"{s.name}: {', '.join(s.recordings)}" for s in grouping.sessions))
    result, rigs = [], {}
    for session in grouping.sessions:
        members = [names.index(name) for name in session.recordings]
        pooled = rig_detections(
            [names[i] for i in members], [known[i] for i in members], [aligned[i] for i in members], camera_order, skeleton, image_size=image_size, root=root
        )
        rig, calibration = recover_rig(pooled, max_frames=max_frames, height_mm=height_mm)
        reprojection = float(np.max(calibration.reprojection_median_px))
        result.append(RecoveredSession(session.name, session.recordings, reprojection, grouping.method, calibration))
        rigs.update(dict.fromkeys(session.recordings, rig))
        log.info("session %s: rig recovered from %d recordings, worst camera's median re-projection %.2f px", session.name, len(members), reprojection)
    return tuple(result), rigs


def _spread(detections, count: int):
    """`detections` (a `RigDetections`) on at most `count` instants spread evenly over it."""
    frames = len(detections.keypoints)
    if frames <= count:
        return detections
    rows = np.linspace(0, frames - 1, count).round().astype(int)
    return dataclasses.replace(detections, keypoints=detections.keypoints[rows], confidence=detections.confidence[rows])
