"""Preparing a rig project's recordings (`prepare`): found -> read -> aligned -> prepared, one recording at a
time, in bounded memory and a fixed number of compilations.

The calibration files found are read (`jaxpose.rig.cameras`).  Each recording is then read and its cameras put
on one time axis at every instant (`_aligned`, an `Aligned` each; the split and its strides are row
selections of the result, made after it: `jaxpose.rig.split`).  Without any calibration the rigs are
recovered from the aligned recordings, one per session (`jaxpose.rig.recovered`).  Each recording is
undistorted and searched for the person the views agree on (`Preparation`) in chunks of `geometry.CHUNK`
instants that run across recordings (`jaxpose.chunks`), so that a short recording does not pay for a chunk
of its own and the compiled functions see one shape; its result is appended to the prepared arrays
(`jaxpose.rig.cache.Assembly`) as soon as it is chosen, and let go.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import hashlib
import logging
import os
import shutil
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from jaxpose.chunks import ChunkedMap
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.layouts import lifting_skeleton
from jaxpose.rig import cache, geometry, people, tracked, tracks
from jaxpose.rig.cache import Assembly, PreparedProject, ProjectMeta, RecordingSummary, SessionSummary
from jaxpose.rig.cameras import check_unit_against_people, distinct_rigs, in_view_order, read_calibrations
from jaxpose.rig.config import RigProjectConfig
from jaxpose.formats.rig_folder import GROUND_TRUTH_NPZ
from jaxpose.rig.recordings import FoundProject, Recording, ground_truth_on_instants, lifting_views, read_detections, truth_of_people
from jaxpose.rig.recovered import RecoveredSession, ground_truth_into_recovered_world, recover_sessions
from jaxpose.rig.timeline import SyncEstimate, align, estimate_recording_offsets, instants_of, lone_cameras, parse_frame_offsets
from jaxpose.skeleton import Skeleton

log = logging.getLogger(__name__)

UNIT_CHECK_INSTANTS = 256  # instants of a rig's people triangulated to check its unit
BACKLOG = 8  # recordings done but waiting for an earlier one before that one's chunk is run part-full


@dataclasses.dataclass(frozen=True)
class Aligned:
    """One recording on one time axis, at every instant, and what reading it found."""

    recording: Recording
    layout: str
    """The keypoint layout of its detections."""
    known_cameras: dict[str, dict]
    """What its detections.npz gives of each camera (`jaxpose.rig.recordings.RecordingDetections`)."""
    calibration: RigCalibration | None
    """Its rig (None until a recovered one is given: `dataclasses.replace`)."""
    offsets: dict[str, int]
    """Camera -> frame offset: its frame f shows instant f + offset."""
    sync: SyncEstimate | None
    """The estimate the offsets come from (--data.sync auto), else None."""
    instants: np.ndarray
    """int[N] every instant of the recording."""
    keypoints: np.ndarray
    """f32[N, C, K, J, 2] pixels as detected, up to K people per view."""
    confidence: np.ndarray
    """f32[N, C, K, J]"""
    warnings: tuple[str, ...] = ()
    """What reading it found suspect (an unreliable sync, a camera sharing no instant), for the report."""


class Phases:
    """The seconds spent in each phase of loading (they interleave: recordings stream through all of
    them), a progress bar per phase, and one timed log line per phase at the end."""

    def __init__(self, total: int, progress: bool):
        self.total, self.progress = total, progress
        self.seconds: dict[str, float] = collections.defaultdict(float)
        self.recordings: dict[str, int] = collections.defaultdict(int)
        self.instants: dict[str, int] = collections.defaultdict(int)
        self.bars: dict[str, tqdm] = {}

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def advance(self, name: str, instants: int = 0) -> None:
        if name not in self.bars:
            self.bars[name] = tqdm(total=self.total, desc=name, unit="recording", disable=not self.progress, position=len(self.bars), leave=False)
        self.bars[name].update(1)
        self.recordings[name] += 1
        self.instants[name] += instants

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
        for name, seconds in self.seconds.items():
            counted = f"{self.recordings[name]} recordings" if name in self.recordings else f"{self.total} recordings"
            counted += f", {self.instants[name]:,} instants" if self.instants[name] else ""
            log.info("%s: %s in %.1f s", name, counted, seconds)


def prepare(config: RigProjectConfig, found: FoundProject, progress: bool, entry: cache.Entry) -> PreparedProject:
    """Every instant of the project prepared from its recordings (found -> read -> aligned -> prepared, one
    recording at a time), and committed to the cache as `entry`."""
    started = time.perf_counter()
    recordings = found.recordings
    project_calibration, calibrations = read_calibrations(found, config.calibration_unit)
    present = set().union(*(recording.cameras for recording in recordings))
    if project_calibration is not None:
        camera_order = [name for name in project_calibration.camera_names if name in present]
    else:
        camera_order = sorted(present)
    for recording in recordings:
        if calibrations[recording.name] is not None:  # every detection folder needs its camera
            calibrations[recording.name].select(sorted(recording.cameras), f"detection folders of recording {recording.name}")
    phases = Phases(len(recordings), progress)
    given_offsets = parse_frame_offsets(config.frame_offsets, recordings)
    parts = _aligned(config, recordings, calibrations, camera_order, given_offsets, phases)
    sessions: tuple[RecoveredSession, ...] = ()
    if all(rig is None for rig in calibrations.values()):
        parts = list(parts)
        with phases("rig recovered"):
            sessions, calibrations = recover_sessions(
                [part.recording.name for part in parts], [part.known_cameras for part in parts],
                [(part.keypoints, part.confidence) for part in parts], camera_order,
                lifting_skeleton(parts[0].layout), sessions=config.sessions, find=config.find_sessions,
                image_size=config.image_size, max_frames=config.recovery_frames, root=config.root,
                height_mm=config.subject_height_mm,
            )  # fmt: skip
        parts = [dataclasses.replace(part, calibration=calibrations[part.recording.name]) for part in parts]
    elif config.sessions:
        log.warning("--data.sessions is for projects without a calibration: ignored (the calibration files give each recording's rig)")
    distinct, rig_index = distinct_rigs(calibrations)
    rigs = geometry.Rigs.of([in_view_order(rig, camera_order) for rig in distinct])
    temporary = cache.start(entry)
    preparation = Preparation(
        rigs, rig_index, tuple(camera_order), cache.Assembly(temporary), phases, threshold_px=config.person_threshold_px, people=config.people, recovered=bool(sessions),
        check_unit=config.calibration_unit == "auto" and not sessions,
        labels={"subject": np.dtype(f"<U{len(f'rig{len(rig_index) - 1}')}"),
                "recording": np.dtype(f"<U{max(len(recording.name) for recording in recordings)}")},
    )  # fmt: skip
    try:
        outcome = preparation.run(parts)
    except BaseException:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
        raise
    finally:
        phases.close()
    meta = ProjectMeta(
        camera_names=tuple(camera_order), layout=outcome.layout, recordings=outcome.summaries, ground_truth_seen=outcome.ground_truth_seen,
        warnings=outcome.warnings, sessions=tuple(SessionSummary.of(session) for session in sessions),
        rigs={field: np.stack([np.asarray(getattr(c.cameras, field), np.float32) for c in rigs.calibrations]) for field in ("K", "R", "t")},
    )  # fmt: skip
    prepared = cache.finish(entry, temporary, preparation.assembly, meta, sessions)
    note = "" if prepared.folder is None else f"; {cache.size_note(config.cache)}"
    log.info("%d recordings (%d instants) %s in %.1f s%s", len(recordings), len(prepared.arrays["frame"]), prepared.how, time.perf_counter() - started, note)
    return prepared


def _aligned(
    config: RigProjectConfig,
    recordings: Sequence[Recording],
    calibrations: Mapping[str, RigCalibration | None],
    camera_order: Sequence[str],
    given: dict[tuple[str, str], int],
    phases: Phases,
) -> Iterator[Aligned]:
    """Each recording read, on one time axis at every instant, one at a time, with its rig (`calibrations`) and
    its offsets (`given` by --data.frame-offsets, or estimated with --data.sync auto); every recording in one
    keypoint layout."""
    parsed = config.cache / PARSED
    layouts: dict[str, str] = {}
    for recording in recordings:
        with phases("recordings read"):
            read = read_detections(recording, config.skeleton, phases.progress, parsed / _parsed_name(recording))
            views = lifting_views(read, config.min_confidence)
        layouts[recording.name] = read.layout
        if len(set(layouts.values())) > 1:
            raise DataFormatError(config.root, "one keypoint layout in every recording", f"layouts {layouts}")
        cameras = [camera for camera in camera_order if camera in views]
        warnings: list[str] = []
        sync = None
        if config.sync == "auto":
            with phases("offsets"):
                sync = estimate_recording_offsets(recording, calibrations[recording.name], views, cameras, config.max_sync_offset)
            offsets = dict(zip(cameras, sync.offsets.tolist()))
            state = "" if sync.reliable else f" (UNRELIABLE: {sync.doubt})"
            log.info("recording %s: estimated frame offsets %s%s", recording.name, offsets, state)
            if not sync.reliable:
                warnings.append(f"frame offsets UNRELIABLE: {sync.doubt}")
            phases.advance("offsets")
        else:
            offsets = {camera: given.get((recording.name, camera), 0) for camera in cameras}
        for camera in lone_cameras(views, offsets):
            warnings.append(
                f"camera {camera} (frame offset {offsets.get(camera, 0):+d}) shares no instant with the other cameras:"
                " are --data.frame-offsets right?"
            )
            log.warning("recording %s: %s", recording.name, warnings[-1])
        with phases("recordings read"):
            instants = instants_of(views, offsets)
            if not len(instants):
                raise DataFormatError(recording.folder, "detections in at least one frame", "no frame")
            keypoints, confidence = align(views, camera_order, offsets, instants)
        phases.advance("recordings read", len(instants))
        yield Aligned(
            recording, read.layout, read.known_cameras, calibrations[recording.name], offsets, sync, instants, keypoints, confidence,
            tuple(warnings),
        )


PARSED = "parsed"
"""The cache's folder of parsed JSON detections, one sub-folder per recording (`_parsed_name`)."""


def _parsed_name(recording: Recording) -> str:
    """The name of a recording's folder of parsed JSON in the cache: its name and a digest of its folder's
    absolute path, so that projects sharing one --data.cache-dir never take each other's recordings of the
    same name (never stale, as each file's key checks the content; but parsed again and again)."""
    return f"{recording.name}-{hashlib.blake2b(os.fsencode(recording.folder.resolve()), digest_size=8).hexdigest()}"


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What preparing the recordings did besides the arrays (`Preparation.run`)."""

    summaries: tuple[RecordingSummary, ...]
    """Per recording, in order, what loading did."""
    ground_truth_seen: bool
    warnings: tuple[str, ...]
    """What the checks of the calibrations found suspect (people of an unlikely size), for the report."""
    layout: str
    """The recordings' keypoint layout (every `Aligned` carries it; one for all)."""


@dataclasses.dataclass
class Preparation:
    """Undistort every recording, choose its person, attach its ground truth, check the calibrations'
    unit (`check_unit`) and append every instant to `assembly`.
    `labels`: the string dtypes of the "subject" and "recording" labels (one width for every recording).
    `run` takes the recordings as they come and returns its `Outcome`; the fields after `labels` are its
    tally while it runs."""

    rigs: geometry.Rigs
    rig_of: Mapping[str, int]
    """Recording name -> its rig's index in `rigs`."""
    camera_order: tuple[str, ...]
    """Every view, in the prepared arrays' order."""
    assembly: Assembly
    phases: Phases
    threshold_px: float
    people: int | None
    """--data.people: how many people there are, where known."""
    recovered: bool
    check_unit: bool
    labels: dict[str, np.dtype]
    summaries: list[RecordingSummary] = dataclasses.field(default_factory=list)
    ground_truth_seen: bool = False
    warnings: list[str] = dataclasses.field(default_factory=list)
    layout: str | None = None

    def run(self, parts: Iterable[Aligned]) -> Outcome:
        units = _UnitCheck(self.rigs) if self.check_unit else None
        mappers: dict[int, ChunkedMap] = {}
        waiting: dict[int, tuple[Aligned, tuple | None]] = {}  # by index: the part, its proposals once through
        group_of: dict[int, int] = {}
        added = 0

        def through(pairs):
            for index, output in pairs:
                waiting[index] = (waiting[index][0], output)

        def drain(final: bool = False):
            nonlocal added
            while added in waiting and waiting[added][1] is not None:
                part, (undistorted, confidence, found) = waiting.pop(added)
                with self.phases("people chosen"):
                    self._finish(dataclasses.replace(part, confidence=confidence), undistorted, people.Proposals(*found), units)
                self.phases.advance("people chosen", len(part.instants))
                added += 1
            blocked = sum(output is not None for _, output in waiting.values())
            if not final and blocked > BACKLOG and added in waiting:  # the next one waits in another count's part-full chunk
                with self.phases("people chosen"):
                    through(mappers[group_of[added]].flush())
                drain()

        for index, part in enumerate(parts):
            self.layout = part.layout
            group = part.keypoints.shape[2]  # people per view: one compiled shape per count
            mapper = mappers.setdefault(group, ChunkedMap(self._propose, geometry.CHUNK))
            group_of[index] = group
            waiting[index] = (part, None)
            rig_rows = np.full(len(part.instants), self.rig_of[part.recording.name], np.int32)
            with self.phases("people chosen"):
                through(mapper.add((rig_rows, part.keypoints, part.confidence), tag=index))
            drain()
        for mapper in mappers.values():
            with self.phases("people chosen"):
                through(mapper.flush())
        drain(final=True)
        if units is not None:
            units.finish()
            self.warnings += units.warnings
        return Outcome(tuple(self.summaries), self.ground_truth_seen, tuple(self.warnings), self.layout)

    def _propose(self, rig_rows, keypoints, confidence):
        """One chunk: undistorted keypoints, their confidence, and the person's proposals
        (`jaxpose.rig.people.proposals`).  A keypoint with no undistorted position (a detector's point far
        outside the image, where the lens model folds back: `jaxpose.camera.UNDISTORTION_TOLERANCE`) is
        undetected, as predict's --outside-margin makes it."""
        undistorted = geometry.undistort(self.rigs, rig_rows, keypoints)
        placed = np.isfinite(undistorted).all(-1)
        confidence = np.where(placed, confidence, 0.0).astype(confidence.dtype)
        undistorted = np.where(placed[..., None], undistorted, 0.0).astype(undistorted.dtype)
        found = people.proposals(self.rigs.P[rig_rows], undistorted, confidence, self.threshold_px)
        return undistorted, confidence, dataclasses.astuple(found)

    def _finish(self, part: Aligned, undistorted: np.ndarray, found: people.Proposals, units: "_UnitCheck | None") -> None:
        """One recording's people found and tracked (`jaxpose.rig.tracked`), their ground truth attached, their
        rows appended: person after person, each one's instants in order."""
        recording, rig_index = part.recording, self.rig_of[part.recording.name]
        skeleton = lifting_skeleton(part.layout)
        chosen = tracked.everyone(found, self.rigs.P[rig_index], undistorted, part.confidence, skeleton, self.threshold_px, tracks.TrackSettings(people=self.people))
        instants = part.instants[chosen.instant]
        if chosen.people > 1 or chosen.implausible_tracks:
            log.info("recording %s: %d people found%s", recording.name, chosen.people,
                     f"; {chosen.implausible_tracks} tracks the detector scored low left out" if chosen.implausible_tracks else "")  # fmt: skip
        target, truth_instants = ground_truth_on_instants(recording.folder, skeleton, part.layout, part.instants)
        if target is not None:
            if self.recovered:  # into the recovered world first, fitted on every row (trimmed: a passer-by's rows weigh little)
                if target.shape[1] > 1:
                    raise DataFormatError(recording.folder / GROUND_TRUTH_NPZ, "points3d of one person [N, J, 3] in a project without"
                                          " calibration (several people are matched in the calibration's world)", f"{target.shape[1]} people")  # fmt: skip
                moved = ground_truth_into_recovered_world(target[chosen.instant, 0], chosen.keypoints, chosen.confidence, self.rigs.calibrations[rig_index])
                target = np.full(target.shape, np.nan, np.float32)
                target[chosen.instant, 0] = moved
            points = None
            if target.shape[1] > 1 or chosen.people > 1:
                points = geometry.triangulate_rows(self.rigs.P[rig_index], chosen.keypoints, chosen.confidence, method="normal")
                points = np.where(((chosen.confidence > 0).sum(1) >= 2)[..., None], points, np.nan)
            target = truth_of_people(target, chosen.instant, chosen.person, points)
        self.ground_truth_seen |= target is not None
        if units is not None:
            units.add(rig_index, chosen.keypoints, chosen.confidence, skeleton)
        rows = len(instants)
        self.assembly.add({
            "keypoints2d": chosen.keypoints,
            "confidence": chosen.confidence,
            "rig_index": np.full(rows, rig_index, np.int32),
            "target3d": target,
            "subject": np.full(rows, f"rig{rig_index}", self.labels["subject"]),
            "recording": np.full(rows, recording.name, self.labels["recording"]),
            "frame": instants.astype(np.int32),
            "person": chosen.person,
        })  # fmt: skip
        self.summaries.append(RecordingSummary(
            name=recording.name, cameras=tuple(camera for camera in self.camera_order if camera in recording.cameras),
            instants=len(part.instants), calibration=part.calibration.source, offsets=dict(part.offsets),
            offsets_estimated=part.sync is not None, sync_reliable=None if part.sync is None else part.sync.reliable,
            instants_with_choice=chosen.instants_with_choice, views_without_match=chosen.views_without_match,
            ground_truth_instants=truth_instants, warnings=part.warnings,
            people=tuple(int(count) for count in np.bincount(chosen.person)[1:]), implausible_tracks=chosen.implausible_tracks,
            dropped_person_instants=chosen.dropped_instants,
        ))  # fmt: skip


class _UnitCheck:
    """The people of each rig, triangulated on a few instants of its recordings, against its unit
    (`jaxpose.rig.cameras.check_unit_against_people`): checked once a rig has
    `UNIT_CHECK_INSTANTS` instants, so a wrong unit stops the load early."""

    def __init__(self, rigs: geometry.Rigs):
        self.rigs, self.skeleton = rigs, None
        self.samples: dict[int, list[tuple[np.ndarray, np.ndarray]]] = collections.defaultdict(list)
        self.checked: set[int] = set()
        self.warnings: list[str] = []

    def add(self, rig: int, keypoints: np.ndarray, confidence: np.ndarray, skeleton: Skeleton) -> None:
        self.skeleton = skeleton  # every recording's: one layout for all
        if rig in self.checked:
            return
        seen = np.flatnonzero(((confidence > 0).any(-1)).sum(-1) >= 2)
        rows = seen[np.linspace(0, len(seen) - 1, min(len(seen), UNIT_CHECK_INSTANTS)).round().astype(int)] if len(seen) else seen
        self.samples[rig].append((keypoints[rows], confidence[rows]))
        if sum(len(k) for k, _ in self.samples[rig]) >= UNIT_CHECK_INSTANTS:
            self._check(rig)

    def finish(self) -> None:
        for rig in list(self.samples):
            self._check(rig)

    def _check(self, rig: int) -> None:
        keypoints = np.concatenate([k for k, _ in self.samples[rig]])
        confidence = np.concatenate([c for _, c in self.samples.pop(rig)])
        self.checked.add(rig)
        if len(keypoints):
            points = geometry.triangulate_rows(self.rigs.P[rig], keypoints, confidence, method="normal")
            warning = check_unit_against_people(self.rigs.calibrations[rig], points, (confidence > 0).sum(1) >= 2, self.skeleton)
            self.warnings += [warning] if warning else []
