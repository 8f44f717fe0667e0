"""The rigs recovered from the recordings when a project has no calibration, one per session, and the
ground truth brought into a recovered rig's world.

`jaxpose.calibrate` recovers a rig from the person seen by every camera (the instants where each view
sees exactly one person), with the image sizes and any intrinsics the recordings' detections.npz give.
With several people in view (`several_people`) the people are first matched across views by their
epipolar geometry (`jaxpose.calibration.matching`), one row per person and instant; the rig recovered
from those then associates everyone (`jaxpose.rig.association`), and the rig is recovered again from
those rows (`people_rows`).
A recovered rig has its own world frame, so a ground truth in the motion capture's world is moved into
it for evaluation (`ground_truth_into_recovered_world`).

Labs record over days and cameras get bumped between them; one rig recovered from every recording
is then wrong for each.  The recordings are grouped into sessions (`group_recordings`):

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
pooled (`recover_rig`), each into its own upright metric world.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import pathlib
import re
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.camera import Cameras, projection_matrices
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.formats.rig_folder import GROUND_TRUTH_NPZ
from jaxpose.rig import association
from jaxpose.rig.geometry import triangulate_rows, undistort_views
from jaxpose.rig.recordings import one_person, recording_folders
from jaxpose.rotations import similarity
from jaxpose.skeleton import Skeleton

log = logging.getLogger(__name__)

MIN_ALIGNMENT_POINTS = 50  # ground-truth joints needed to align it with a recovered rig


def rig_detections(
    names: Sequence[str],
    known: Sequence[Mapping[str, dict]],
    aligned: Sequence[tuple[np.ndarray, np.ndarray]],
    camera_order: Sequence[str],
    skeleton: Skeleton,
    *,
    image_size: tuple[int, int] | None,
    root: pathlib.Path,
    rig: RigCalibration | None = None,
):
    """The detections `jaxpose.calibrate` recovers a rig from: the instants of some recordings (`aligned`:
    each recording's keypoints and confidence on one time axis, `jaxpose.rig.timeline.align`), each
    view's detection where it saw one person, one recording after the other; `known`: what each
    recording's detections.npz gives of its cameras (image size, intrinsics); `image_size`
    (--data.image-size) serves the cameras none gives one; with several people in view, each person a row
    (`people_rows`, through `rig` where one was recovered from them already).  A `RigDetections`."""
    from jaxpose.calibration import CalibrationError, RigDetections  # the calibrate extra

    # Per camera, by name from every recording's detections.npz: image size and, where given, intrinsics.
    given: dict[str, dict[str, np.ndarray]] = {}
    for cameras in known:
        for camera, fields in cameras.items():
            given.setdefault(camera, fields)
    sizes = []
    for camera in camera_order:
        if "image_size" in given.get(camera, {}):
            sizes.append(np.asarray(given[camera]["image_size"], np.int64))
        elif image_size is not None:
            sizes.append(np.asarray(image_size, np.int64))
        else:
            raise DataFormatError(
                root,
                "a calibration file (project or recording folder, or --data.calibration), or the image size to recover"
                " the rig (--data.image-size W H, or 'image_size' in detections.npz)",
                f"no calibration and no image size of camera {camera!r}",
            )
    intrinsics = [given.get(camera, {}) for camera in camera_order]
    given_K = all("K" in fields for fields in intrinsics)
    given_dist = given_K and all("dist" in fields for fields in intrinsics)
    K = np.stack([fields["K"] for fields in intrinsics]).astype(np.float64) if given_K else None
    dist = np.stack([fields["dist"] for fields in intrinsics]).astype(np.float64) if given_dist else None
    model = intrinsics[0].get("model", "opencv")
    lenses = None
    if dist is not None:  # the epipolar geometry that matches people holds for undistorted pixels
        C = len(camera_order)
        cameras = Cameras(K=K, R=np.broadcast_to(np.eye(3), (C, 3, 3)), t=np.zeros((C, 3)), dist=dist, distortion_model=model)
        lenses = RigCalibration(camera_names=tuple(camera_order), cameras=cameras, image_size=np.stack(sizes), source="given lenses", unit="mm")
    keypoints, confidence = [], []
    for name, (candidates, candidate_confidence) in zip(names, aligned):
        try:
            rows = people_rows(candidates, candidate_confidence, lenses, rig)
        except CalibrationError as error:  # the recording alone cannot relate its views: one line naming it
            raise ValueError(f"{root / name}: its rig cannot be recovered from the people in view: {error}") from None
        keypoints.append(rows[0])
        confidence.append(rows[1])
    return RigDetections(
        keypoints=np.concatenate(keypoints),
        confidence=np.concatenate(confidence),
        camera_names=tuple(camera_order),
        image_size=np.stack(sizes),
        skeleton=skeleton,
        K=K,
        dist=dist,
        distortion_model=model,
        source=f"{root} (recording {names[0]}" + (f" and {len(names) - 1} more)" if len(names) > 1 else ")"),
    )


def several_people(confidence: np.ndarray) -> bool:
    """Whether a recording (confidence [N, C, P, J]) shows several people: some view holds more than one
    detection in most instants with detections (an occasional passer-by or false detection is not several people)."""
    detected = (confidence > 0).any(-1).sum(-1)  # [N, C] detections per view
    return bool((detected > 1).any(-1).sum() > 0.5 * (detected > 0).any(-1).sum())


def people_rows(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    lenses: RigCalibration | None,
    rig: RigCalibration | None = None,
    *,
    match_px: float | None = None,
):
    """One recording's instants (keypoints [N, C, P, J, 2], confidence [N, C, P, J]) as the single-person
    rows a rig is recovered from, (keypoints f32[R, C, J, 2], confidence f32[R, C, J]):

    - with several people in view (`several_people`) and no rig yet: every person the views' epipolar geometry
      matches (`jaxpose.calibration.matching.match_people`, median epipolar distance <= `match_px`, default the
      calibration's RANSAC threshold; on pixels undistorted through `lenses` where the recordings give them with
      distortion), one row each;
    - with several people and a `rig` recovered from those: every person associated through it
      (`jaxpose.rig.association`, within twice the matching threshold: rows for a rig need to be clean, not
      complete), one row each: cleaner rows, seen by more views, for the rig recovered again;
    - else each instant's views that hold one detection (`one_person`).
    """
    from jaxpose.calibration import CalibrationConfig  # the calibrate extra
    from jaxpose.calibration.matching import match_people

    if not several_people(confidence):
        return one_person(keypoints, confidence)
    config = CalibrationConfig()
    match_px = config.ransac_threshold_px if match_px is None else match_px
    C = keypoints.shape[1]
    if rig is not None:
        pixels = np.stack([undistort_views(rig, name, keypoints[:, c]) for c, name in enumerate(rig.camera_names)], 1)
        P = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float32)
        found = association.associate(P, pixels, confidence, 2 * match_px)
        instant, slot = np.nonzero(found.present)
        index = found.detection[instant, slot]  # [R, C], -1 where the person has no detection in the view
        chosen = (instant[:, None], np.arange(C), np.maximum(index, 0))
        log.info("several people in view: %d people-instants associated through the first rig, %d detections fit no one",
                 len(instant), found.unmatched)  # fmt: skip
        return keypoints[chosen], np.where(index[..., None] >= 0, confidence[chosen], 0.0).astype(np.float32)
    pixels = None
    if lenses is not None:
        pixels = np.stack([undistort_views(lenses, name, keypoints[:, c]) for c, name in enumerate(lenses.camera_names)], 1)
    matched = match_people(
        keypoints, confidence, threshold_px=match_px, min_joints=config.min_joints, min_confidence=config.min_confidence,
        seed=config.seed, pixels=pixels,
    )  # fmt: skip
    log.info(
        "several people in view: %d people-instants matched across views without a rig (%d of %d instants), %d detections"
        " fit no one", len(matched.instant), len(np.unique(matched.instant)), len(keypoints), matched.unmatched,
    )  # fmt: skip
    return matched.keypoints, matched.confidence


def explains_better(again, first, detections) -> bool:
    """Whether the rig recovered again from everyone associated through the first (`again`, a
    `jaxpose.calibration.Calibration`) explains those rows (`detections`) at least as well as the `first` does:
    the worst camera's median re-projection error (`jaxpose.calibration.sessions.rig_fit_px`).  A recovery
    started afresh can fall into a wrong valley (on Campus with the rows associated at 15 px, 1 seed of 3: 11 px
    where the first rig gave 2); the first rig is kept then, and the log says so."""
    from jaxpose.calibration.sessions import rig_fit_px

    fit_again, fit_first = (float(np.nanmax(rig_fit_px(c.cameras, detections))) for c in (again, first))
    if fit_again <= fit_first:
        return True
    log.warning("the rig recovered again from everyone re-projects them at %.2f px (worst camera's median), the first"
                " rig at %.2f px: the first is kept", fit_again, fit_first)  # fmt: skip
    return False


def recover_rig(detections, *, max_frames: int, height_mm: float | None = None):
    """`jaxpose.calibrate` on `detections` (`rig_detections`), on at most `max_frames` instants, the rig
    then moved into the person's upright metric world.  Returns (the rig as a `RigCalibration`, the
    `jaxpose.calibration.Calibration`)."""
    from jaxpose.calibration import CalibrationConfig, calibrate  # the calibrate extra

    calibration = calibrate(detections, CalibrationConfig(max_frames=max_frames))
    calibration = _upright(calibration, detections, detections.skeleton, height_mm)
    rig = RigCalibration(
        camera_names=tuple(detections.camera_names),
        cameras=calibration.cameras.replace(**{name: np.asarray(getattr(calibration.cameras, name), np.float64) for name in ("K", "R", "t")}),
        image_size=detections.image_size,
        source="recovered from the recordings by jaxpose.calibrate",
        unit="mm",
    )
    return rig, calibration


def _upright(calibration, detections, skeleton: Skeleton, height_mm: float | None):
    """`calibration` with its cameras moved into the upright metric world of the person
    (`jaxpose.calibration.world`: +Y up, the floor at Y = 0, mm; scaled by `height_mm` where given), so that
    the project's motion stands on the floor; where the person does not show it (a `ValueError` of
    `world_frame`), view 0's frame is kept and the log says why."""
    from jaxpose.calibration.world import WORLD_FRAME, to_world, world_frame

    names = calibration.camera_names
    rig = RigCalibration(camera_names=names, cameras=calibration.cameras, image_size=detections.image_size, source="recovered", unit="mm")
    keypoints = np.stack([undistort_views(rig, name, detections.keypoints[:, c]) for c, name in enumerate(names)], 1)
    P = np.asarray(projection_matrices(calibration.cameras.without_distortion()), np.float32)
    points = triangulate_rows(P, keypoints, detections.confidence, method="normal")
    valid = (detections.confidence > 0).sum(1) >= 2
    try:
        world = world_frame(points, valid, skeleton, height_mm=height_mm)
    except ValueError as error:
        log.warning("the recovered rig stays in view 0's camera frame (not upright): %s", error)
        return calibration
    log.info(
        "recovered rig moved into the %s (up from the %s, scale from the %s, x%.3f)", WORLD_FRAME, world.up_source, world.scale_source, world.scale
    )
    return to_world(world, calibration)


def ground_truth_into_recovered_world(target: np.ndarray, keypoints, confidence, rig: RigCalibration) -> np.ndarray:
    """Ground truth [N, J, 3] in the motion capture's world, turned into the recovered rig's world.

    A recovered rig has its own world frame (`jaxpose.calibrate`), so the ground truth is moved there
    by the similarity that maps it best onto the triangulated detections (least squares, then again
    without the worst 10% of joints); only the rotation and translation are applied, so it keeps
    its true size: MPJPE then includes the recovered rig's scale error, P-MPJPE does not.
    """
    P = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float32)
    points = triangulate_rows(P, keypoints, confidence, method="normal")
    usable = np.isfinite(target).all(-1) & ((confidence > 0).sum(1) >= 2)
    if usable.sum() < MIN_ALIGNMENT_POINTS:
        raise DataFormatError(
            f"{GROUND_TRUTH_NPZ}, array 'frames'",
            f"at least {MIN_ALIGNMENT_POINTS} joints at frames seen by two or more cameras, to bring the ground truth into"
            " the recovered rig's frame",
            f"{int(usable.sum())}: do its frame numbers match the detections'?",
        )
    source, destination = target[usable].astype(np.float64), points[usable].astype(np.float64)
    s, R, t = similarity(source, destination)
    residual = np.linalg.norm(s * source @ R.T + t - destination, axis=-1)
    keep = residual <= np.quantile(residual, 0.9)
    s, R, t = similarity(source[keep], destination[keep])
    return (target @ R.T + t / s).astype(np.float32)


SESSION_FRAMES = 150
"""Instants of each recording its own rig is recovered from to find the sessions (the synthetic study
of docs/calibration.md, "Sessions", found every session with 150): a rig that tells one session from
another need not be the session's best, which is recovered from all its recordings afterwards."""
SESSION_ROUNDS = 2
"""Robust rounds of those rigs (`CalibrationConfig.robust_rounds`; a session's own rig gets the default 4),
for the same reason: the first round re-weights the detector's outliers and swaps away, the second
settles the weights, and a moved camera misses by tens of pixels, not the 3 px margin (`FIT_MARGIN_PX`);
the Human3.6M development split as two sessions finds the same sessions (docs/performance.md)."""
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


def parse_sessions(entries: Sequence[str], names: Sequence[str], root: pathlib.Path) -> dict[str, str]:
    """--data.sessions entries SESSION=REC1,REC2 as {recording: session} over the recordings `names`
    loaded; every recording must be named exactly once (names of the project's recordings not loaded, e.g.
    left out by --data.recordings, are passed over; a name the project `root` has no recording of is refused,
    with the closest one: a typo would otherwise drop its session without a word)."""
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
    if unknown:
        existing = [folder.name for folder in recording_folders(root)]
        for member in unknown:
            if member not in existing:
                (closest,) = difflib.get_close_matches(member, existing, n=1, cutoff=0.0)
                raise ValueError(
                    f"--data.sessions {labels[member]}={member}: {root} has no recording {member!r}; the closest is {closest!r}"
                    f" (its recordings: {', '.join(existing)})"
                )
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
    grouping = find_sessions(spread, CalibrationConfig(max_frames=SESSION_FRAMES, robust_rounds=SESSION_ROUNDS), until_explained=True)
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
    from jaxpose.calibration import CalibrationError  # the calibrate extra

    names = list(names)
    detections = {
        name: rig_detections([name], [cameras], [part], camera_order, skeleton, image_size=image_size, root=root)
        for name, cameras, part in zip(names, known, aligned)
    }
    labels = parse_sessions(sessions, names, root) if sessions else None
    grouping = group_recordings(detections, labels, find, root)
    if len(grouping.sessions) > 1 or grouping.method != "one":
        log.info("sessions (%s): %s", grouping.method, "; ".join(f"{s.name}: {', '.join(s.recordings)}" for s in grouping.sessions))
    result, rigs = [], {}
    for session in grouping.sessions:
        members = [names.index(name) for name in session.recordings]
        pooled = rig_detections(
            [names[i] for i in members], [known[i] for i in members], [aligned[i] for i in members], camera_order, skeleton, image_size=image_size, root=root
        )
        try:
            rig, calibration = recover_rig(pooled, max_frames=max_frames, height_mm=height_mm)
            if any(several_people(aligned[i][1]) for i in members):
                # Several people: recovered again from everyone associated through that rig (the matching without a
                # rig lets some wrong pairings in; the association checks each person's triangulation in every view).
                pooled = rig_detections([names[i] for i in members], [known[i] for i in members], [aligned[i] for i in members],
                                        camera_order, skeleton, image_size=image_size, root=root, rig=rig)  # fmt: skip
                again = recover_rig(pooled, max_frames=max_frames, height_mm=height_mm)
                if explains_better(again[1], calibration, pooled):
                    rig, calibration = again
        except CalibrationError as error:
            raise ValueError(_unrecoverable(session.name, session.recordings, detections, grouping.method, error)) from None
        reprojection = float(np.max(calibration.reprojection_median_px))
        result.append(RecoveredSession(session.name, session.recordings, reprojection, grouping.method, calibration))
        rigs.update(dict.fromkeys(session.recordings, rig))
        log.info("session %s: rig recovered from %d recordings, worst camera's median re-projection %.2f px", session.name, len(members), reprojection)
    return tuple(result), rigs


def _unrecoverable(name: str, recordings: Sequence[str], detections: Mapping[str, object], method: str, error: Exception) -> str:
    """Why the session's rig could not be recovered, in one line: the session and its recordings, the
    calibration's reason, the recordings lacking a camera's detections altogether (the usual cause: a camera
    folder missing), and what to do."""
    lacking = []
    for recording in recordings:
        rows = detections[recording]
        absent = [camera for c, camera in enumerate(rows.camera_names) if not (rows.confidence[:, c] > 0).any()]
        lacking += [f"recording {recording} has no detections of camera {camera}" for camera in absent]
    how = "as --data.sessions gives it" if method == "labels" else "as found from the data"
    way_out = "leave such a recording out (--data.recordings) or give it a calibration file"
    return (
        f"session {name} (recordings {', '.join(recordings)}, {how}): its rig cannot be recovered: {error}"
        + "".join(f"; {line}" for line in lacking)
        + (f"; give every camera's detections, {way_out}" if lacking else f"; {way_out}")
    )


def _spread(detections, count: int):
    """`detections` (a `RigDetections`) on at most `count` instants spread evenly over it."""
    frames = len(detections.keypoints)
    if frames <= count:
        return detections
    rows = np.linspace(0, frames - 1, count).round().astype(int)
    return dataclasses.replace(detections, keypoints=detections.keypoints[rows], confidence=detections.confidence[rows])
