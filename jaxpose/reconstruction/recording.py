"""A rig project's recordings as 3D motion: every instant, each view lifted, all fused, gaps bridged.

    from jaxpose.serving import inference
    from jaxpose.reconstruction import recording
    project = recording.load_every_instant(RigProjectConfig(root=PROJECT), RunDirectory.of(RUN))
    lifter = inference.load(RUN)
    for inputs in recording.recording_inputs(project.instants):
        motion, lifted = recording.lift_and_reconstruct(lifter, inputs)

The project is loaded as `experiments.rig` loads it (`jaxpose.rig.project`), with every recording in
one part at every instant: no stride, nothing held out.  Its world frame is the calibration's; a
project without one was trained on the rig recovered in the run (`experiments.rig` writes it to
RUN/recovered_cameras.json), and that rig is read, never recovered again: another recovery would give
another world frame.

Per recording, on its whole frame axis (first to last instant; an instant no camera saw has every
confidence 0): each camera's detections lifted by the trained lifter (`jaxpose.serving.inference.Lifter3D`,
root-relative in the camera's axes; its chunks of fixed sizes keep the compilations bounded whatever
the recordings), fused with the detections (`jaxpose.reconstruction.fusion.fuse`, world mm), the views
whose root was occluded lifted about the fused root and fused again (`lift_and_reconstruct`), then the
instants nothing fixes bridged up to `max_gap` frames and the rest split off
(`jaxpose.formats.gaps.fill_gaps`).
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
from collections.abc import Iterator

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.serving.inference import Lifter3D
from jaxpose.reconstruction.fusion import MIN_DEPTH_MM, Fusion, FusionConfig, Provenance, fuse
from jaxpose.formats.gaps import DEFAULT_MAX_GAP, complete_segments, fill_gaps
from jaxpose.reconstruction.trajectory import TrajectoryConfig, limb_lengths, solve_trajectory
from jaxpose.rig.cameras import in_view_order
from jaxpose.rig.project import prepared_project
from jaxpose.rig.cache import PreparedProject
from jaxpose.rig.config import SPLIT_FIELDS, RigProjectConfig
from jaxpose.rig.split import ProjectInstants, every_instant
from jaxpose.training.run_directory import RECOVERED_SESSIONS_DIR, RunDirectory, read_record
from jaxpose.rig.recordings import FoundProject, find_project
from jaxpose.skeleton import ROOT, Skeleton

log = logging.getLogger(__name__)


def load_every_instant(data: RigProjectConfig, run: RunDirectory, progress: bool = True, found: FoundProject | None = None) -> ProjectInstants:
    """Every instant of every recording (of --data.recordings) of the project; `found`: its files as found
    already (`jaxpose.rig.recordings.find_project`), else found now.

    The calibration: --data.calibration where given; else the run's recovered rig where it was trained on one
    (the asset its record lists, `RunRecord.recovered_rigs`: RUN/recovered_cameras.json; read from the prepared project the run was trained on where the cache still
    holds it); else the project's own.  A project with none of these is refused, as are the split flags
    (`SPLIT_FIELDS`) set to anything but their defaults.  The prepared instants are those training read
    (`jaxpose.rig.project.prepared_project`): the same cache, whatever the run's split."""
    defaults = RigProjectConfig()
    changed = [field for field in SPLIT_FIELDS if getattr(data, field) != getattr(defaults, field)]
    if changed:
        flags = ", ".join("--data." + field.replace("_", "-") for field in changed)
        raise ValueError(f"{flags}: a reconstruction takes every instant of every recording; leave the split flags out")
    found = found or find_project(data.root, data.recordings, data.calibration)
    rigs = run.recovered_rigs(read_record(run))  # the run's assets, as its record lists them
    if data.calibration is None and len(rigs) == 1:
        (recovered,) = rigs.values()
        # the run's own, where the cache holds it
        prepared = _whole_project(data, found, progress) or prepared_project(data, found, progress, cached_only=True)
        if prepared is not None and _holds_rig(prepared, recovered):
            log.info("the run was trained on the rig recovered from the recordings, %s: the prepared project it was trained on", recovered)
            return every_instant(prepared, data.recordings)
        log.info("the run was trained on the rig recovered from the recordings: its world frame, %s", recovered)
        data = dataclasses.replace(data, calibration=recovered)
        found = dataclasses.replace(found, calibration=recovered)
    elif not found.calibrated:
        if rigs:
            sessions = run.path / RECOVERED_SESSIONS_DIR
            raise ValueError(
                f"{data.root}: no calibration file, and the run {run.path} was trained on one recovered rig per session"
                f" ({sessions}): pass the recordings' session's as --data.calibration {sessions}/SESSION.toml"
            )
        raise ValueError(
            f"{data.root}: no calibration file, and the run {run.path} has no {run.recovered_cameras.name} (it was trained on"
            " a calibrated project): pass --data.calibration; a rig recovered again would have another world frame"
        )
    prepared = _whole_project(data, found, progress) or prepared_project(data, found, progress)
    return every_instant(prepared, data.recordings)


def _whole_project(data: RigProjectConfig, found: FoundProject, progress: bool) -> PreparedProject | None:
    """With --data.recordings, the whole project where the cache holds it (as training prepared it; each
    recording is prepared on its own, so their rows, which `every_instant` takes, are the same); else None."""
    if not data.recordings:
        return None
    try:
        whole = find_project(data.root, (), found.calibration)
        prepared = prepared_project(dataclasses.replace(data, recordings=()), whole, progress, cached_only=True)
    except ValueError:  # a recording left out may be one that cannot be read: then only the named ones are
        return None
    if prepared is not None:
        log.info("--data.recordings: their instants taken from the whole project's prepared folder")
    return prepared


def _holds_rig(prepared: PreparedProject, recovered: pathlib.Path) -> bool:
    """Whether the prepared project's one rig is the run's recovered rig (the file `recovered`): the same
    cameras to float precision (another recovery gives another world frame, far from it)."""
    rigs = prepared.meta.rigs
    if len(prepared.sessions) != 1 or len(rigs["K"]) != 1:
        return False
    rig = read_rig_calibration(recovered)
    if set(rig.camera_names) != set(prepared.meta.camera_names):
        return False
    cameras = in_view_order(rig, prepared.meta.camera_names).cameras
    return all(np.allclose(np.asarray(getattr(cameras, field), np.float64), np.asarray(rigs[field][0]), rtol=1e-5, atol=1e-3)
               for field in ("K", "R", "t"))  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RecordingInput:
    """One person's detections in one recording, on their whole frame axis (F frames, C views, J joints).

    name:       what the files are named: the recording's name where it has one person, else
                ``<recording>.person<k>`` (`jaxpose.rig.split.person_names`).
    frames:     i64[F] the instants, consecutive, the person's first to last (the rig project's frame numbers).
    cameras:    the recording's pinhole rig, fields [C, ...] (x_cam = R x_world + t, mm).
    keypoints:  f32[F, C, J, 2] undistorted pixels; 0 where not seen.
    confidence: f32[F, C, J]; 0 where not seen (and at every instant the project lacks).
    target3d:   f32[F, J, 3] world mm, the ground truth (NaN where none), or None.
    recording:  the recording's name.
    person:     k, the person (1, 2, ... in order of first appearance in the recording).
    """

    name: str
    frames: np.ndarray
    cameras: Cameras
    keypoints: np.ndarray
    confidence: np.ndarray
    target3d: np.ndarray | None
    recording: str = ""
    person: int = 1

    @property
    def seen(self) -> np.ndarray:
        """bool[F]: some camera sees the person (detects a joint of it)."""
        return (self.confidence > 0).any((1, 2))


def recording_inputs(dataset: MultiViewDataset) -> Iterator[RecordingInput]:
    """The people of a data set's recordings (labels "recording", "sequence", "person" and "frame", e.g.
    `load_every_instant`'s instants), each undistorted and on its whole frame axis, in the order they appear."""
    dataset = dataset.undistorted()
    labels = dataset.samples.labels
    names = labels["sequence"]
    _, first = np.unique(names, return_index=True)
    for name in names[np.sort(first)]:
        rows = np.flatnonzero(names == name)
        rows = rows[np.argsort(labels["frame"][rows], kind="stable")]
        rigs = np.unique(dataset.samples.rig_index[rows])
        if len(rigs) != 1:
            raise ValueError(f"recording {name}: its instants have {len(rigs)} rigs; expected one")
        frame = labels["frame"][rows].astype(np.int64)
        index = frame - frame[0]
        F = int(index[-1]) + 1
        keypoints = np.zeros((F, *dataset.samples.keypoints2d.shape[1:]), np.float32)
        confidence = np.zeros((F, *dataset.samples.confidence.shape[1:]), np.float32)
        keypoints[index], confidence[index] = dataset.samples.keypoints2d[rows], dataset.samples.confidence[rows]
        target = None
        if dataset.samples.target3d is not None:
            target = np.full((F, *dataset.samples.target3d.shape[1:]), np.nan, np.float32)
            target[index] = dataset.samples.target3d[rows]
        cameras = dataset.rigs[int(rigs[0])]
        yield RecordingInput(str(name), frame[0] + np.arange(F), cameras, keypoints, confidence, target,
                             str(labels["recording"][rows[0]]), int(labels["person"][rows[0]]))  # fmt: skip


def lift_views(lifter: Lifter3D, inputs: RecordingInput, roots: np.ndarray | None = None) -> np.ndarray:
    """f32[F, C, J, 3]: each camera's detections lifted (mm, root-relative, that camera's axes; NaN where
    the view's root is neither detected nor derived from the hips, `root_from_hips`): for a temporal
    lifter camera by camera as a sequence, so that it reads its windows of frames; for a frame lifter
    every view-frame in one call.

    `roots` (f32[F, 3] world mm, `root_track`): lift only the view-frames whose root neither the detector
    nor the hips give, with the root put where `roots` projects into that view (`root_from_world`)."""
    names = tuple(lifter.joint_names)
    F, C, J, _ = inputs.keypoints.shape
    if J != lifter.num_joints:
        raise ValueError(f"recording {inputs.name}: {J} joints per view, but the lifter of {lifter.source} lifts {names}")
    keypoints, confidence = root_from_hips(lifter.skeleton, inputs.keypoints, inputs.confidence)
    liftable = confidence[..., ROOT] > 0
    if roots is not None:
        keypoints, confidence = root_from_world(inputs.cameras, keypoints, confidence, roots)
        liftable = (confidence[..., ROOT] > 0) & ~liftable
    lifted = np.full((F, C, J, 3), np.nan, np.float32)
    # A temporal lifter reads each camera's frames as a sequence; a frame lifter takes every view-frame in one call.
    groups = [[view] for view in range(C)] if lifter.model_config.temporal_window > 1 else [list(range(C))]
    for views in groups:
        if liftable[:, views].any():
            K = np.broadcast_to(np.asarray(inputs.cameras.K, np.float32)[views], (F, len(views), 3, 3)).reshape(-1, 3, 3)
            lift = lifter.predict(keypoints[:, views].reshape(-1, J, 2), intrinsics=K, confidence=confidence[:, views].reshape(-1, J))
            lifted[:, views] = np.where(liftable[:, views, None, None], lift.reshape(F, len(views), J, 3), np.nan)
    return lifted


def root_from_world(cameras: Cameras, keypoints: np.ndarray, confidence: np.ndarray, roots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The detections (f32[F, C, J, 2] undistorted pixels, [F, C, J]) with a missing root put where the
    world point roots[f] (mm, NaN where unknown) projects into that view, at a view-frame that detects
    some joint and has the point in front of it: the lifter's input is root-relative, so a view whose
    pelvis and hips are occluded is lifted about where the body's root is known to be."""
    R, t, K = (np.asarray(getattr(cameras, name), np.float64) for name in ("R", "t", "K"))
    in_camera = np.einsum("cij,fj->fci", R, np.asarray(roots, np.float64)) + t  # [F, C, 3]
    pixels = np.einsum("cij,fcj->fci", K, in_camera / in_camera[..., 2:])[..., :2]
    derive = (
        (confidence[..., ROOT] <= 0) & (confidence > 0).any(-1) & np.isfinite(in_camera).all(-1) & (in_camera[..., 2] > MIN_DEPTH_MM)
    )
    keypoints, confidence = keypoints.copy(), confidence.copy()
    keypoints[..., ROOT, :] = np.where(derive[..., None], pixels, keypoints[..., ROOT, :])
    confidence[..., ROOT] = np.where(derive, 1.0, confidence[..., ROOT])  # any score > 0: the lifter reads seen / not
    return keypoints, confidence


def root_track(roots: np.ndarray) -> np.ndarray:
    """f32[F, 3]: a recording's fused root positions (world mm, NaN where the fusion has none) with every
    missing frame interpolated linearly between the nearest frames that have one (held before the first
    and after the last): the body's root moves smoothly, so this is where it was.  All NaN without any."""
    roots = np.asarray(roots, np.float32)
    known = np.flatnonzero(np.isfinite(roots).all(-1))
    if not len(known):
        return roots
    frames = np.arange(len(roots))
    return np.stack([np.interp(frames, known, roots[known, axis]) for axis in range(3)], -1).astype(np.float32)


def root_from_hips(skeleton: Skeleton, keypoints: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The detections with a missing root (the pelvis) put midway between the hips where both are seen
    (confidence: the lower of theirs), as the detector layouts without a pelvis derive it: a view whose
    pelvis is occluded can still be lifted.  The hips: the root's children that are a left/right pair."""
    children = {j for j, parent in enumerate(skeleton.parents) if parent == ROOT}
    hips = [pair for pair in skeleton.left_right_pairs if set(pair) <= children]
    if not hips:
        return keypoints, confidence
    left, right = hips[0]
    derive = (confidence[..., ROOT] <= 0) & (confidence[..., left] > 0) & (confidence[..., right] > 0)
    keypoints, confidence = keypoints.copy(), confidence.copy()
    keypoints[..., ROOT, :] = np.where(derive[..., None], 0.5 * (keypoints[..., left, :] + keypoints[..., right, :]), keypoints[..., ROOT, :])
    confidence[..., ROOT] = np.where(derive, np.minimum(confidence[..., left], confidence[..., right]), confidence[..., ROOT])
    return keypoints, confidence


@dataclasses.dataclass(frozen=True)
class RecordingMotion:
    """One recording's 3D motion on its frame axis (F frames, J joints), world frame of the rig, mm.

    points:      f32[F, J, 3]; gaps of at most max_gap frames interpolated, NaN where still missing.
    provenance:  i8[F, J] `Provenance` (INTERPOLATED where the gap filling filled the cell).
    uncertainty: f32[F, J] mm, the posterior RMS error: the fusion's, NaN where not fused (interpolated or
                 missing); the trajectory's (`smooth_recording`), its bridges included.
    views:       i8[F, J] detections that agree with the joint.
    segments:    i64[S, 2] (start, stop) frame indices, half-open, of the complete runs: one output file each.
    fusion:      the fusion before gap filling (with each view's placement).
    acceleration_mm_s2: f32[J] the motion prior's process noise per joint (mm/s^2; over the parts solved
                 apart, their geometric mean weighted by frames), or None without the trajectory.
    impact_weight: f32[F, J] the trajectory's Student-t weight of each acceleration (below 0.5: an impact;
                 NaN where not solved), or None without the trajectory.
    """

    name: str
    frames: np.ndarray
    points: np.ndarray
    provenance: np.ndarray
    uncertainty: np.ndarray
    views: np.ndarray
    segments: np.ndarray
    seen: np.ndarray
    fusion: Fusion
    acceleration_mm_s2: np.ndarray | None = None
    impact_weight: np.ndarray | None = None

    @property
    def interpolated_frames(self) -> int:
        return int((self.provenance == Provenance.INTERPOLATED).any(-1).sum())

    @property
    def dropped_frames(self) -> int:
        """Frames in no segment (some joint missing there even after the gap filling)."""
        return len(self.frames) - int(np.sum(self.segments[:, 1] - self.segments[:, 0]))

    @property
    def unseen_frames(self) -> int:
        """Frames at which no camera detects the person."""
        return int((~self.seen).sum())


def lift_and_reconstruct(
    lifter: Lifter3D,
    inputs: RecordingInput,
    config: FusionConfig = FusionConfig(),
    max_gap: int = DEFAULT_MAX_GAP,
    bridge_lifted: bool = True,
    trajectory: TrajectoryConfig | None = None,
    fps: float | None = None,
) -> tuple[RecordingMotion, np.ndarray]:
    """The recording's motion and the lifts it fused (f32[F, C, J, 3]), in two passes.

    The first lifts every view whose root the detector or the hips give and fuses.  A view that detects
    the person but not its root (pelvis and a hip occluded) is then lifted about the fused root's
    projection (`root_track`, `root_from_world`) and the frames it gains are fused again: without it, a
    joint such a view alone detects has nothing to fix its depth, and the frame has a gap although a
    camera sees the person.

    Then the joints no view detects are re-anchored where views detect them (`anchored_lifts`), and
    `fill_recording` bridges the short runs of them: on the Human3.6M development split's training
    recordings with simulated occlusion (docs/reconstruction.md), such joints 124.5 mm from the truth,
    against 147.8 bridged only, 140.4 anchored only and 175.6 with neither.

    With `trajectory` (and the recordings' `fps`), `smooth_recording` solves the motion over time
    instead of `fill_recording`'s per-instant points (`bridge_lifted` then does not apply)."""
    if trajectory is not None and not (fps and fps > 0):
        raise ValueError(f"recording {inputs.name}: the trajectory needs the recording's fps, got {fps!r}")
    lifted = lift_views(lifter, inputs)
    fusion = fuse_recording(inputs, lifted, config)
    unlifted = np.isnan(lifted[..., ROOT, 0]) & (inputs.confidence > 0).any(-1)
    if unlifted.any():
        relifted = lift_views(lifter, inputs, root_track(fusion.points[:, ROOT]))
        gained = unlifted & np.isfinite(relifted[..., ROOT, 0])
        if gained.any():
            lifted = np.where(gained[..., None, None], relifted, lifted)
            again = fuse_recording(inputs, lifted, config, frames=gained.any(1))
            fusion = Fusion(**{
                name: np.where(gained.any(1).reshape((-1,) + (1,) * (value.ndim - 1)), getattr(again, name), value)
                for name, value in dataclasses.asdict(fusion).items()
            })  # fmt: skip
    anchored = anchored_lifts(fusion.points, fusion.provenance, placed_lifts(inputs.cameras, lifted, fusion.placement))
    fusion = dataclasses.replace(fusion, points=anchored)
    if trajectory is None:
        return fill_recording(inputs, fusion, max_gap, bridge_lifted), lifted
    return smooth_recording(inputs, fusion, lifter.skeleton.bones, fps, trajectory, max_gap), lifted


def fuse_recording(
    inputs: RecordingInput, lifted: np.ndarray | None, config: FusionConfig = FusionConfig(), frames: np.ndarray | None = None
) -> Fusion:
    """`fuse` at every frame some camera sees the person (and `frames`, bool[F], allows), on the whole
    frame axis: a frame not fused has nothing (NONE, NaN)."""
    F, C, J, _ = inputs.keypoints.shape
    rows = np.flatnonzero(inputs.seen if frames is None else inputs.seen & frames)
    fused = fuse(
        inputs.cameras, inputs.keypoints[rows], inputs.confidence[rows], None if lifted is None else lifted[rows], config
    )
    shapes = {"points": (J, 3), "provenance": (J,), "uncertainty": (J,), "views": (J,), "placement": (C, 4), "covariance": (J, 3, 3)}
    whole = {}
    for name, shape in shapes.items():
        values = getattr(fused, name)
        full = np.zeros((F, *shape), values.dtype) if values.dtype.kind == "i" else np.full((F, *shape), np.nan, values.dtype)
        full[rows] = values
        whole[name] = full
    return Fusion(**whole)


def placed_lifts(cameras: Cameras, lifted: np.ndarray, placement: np.ndarray) -> np.ndarray:
    """f32[F, C, J, 3] world mm: each view's lift where the fusion placed it, X = T_c + s_c R_c^T L_c
    (placement [F, C, 4]: root T_c and scale s_c); NaN where the view's lift did not count."""
    R = np.asarray(cameras.R, np.float64)  # [C, 3, 3] (one rig per recording)
    world = np.einsum("cba,fcjb->fcja", R, lifted.astype(np.float64))  # R^T L
    where = placement.astype(np.float64)
    return (where[..., None, :3] + where[..., None, 3:] * world).astype(np.float32)


def anchored_lifts(points: np.ndarray, provenance: np.ndarray, placed: np.ndarray) -> np.ndarray:
    """f32[F, J, 3]: the LIFTED cells (no view detects the joint) re-anchored to the detected ones.

    A lifter's error in a joint changes slowly with the pose, so where the joint is detected (TRIANGULATED
    or FUSED) the fused point minus the mean placed lift (`placed_lifts`) measures it; over a run of
    lifted frames that offset is interpolated linearly between the detected frames around it (held
    beyond the first and last) and added to the lifts: the joint follows the lifts' motion from where
    the cameras last put it to where they put it next.  A joint never detected keeps its lifts."""
    counted = np.isfinite(placed).all(-1)  # [F, C, J]
    guess = np.where(counted[..., None], placed, 0.0).sum(1) / np.maximum(counted.sum(1), 1)[..., None]  # [F, J, 3]
    guess = np.where(counted.any(1)[..., None], guess, np.nan)
    detected = np.isin(provenance, (Provenance.TRIANGULATED, Provenance.FUSED)) & np.isfinite(guess).all(-1)
    lifted_only = (provenance == Provenance.LIFTED) & np.isfinite(guess).all(-1)
    out = points.copy()
    frames = np.arange(len(points))
    for joint in np.flatnonzero(lifted_only.any(0) & detected.any(0)):
        known = np.flatnonzero(detected[:, joint])
        offset = points[known, joint] - guess[known, joint]
        cells = np.flatnonzero(lifted_only[:, joint])
        shift = np.stack([np.interp(frames[cells], known, offset[:, axis]) for axis in range(3)], -1)
        out[cells, joint] = guess[cells, joint] + shift
    return out.astype(np.float32)


def fill_recording(inputs: RecordingInput, fusion: Fusion, max_gap: int = DEFAULT_MAX_GAP, bridge_lifted: bool = True) -> RecordingMotion:
    """`fill_gaps` on a recording's fusion (`fuse_recording`).

    `bridge_lifted`: a joint no view detects (LIFTED: the lifts alone) for at most `max_gap` frames
    between frames where views fix it is interpolated between them instead: on the Human3.6M training
    recordings with simulated occlusion, 148 mm from the truth against the lifts' 175 (a lifter guesses
    a joint missing from its input; the joint moves little in 0.2 s).  Longer runs keep the lifts."""
    F, J = fusion.provenance.shape
    points, bridged = fusion.points, np.zeros((F, J), bool)
    if bridge_lifted:
        lifted_only = fusion.provenance == Provenance.LIFTED
        bridging = fill_gaps(np.where(lifted_only[..., None], np.nan, points), max_gap)
        bridged = bridging.filled & lifted_only
        points = np.where(bridged[..., None], bridging.values, points)
    filling = fill_gaps(points, max_gap)
    provenance = np.where(filling.filled | bridged, np.int8(Provenance.INTERPOLATED), fusion.provenance).astype(np.int8)
    uncertainty = np.where(bridged, np.nan, fusion.uncertainty).astype(np.float32)
    return RecordingMotion(
        inputs.name, inputs.frames, filling.values, provenance, uncertainty, fusion.views, filling.segments, inputs.seen, fusion
    )


def smooth_recording(
    inputs: RecordingInput, fusion: Fusion, bones, fps: float, config: TrajectoryConfig = TrajectoryConfig(), max_gap: int = DEFAULT_MAX_GAP
) -> RecordingMotion:
    """The recording's motion solved over time (`jaxpose.reconstruction.trajectory`) from its per-instant
    evidence (`fuse_recording`, the lifted-only cells re-anchored): every cell with evidence keeps its
    provenance, a missing one (no camera sees the person) that a gap of at most `max_gap` frames holds
    is the smoother's bridge (INTERPOLATED), and a longer gap splits the recording as `fill_recording`
    does.  The parts a gap of more than `max_gap` frames without any evidence separates are solved apart
    (nothing is bridged across it; a bridge of thousands of frames would only slow the solve), with the
    limb lengths of the whole recording, each with its own motion prior (`TrajectoryConfig.acceleration_mm_s2`
    None: estimated on that part).  The uncertainty is the trajectory's posterior RMS error, bridges included."""
    missing = fusion.provenance == Provenance.NONE
    lengths = limb_lengths(fusion.points, fusion.provenance, bones)
    points = np.full(fusion.points.shape, np.nan, np.float32)
    sigma = np.full(missing.shape, np.nan, np.float32)
    impact = np.full(missing.shape, np.nan, np.float32)
    log_noise, solved_frames = np.zeros(missing.shape[1]), np.zeros(missing.shape[1])
    evidence = ~missing.all(-1)  # [F] frames with something to go by
    bridgeable = fill_gaps(np.where(evidence, 0.0, np.nan)[:, None, None], max_gap).filled[:, 0]
    for start, stop in complete_segments(evidence | bridgeable):
        part = slice(start, stop)
        solved = solve_trajectory(fusion.points[part], fusion.covariance[part], fusion.provenance[part], bones, fps, config, lengths)
        points[part], sigma[part], impact[part] = solved.points, solved.sigma, solved.impact_weight
        counted = np.isfinite(solved.acceleration_mm_s2)
        log_noise[counted] += (stop - start) * np.log(solved.acceleration_mm_s2[counted])
        solved_frames[counted] += stop - start
    bridged = fill_gaps(np.where(missing[..., None], np.nan, fusion.points), max_gap).filled
    kept = ~missing | bridged
    return RecordingMotion(
        inputs.name,
        inputs.frames,
        np.where(kept[..., None], points, np.nan).astype(np.float32),
        np.where(bridged, np.int8(Provenance.INTERPOLATED), fusion.provenance).astype(np.int8),
        np.where(kept, sigma, np.nan).astype(np.float32),
        fusion.views,
        complete_segments(kept.all(-1)),
        inputs.seen,
        fusion,
        np.where(solved_frames > 0, np.exp(log_noise / np.maximum(solved_frames, 1)), np.nan).astype(np.float32),
        np.where(np.isfinite(sigma), impact, np.nan).astype(np.float32),
    )
