"""A recording's cameras on one time axis.

Camera c's frame f shows instant f + offset[c]; the offsets are given (--data.frame-offsets, parsed
here) or estimated from the detections (`estimate_recording_offsets`, below).  Instants seen by no camera
are absent, and a camera without a frame at an instant has confidence 0 there.

Estimating the offsets of cameras that were not started together.  Convention: a camera's offset o means
that its frame f shows the instant f + o of the recording (the frame numbering of the cameras with offset
0).  Two cameras c and r then show the same instant in their frames f and f + (o_c - o_r).

Only joints that move tell offsets apart (in a reaching motion the legs stand still), so every
score below is over the moving half of a camera's detections (by image speed), a mean of pixel
distances each clipped at `CLIP_PX`, so that gross detection errors weigh no more than a
moderate miss.  A person standing still makes every offset alike: the estimate then says it is
unreliable.

With a calibration (`estimate_offsets` given projection matrices): each camera in turn is left
out, the person is triangulated from the other cameras, and the camera's detections at frame
f - d are compared with that triangulation's projection at instant f, for every d in
[-max_offset, max_offset].  The camera that gains most by moving to its best d (at least
`MIN_GAIN`) moves, and all are measured again: the other cameras' curves were taken against a
triangulation that the out-of-sync camera spoiled, so only the clearest move is trusted per round.  Both image
directions count, where two views alone would only see motion across the epipolar lines (a
person walking along a pair's baseline shows none).

Without one (or with two cameras only): for every pair of cameras and offset d, the joints of
camera c's frame f and camera r's frame f + d are correspondences when d is right, scored by their
distance to the epipolar lines of the calibration's fundamental matrix, or without a calibration
of one fitted robustly to them (OpenCV's MAGSAC++; a wrong d fits worse too).  Each pair's best d, weighted by how clearly it wins, gives the offsets by least squares.

Either way the offsets are then shifted so that most cameras have offset 0.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.camera import projection_matrices
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.rig.geometry import triangulate_rows, undistort_views
from jaxpose.rig.recordings import Recording, Views, one_person

MIN_CORRESPONDENCES = 50
CLIP_PX = 20.0
RELIABLE_MARGIN = 0.1  # an offset is trusted where it fits 10% better than any two or more frames away
MIN_GAIN = 0.05  # a camera's offset moves only where that fits its detections 5% better
# A camera with under 0.6 or over 1/0.6 times the others' median frame count, where the offsets cannot be
# told apart, most likely runs at another frame rate (25 beside 50 fps is 0.5): no integer offset aligns it.
RATE_RATIO = 0.6


@dataclasses.dataclass(frozen=True)
class SyncEstimate:
    """Estimated offsets and the evidence for them."""

    offsets: np.ndarray
    """int[C] frames: camera c's frame f shows instant f + offsets[c]."""
    scores: dict[str, np.ndarray]
    """Per camera ("2": camera 2 against the others' triangulation) or per pair ("0-2": epipolar) ->
    f[2 * max_offset + 1] the mean clipped distance (px) at each offset -max..max."""
    reliable: bool
    """Whether every curve's best offset clearly beats those two or more frames away (by `RELIABLE_MARGIN`):
    a person who moves enough for the frames to be told apart."""
    doubt: str = ""
    """Why the estimate is not reliable, in words ("" where it is)."""


@dataclasses.dataclass(frozen=True)
class _Track:
    """One camera's detections of the person: its own frame numbers int[F], keypoints f[F, J, 2]
    (undistorted pixels), and bool[F, J] which of them are detected (`valid`) and move (`moving`)."""

    frames: np.ndarray
    keypoints: np.ndarray
    valid: np.ndarray
    moving: np.ndarray


def fundamental_from_projections(P_a: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """F [3, 3] with x_b^T F x_a = 0 for the projections of one point by P_a and P_b [3, 4]."""
    centre_a = np.linalg.svd(P_a)[2][-1]  # P_a's null space: camera a's centre
    e = P_b @ centre_a  # the epipole in image b
    cross = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
    return cross @ P_b @ np.linalg.pinv(P_a)


def epipolar_distances(F: np.ndarray, points_a: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance (px) of correspondences [M, 2] (mean of both images)."""
    a = np.concatenate([points_a, np.ones((len(points_a), 1))], 1)
    b = np.concatenate([points_b, np.ones((len(points_b), 1))], 1)
    lines_b = a @ F.T  # epipolar lines in image b
    lines_a = b @ F  # in image a
    residual = np.abs(np.sum(b * lines_b, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        distance_b = residual / np.linalg.norm(lines_b[:, :2], axis=1)
        distance_a = residual / np.linalg.norm(lines_a[:, :2], axis=1)
    return 0.5 * (distance_a + distance_b)


def _fitted_fundamental(points_a: np.ndarray, points_b: np.ndarray, seed: int) -> np.ndarray | None:
    import cv2  # the calibrate extra; only needed without a calibration

    cv2.setRNGSeed(seed)
    F, _ = cv2.findFundamentalMat(points_a, points_b, cv2.USAC_MAGSAC, 3.0, 0.999, 2000)
    return None if F is None or F.shape != (3, 3) else F


def _image_speed(frames: np.ndarray, keypoints: np.ndarray, valid: np.ndarray, reach: int = 3) -> np.ndarray:
    """f[F, J] pixels per frame of each detection: the median over k = 1..reach of its displacement
    between frames f - k and f + k over 2k (a gross error in one neighbouring frame does not make a
    joint look fast); 0 where no such pair was detected."""
    F = len(frames)
    estimates = np.full((reach, *valid.shape), np.nan)
    for k in range(1, reach + 1):
        if F <= 2 * k:
            break
        consecutive = (frames[2 * k :] - frames[: -2 * k]) == 2 * k
        seen = valid[2 * k :] & valid[: -2 * k] & consecutive[:, None]
        moved = np.linalg.norm(keypoints[2 * k :] - keypoints[: -2 * k], axis=-1) / (2 * k)
        estimates[k - 1, k : F - k] = np.where(seen, moved, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: no neighbours detected
        return np.nan_to_num(np.nanmedian(estimates, axis=0), nan=0.0)


def _correspondences(a: _Track, b: _Track, shift: int, limit: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Moving joints of camera a's frame f seen in camera b's frame f + shift: ([M, 2], [M, 2])."""
    _, index_a, index_b = np.intersect1d(a.frames + shift, b.frames, assume_unique=True, return_indices=True)
    both = a.moving[index_a] & b.valid[index_b]  # [n, J]
    frame, joint = np.nonzero(both)
    if len(frame) > limit:
        keep = np.sort(rng.choice(len(frame), limit, replace=False))
        frame, joint = frame[keep], joint[keep]
    return a.keypoints[index_a[frame], joint].astype(np.float64), b.keypoints[index_b[frame], joint].astype(np.float64)


def _track(frames: np.ndarray, keypoints: np.ndarray, valid: np.ndarray) -> _Track:
    """A camera's track; its moving detections are those at least as fast in the image as its median one."""
    speed = _image_speed(frames, keypoints, valid)
    threshold = np.median(speed[speed > 0]) if (speed > 0).any() else np.inf
    return _Track(frames=frames, keypoints=keypoints, valid=valid, moving=valid & (speed >= threshold))


def _reliability(scores: np.ndarray) -> float:
    """How clearly a curve's minimum wins: the best distance two or more frames away from it over the
    minimum, less 1 (0 for a flat curve)."""
    if not np.isfinite(scores).any():
        return 0.0
    best = int(np.argmin(scores))
    away = np.abs(np.arange(len(scores)) - best) >= 2
    if not np.isfinite(scores[away]).any():
        return 0.0
    return max(float(np.min(scores[away]) / max(scores[best], 1e-6)) - 1.0, 0.0)


def estimate_offsets(
    frames: list[np.ndarray],
    keypoints: list[np.ndarray],
    confidence: list[np.ndarray],
    projections: np.ndarray | None,
    max_offset: int = 10,
    min_confidence: float = 0.3,
    max_instants: int = 3000,
    seed: int = 0,
    camera_names: list[str] | None = None,
) -> SyncEstimate:
    """Offsets of C cameras from one person's detections (see the module docstring).

    Per camera c: frames int[F_c] (its own frame numbers), keypoints f[F_c, J, 2] undistorted pixels
    (one person per frame), confidence f[F_c, J].  projections: f[C, 3, 4] of a calibration, or None
    to fit a fundamental matrix per pair and offset.  At most `max_instants` instants (evenly spread)
    are scored.  `camera_names` name the cameras in `SyncEstimate.doubt`.
    """
    tracks = [
        _track(f, k, (c > min_confidence) & np.isfinite(k).all(-1)) for f, k, c in zip(frames, keypoints, confidence)
    ]  # fmt: skip
    shifts = np.arange(-max_offset, max_offset + 1)
    if projections is not None and len(frames) >= 3:
        estimate = _offsets_by_triangulation(tracks, projections, shifts, max_instants)
    else:  # two cameras (nothing to triangulate the left-out one from) or no calibration: epipolar lines
        estimate = _offsets_by_epipolar_fit(tracks, shifts, 20000, seed, projections)
    if estimate.reliable:
        return estimate
    names = camera_names or [str(c) for c in range(len(frames))]
    return dataclasses.replace(estimate, doubt=_doubt([len(f) for f in frames], names))


def _doubt(counts: list[int], names: list[str]) -> str:
    """Why offsets could not be told apart: a camera whose frame count is far from the others' (another
    frame rate), else a person who hardly moves between frames."""
    for c, count in enumerate(counts):
        others = float(np.median([n for i, n in enumerate(counts) if i != c])) if len(counts) > 1 else count
        if others > 0 and not RATE_RATIO <= count / others <= 1 / RATE_RATIO:
            return (
                f"camera {names[c]} has {count} frames against the others' {others:.0f}: another frame rate? Every camera"
                " must run at one rate (resample it, or leave it out)"
            )
    return "the person hardly moves between frames"


def _offsets_by_triangulation(tracks: list[_Track], projections: np.ndarray, shifts: np.ndarray, max_instants: int) -> SyncEstimate:
    C = len(tracks)
    offsets = np.zeros(C, np.int64)
    for _ in range(C + 1):
        scores = {str(c): _camera_curve(c, tracks, projections, offsets, shifts, max_instants) for c in range(C)}
        # Move only the camera that gains most, then look again: the others' curves were measured
        # against a triangulation that the out-of-sync camera still spoiled.
        gains = np.array([_gain(scores[str(c)], shifts, offsets[c]) for c in range(C)])
        worst = int(np.argmax(gains))
        if gains[worst] <= MIN_GAIN:
            break
        offsets[worst] = shifts[int(np.argmin(scores[str(worst)]))]
    reliable = all(_reliability(curve) > RELIABLE_MARGIN for curve in scores.values())
    return SyncEstimate(offsets=_most_at_zero(offsets), scores=scores, reliable=reliable)


def _gain(curve: np.ndarray, shifts: np.ndarray, current: int) -> float:
    """How much a camera's curve improves from its current offset to its best, relative (0 if it cannot)."""
    if not np.isfinite(curve).any():
        return 0.0
    at_current = curve[np.flatnonzero(shifts == current)[0]] if current in shifts else np.inf
    return float(at_current / np.min(curve) - 1.0) if np.isfinite(at_current) else float(np.inf)


def _camera_curve(
    c: int, tracks: list[_Track], projections: np.ndarray, offsets: np.ndarray, shifts: np.ndarray, max_instants: int
) -> np.ndarray:
    """Camera c's mean clipped distance (px) to the other cameras' triangulation at each offset in `shifts`."""
    C, J = len(tracks), tracks[0].keypoints.shape[1]
    others = [v for v in range(C) if v != c]
    instants = np.unique(np.concatenate([tracks[v].frames + offsets[v] for v in others]))
    instants = instants[np.linspace(0, len(instants) - 1, min(max_instants, len(instants))).round().astype(int)]
    points = np.zeros((len(instants), len(others), J, 2))
    weights = np.zeros((len(instants), len(others), J))
    for slot, v in enumerate(others):
        _, rows, own = np.intersect1d(instants, tracks[v].frames + offsets[v], assume_unique=True, return_indices=True)
        points[rows, slot], weights[rows, slot] = tracks[v].keypoints[own], tracks[v].valid[own]
    seen = weights.sum(1) >= 2  # [n, J] triangulable without camera c
    X = triangulate_rows(projections[others], points, weights * seen[:, None], method="svd")
    projected = np.concatenate([X, np.ones_like(X[..., :1])], -1) @ projections[c].T  # [n, J, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        pixels = projected[..., :2] / projected[..., 2:]
    curve = np.full(len(shifts), np.inf)
    for i, shift in enumerate(shifts):
        # With offset `shift`, camera c's frame f shows instant f + shift.
        _, rows, own = np.intersect1d(instants, tracks[c].frames + shift, assume_unique=True, return_indices=True)
        use = tracks[c].moving[own] & seen[rows] & (projected[rows, :, 2] > 0)
        if use.sum() >= MIN_CORRESPONDENCES:
            distance = np.linalg.norm(pixels[rows] - tracks[c].keypoints[own], axis=-1)
            curve[i] = np.minimum(distance[use], CLIP_PX).mean()
    return curve


def _offsets_by_epipolar_fit(
    tracks: list[_Track], shifts: np.ndarray, max_correspondences: int, seed: int, projections: np.ndarray | None
) -> SyncEstimate:
    C = len(tracks)
    rng = np.random.default_rng(seed)
    scores, pair_offsets, weights = {}, {}, {}
    for a, b in itertools.combinations(range(C), 2):
        curve = np.full(len(shifts), np.inf)
        for i, shift in enumerate(shifts):
            points_a, points_b = _correspondences(tracks[a], tracks[b], int(shift), max_correspondences, rng)
            if len(points_a) < MIN_CORRESPONDENCES:
                continue
            F = _fitted_fundamental(points_a, points_b, seed) if projections is None else fundamental_from_projections(projections[a], projections[b])
            if F is not None:
                curve[i] = np.nanmean(np.minimum(epipolar_distances(F, points_a, points_b), CLIP_PX))
        scores[f"{a}-{b}"] = curve
        if np.isfinite(curve).any():
            # o_a - o_b: camera a's frame f shows what camera b's frame f + shift shows.
            pair_offsets[a, b] = int(shifts[int(np.argmin(curve))])
            weights[a, b] = _reliability(curve)
    reliable = bool(pair_offsets) and all(weight > RELIABLE_MARGIN for weight in weights.values())
    return SyncEstimate(offsets=_solve_offsets(C, pair_offsets, weights), scores=scores, reliable=reliable)


def _solve_offsets(C: int, pair_offsets: dict[tuple[int, int], int], weights: dict[tuple[int, int], float]) -> np.ndarray:
    """Integer offsets o with o_a - o_b ~ pair_offsets[a, b] (weighted least squares), most cameras at 0."""
    rows, targets = [], []
    for (a, b), offset in pair_offsets.items():
        w = np.sqrt(max(weights.get((a, b), 0.0), 1e-3))
        row = np.zeros(C)
        row[a], row[b] = w, -w
        rows.append(row)
        targets.append(w * offset)
    if not rows:
        return np.zeros(C, np.int64)
    # Offsets are relative: fix their sum with one more equation, then move the most common to 0.
    system = np.vstack([*rows, np.ones(C)])
    solution = np.linalg.lstsq(system, np.array([*targets, 0.0]), rcond=None)[0]
    # Relative to camera 0 before rounding: a sum fixed at 0 splits an odd offset into +-x.5.
    return _most_at_zero(np.round(solution - solution[0]).astype(np.int64))


def _most_at_zero(offsets: np.ndarray) -> np.ndarray:
    """Offsets moved so that the most common value is 0; of equally common values, the one of the
    earliest camera (so the numbering is the first cameras', e.g. that of a ground truth)."""
    values, counts = np.unique(offsets, return_counts=True)
    common = set(values[counts == counts.max()].tolist())
    reference = next(offset for offset in offsets.tolist() if offset in common)
    return offsets - reference


def parse_frame_offsets(values: Sequence[str], recordings: Sequence[Recording]) -> dict[tuple[str, str], int]:
    """--data.frame-offsets as {(recording, camera): offset}; CAMERA=N applies to every recording that has the camera."""
    offsets = {}
    for value in values:
        match = re.fullmatch(r"(?:(?P<recording>[^/=]+)/)?(?P<camera>[^/=]+)=(?P<offset>[+-]?\d+)", value.strip())
        if match is None:
            raise ValueError(f"--data.frame-offsets {value!r}: expected CAMERA=N or RECORDING/CAMERA=N (N an integer)")
        targets = [r for r in recordings if match["recording"] in (None, r.name)]
        if not targets:
            raise ValueError(f"--data.frame-offsets {value!r}: no recording {match['recording']!r} (have {[r.name for r in recordings]})")
        having = [r for r in targets if match["camera"] in r.cameras]
        if not having:
            cameras = sorted(set().union(*(r.cameras for r in targets)))
            raise ValueError(f"--data.frame-offsets {value!r}: no camera {match['camera']!r} in {[r.name for r in targets]} (cameras {cameras})")
        for recording in having:
            offsets[recording.name, match["camera"]] = int(match["offset"])
    return offsets


def estimate_recording_offsets(
    recording: Recording, calibration: RigCalibration | None, views: Views, camera_order: Sequence[str], max_offset: int
) -> SyncEstimate:
    """`estimate_offsets` on the frames where each camera sees one person (offsets up
    to `max_offset` frames), with the recording's `calibration` where it has one."""
    frames, keypoints, confidence = [], [], []
    for camera in camera_order:
        camera_frames, camera_keypoints, camera_confidence = views[camera]
        single_keypoints, single_confidence = one_person(camera_keypoints, camera_confidence)
        rows = np.flatnonzero((single_confidence > 0).any(-1))
        frames.append(camera_frames[rows])
        keypoints.append(undistort_views(calibration, camera, single_keypoints[rows]))
        confidence.append(single_confidence[rows])
    projections = None
    if calibration is not None:
        rig = calibration.select(camera_order, f"cameras of recording {recording.name}")
        projections = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float64)
    return estimate_offsets(frames, keypoints, confidence, projections, max_offset, camera_names=list(camera_order))


def instants_of(views: Views, offsets: Mapping[str, int]) -> np.ndarray:
    """int[N] the recording's instants: every camera's frames moved by its offset, sorted, unique."""
    return np.unique(np.concatenate([frames + offsets.get(camera, 0) for camera, (frames, _, _) in views.items()]))


def lone_cameras(views: Views, offsets: Mapping[str, int]) -> list[str]:
    """The cameras none of whose frames shows an instant another camera shows (with their offsets): their
    detections can be neither triangulated nor paired; usually a frame offset that is wrong."""
    shown = {camera: np.unique(frames + offsets.get(camera, 0)) for camera, (frames, _, _) in views.items()}
    lone = []
    for camera, instants in shown.items():
        others = [other for name, other in shown.items() if name != camera]
        if others and len(instants) and not np.isin(instants, np.concatenate(others)).any():
            lone.append(camera)
    return lone


def align(views: Views, camera_order: Sequence[str], offsets: Mapping[str, int], instants: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cameras on one time axis at `instants` (sorted, some or all of `instants_of`): keypoints
    [n, C, P, J, 2], confidence [n, C, P, J]."""
    people = max(views[c][1].shape[1] for c in views)
    J = next(iter(views.values()))[1].shape[2]
    keypoints = np.zeros((len(instants), len(camera_order), people, J, 2), np.float32)
    confidence = np.zeros((len(instants), len(camera_order), people, J), np.float32)
    for index, camera in enumerate(camera_order):
        if camera not in views:
            continue  # a camera this recording lacks: confidence 0 throughout
        frames, camera_keypoints, camera_confidence = views[camera]
        shown = frames + offsets.get(camera, 0)
        rows = np.minimum(np.searchsorted(instants, shown), len(instants) - 1)
        kept = np.flatnonzero(instants[rows] == shown)
        width = camera_keypoints.shape[1]
        keypoints[rows[kept], index, :width] = camera_keypoints[kept]
        confidence[rows[kept], index, :width] = camera_confidence[kept]
    return keypoints, confidence
