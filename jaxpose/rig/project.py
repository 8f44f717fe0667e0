"""A user's own rig: multi-camera recordings of a person, in the formats users already have, as data sets.

A project folder::

    PROJECT/
      <calibration>              optional: the rig of every recording (see below)
      <recording>/               one folder per recording (a trial, a session) of that rig
        detections.npz           jaxpose's multi-view arrays (`jaxpose.formats.detections_npz`: keypoints
                                 [N, C, J, 2] px, camera_names, optional confidence, frames [N],
                                 image_size, skeleton, K/dist/distortion_model), or
        <camera>/ or <camera>_json/   one folder per camera of OpenPose-style JSON frames, or
        <camera>.json            one COCO keypoint-results file per camera (image_id = frame number)
        <calibration>            optional: this recording's own rig, overriding the project's
        ground_truth.npz         optional, evaluation only: points3d [N, J, 3] world mm (the
                                 calibration's world frame), frames [N], joint_names [J]

Calibrations (`jaxpose.formats.calibration_files`): a jaxpose camera file, an Anipose / Pose2Sim /
FreeMoCap TOML, or EasyMocap's intri.yml + extri.yml, found in a folder by their content.  Cameras
are matched to the detection folders by name (a folder's name without `_json`), ignoring case,
separators and leading zeros where that matches them one to one ("cam_01" is folder "cam01_json").  Without any
calibration the rig is recovered from the recordings (`jaxpose.calibrate`).

What loading does to each recording, in order (one recording at a time: `jaxpose.rig.preparation`):
1. reads every camera's detections (parsed once, then cached: `jaxpose.formats.keypoint_files`),
   and finds its calibration (`jaxpose.rig.recordings`, `jaxpose.rig.cameras`);
2. converts them from the detector's layout to its lifting skeleton (the detector's own joints,
   root first: `jaxpose.layouts.to_lifting_skeleton`); scores below `min_confidence` are
   treated as missing;
3. aligns the cameras in time: camera c's frame f shows instant f + offset[c]; offsets given, or
   estimated (`jaxpose.rig.timeline`); instants seen by no camera are absent, a
   camera without a frame at an instant has confidence 0 there; every instant goes further (the split
   and the strides are applied to the prepared instants: `jaxpose.rig.split`);
4. without any calibration, groups the recordings by rig (sessions: given by --data.sessions, else found
   from the data) and recovers each session's rig from its recordings (`jaxpose.rig.recovered`);
5. undistorts the keypoints with the calibration (the data sets' rigs are then pinhole);
6. keeps one person per instant, the one the views agree on (`jaxpose.rig.people`), and checks a
   calibration read without a stated unit against that person's limbs;
7. attaches the ground truth where there is one, over the joints it shares with the lifting
   skeleton by name (the derived root from the hips where the ground truth has both:
   `jaxpose.data.ground_truth`), moved into a recovered rig's world.

The result, every instant of every recording, is prepared once: written to the project's cache
(``PROJECT/.jaxpose_cache/prepared-<key>/``, or --data.cache-dir, `jaxpose.rig.cache`) and memory-mapped
from there by every later run with the same inputs and options, whatever its split: the training and
validation parts are row selections of it (`jaxpose.rig.split`: held-out recordings or each
recording's final fraction, then the strides), and a temporal lifter's window is the neighbouring rows of the same
recording.  Every JSON file parsed is cached there too (`jaxpose.formats.keypoint_files`).  Steps 5 and 6
run in chunks of one fixed size across recordings (`jaxpose.rig.geometry`): the compilations of loading do
not grow with the number or the lengths of the recordings.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import pathlib
import shutil
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import Literal

import numpy as np

from jaxpose.formats.rig_cameras import CalibrationUnit, RigCalibration
from jaxpose.formats import keypoint_files
from jaxpose.formats.file_cache import CACHE_DIR
from jaxpose.formats.errors import DataFormatError
from jaxpose.layouts import lifting_skeleton
from jaxpose.rig import cache
from jaxpose.rig.cameras import distinct_rigs, in_view_order, read_calibrations
from jaxpose.rig.geometry import Rigs
from jaxpose.rig.people import DEFAULT_THRESHOLD_PX
from jaxpose.rig.preparation import Aligned, Phases, Preparation
from jaxpose.rig.cache import PreparedProject
from jaxpose.rig.split import SPLIT_FIELDS, RigProject, split
from jaxpose.rig.recordings import FoundProject, Recording, find_project, lifting_views, read_detections
from jaxpose.rig.recovered import RecoveredSession, recover_sessions
from jaxpose.rig.timeline import (
    align,
    estimate_recording_offsets,
    instants_of,
    lone_cameras,
    parse_frame_offsets,
)

log = logging.getLogger(__name__)

_NOT_PREPARED = ("root", "cache_dir", *SPLIT_FIELDS)  # where the project and its cache are; the split
_NOT_RECORDED = ("recordings", *SPLIT_FIELDS)  # which recordings a command reads is its own choice


@dataclasses.dataclass(frozen=True)
class RigProjectConfig:
    """A rig project folder and how its recordings are read (see `jaxpose.rig.project`)."""

    root: pathlib.Path = pathlib.Path("runs/rig_example/project")
    """The project folder: one sub-folder per recording, and optionally a calibration file."""
    calibration: pathlib.Path | None = None
    """A calibration for every recording (a recording's own calibration file still overrides it);
    None = the calibration file found in the project folder, if any; none anywhere = the rig is
    recovered from the recordings."""
    calibration_unit: CalibrationUnit = "auto"
    """Length unit of a TOML or EasyMocap calibration: Pose2Sim and EasyMocap write metres, Anipose the
    board's unit (usually mm), FreeMoCap mm.  auto: metres if the cameras lie within 100 units of each
    other, else mm (cm must be given)."""
    recordings: tuple[str, ...] = ()
    """Recordings (sub-folder names) to use; empty = all of them."""
    skeleton: str = "auto"
    """Keypoint layout of the detections: body25, body25b, coco17, coco18, halpe26 or a jaxpose
    skeleton name; auto = from the number of keypoints (75 values per person is ambiguous: BODY_25 or
    BODY_25B), or the `skeleton` array of a detections.npz."""
    min_confidence: float = 0.1
    """Keypoints scored below this are treated as not detected."""
    frame_offsets: tuple[str, ...] = ()
    """Cameras not started together: CAMERA=N (every recording) or RECORDING/CAMERA=N, meaning that
    camera's frame f shows the instant of the other cameras' frame f + N."""
    sync: Literal["given", "auto"] = "given"
    """given: --data.frame-offsets (default 0); auto: estimate every camera's integer offset per
    recording from the detections (epipolar geometry), reported and used (given offsets are ignored)."""
    max_sync_offset: int = 10
    """auto sync: the largest offset tried, in frames."""
    person_threshold_px: float = DEFAULT_THRESHOLD_PX
    """A view's detection belongs to the chosen person when it lies within this median distance (px)
    of that person's projection; views without one get confidence 0 at that instant."""
    recovery_frames: int = 600
    """Without a calibration: the instants (spread over all recordings) the rig is recovered from
    (`jaxpose.calibrate`'s max_frames: 600 take ~25 s on 2 cores)."""
    image_size: tuple[int, int] | None = None
    """Width and height of the images (px), needed only to recover the rig of JSON detections without
    any calibration (a detections.npz carries its own)."""
    sessions: tuple[str, ...] = ()
    """Without a calibration: the recordings grouped by rig, SESSION=REC1,REC2 per session (cameras moved
    between sessions), every recording in one; empty = found from the data (--data.find-sessions)."""
    find_sessions: bool = True
    """Without a calibration or --data.sessions: find the sessions from the data (2+ recordings: recordings
    one rig explains belong together); --data.no-find-sessions: one rig for every recording."""
    subject_height_mm: float | None = None
    """Without a calibration: the subject's height (mm), which sets the recovered world's scale (Pose2Sim's
    participant_height); None: the generic limb prior (5-9% off for bodies unlike it: docs/calibration.md)."""
    validation_recordings: tuple[str, ...] = ()
    """Recordings held out for validation; empty = the last --data.validation-fraction of every recording."""
    validation_fraction: float = 0.2
    """With no --data.validation-recordings: the final block of each recording (a fraction of its
    instants) validates; the rest trains."""
    train_stride: int = 1
    """Keep every n-th instant of the training part."""
    validation_stride: int = 1
    """Keep every n-th instant of the validation part."""
    cache_dir: pathlib.Path | None = None
    """Where the prepared project and the parsed JSON are cached; None = PROJECT/.jaxpose_cache.  Name a
    folder that can be written for a read-only project (without one it is prepared in memory every run)."""

    def __post_init__(self):
        if self.subject_height_mm is not None and not 500.0 <= self.subject_height_mm <= 2800.0:
            raise ValueError(f"--data.subject-height-mm is the subject's height in millimetres (500-2800), got {self.subject_height_mm}")
        if not 0.0 < self.validation_fraction < 1.0:
            raise ValueError(f"--data.validation-fraction must lie in (0, 1), got {self.validation_fraction}")
        if self.train_stride < 1 or self.validation_stride < 1 or self.max_sync_offset < 0:
            raise ValueError("--data.train-stride and --data.validation-stride must be >= 1, --data.max-sync-offset >= 0")


def load_rig_project(config: RigProjectConfig, progress: bool = True, found: FoundProject | None = None) -> RigProject:
    """Every recording of the project, read, aligned, calibrated and reduced to one person (see the module
    docstring), or all that from the cache, split into training and validation parts (`split`).  `found`:
    the project's files as found already (`jaxpose.rig.recordings.find_project`), else found now."""
    found = found or find_project(config.root, config.recordings, config.calibration)
    unknown = sorted(set(config.validation_recordings) - set(found.names))
    if unknown:  # before any work
        raise ValueError(f"--data.validation-recordings {unknown}: no such recording (have {list(found.names)})")
    return split(prepared_project(config, found, progress), config)


def cache_folder(config: RigProjectConfig) -> pathlib.Path:
    """The project's cache: --data.cache-dir, else PROJECT/.jaxpose_cache."""
    return config.cache_dir if config.cache_dir is not None else config.root / CACHE_DIR


def prepared_project(config: RigProjectConfig, found: FoundProject, progress: bool = True, prepare: bool = True) -> PreparedProject | None:
    """Every instant of the project from the cache, else prepared (and cached where the cache can be
    written); with `prepare` False, None where the cache does not hold it."""
    inputs = cache.input_digests(_input_files(config, found))
    cache_key = cache.key(_options(config), inputs)
    prepared = cache.lookup(cache_folder(config), cache_key)
    if prepared is None and config.skeleton != "auto":  # a layout named (as a run records the one it resolved) reads what auto prepared as it
        auto = cache.key(_options(dataclasses.replace(config, skeleton="auto")), inputs)
        prepared = cache.lookup(cache_folder(config), auto, layout=config.skeleton)
    if prepared is not None or not prepare:
        return prepared
    return _prepare(config, found, progress, cache_key, inputs)


def _options(config: RigProjectConfig) -> dict:
    """Every option that changes the prepared arrays (not where the project and its cache are, not the
    split), and the version of the JSON parsing whose results they hold."""
    options = {field.name: getattr(config, field.name) for field in dataclasses.fields(config) if field.name not in _NOT_PREPARED}
    options["calibration"] = None if config.calibration is None else str(config.calibration.resolve())
    return options | {"parsed_frames": keypoint_files.CACHE_VERSION}


def _input_files(config: RigProjectConfig, found: FoundProject) -> dict[str, list[pathlib.Path]]:
    """Every file loading may read, by group (`jaxpose.rig.cache.input_digests`): the project folder's
    files, --data.calibration with its siblings of the same kind (EasyMocap's extri.yml), and each
    recording's (its folder's files and every camera's detections), named by their absolute folders."""

    def plain_files(folder: pathlib.Path, suffix: str = "") -> list[pathlib.Path]:
        return [entry for entry in folder.iterdir() if not entry.name.startswith(".") and entry.suffix.endswith(suffix) and not entry.is_dir()]

    groups = {f"project {config.root.resolve()}": plain_files(config.root)}
    if config.calibration is not None:
        groups[f"calibration {config.calibration.resolve()}"] = [config.calibration, *plain_files(config.calibration.parent, config.calibration.suffix)]
    for recording in found.recordings:
        files = plain_files(recording.folder)
        for source in recording.sources.values():
            files += plain_files(source, ".json") if source.is_dir() else [source]
        groups[f"recording {recording.folder.resolve()}"] = files
    return groups


def _prepare(config: RigProjectConfig, found: FoundProject, progress: bool, cache_key: str, inputs: dict[str, str]) -> PreparedProject:
    """Every instant of the project prepared from its recordings (`jaxpose.rig.preparation`), and cached."""
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
    layouts: dict[str, str] = {}
    given_offsets = parse_frame_offsets(config.frame_offsets, recordings)
    parts = _aligned(config, recordings, calibrations, camera_order, given_offsets, phases, layouts)
    sessions: tuple[RecoveredSession, ...] = ()
    if all(rig is None for rig in calibrations.values()):
        parts = list(parts)
        with phases("rig recovered"):
            sessions, calibrations = recover_sessions(
                [part.recording.name for part in parts], [part.known_cameras for part in parts],
                [(part.keypoints, part.confidence) for part in parts], camera_order,
                lifting_skeleton(next(iter(layouts.values()))), sessions=config.sessions, find=config.find_sessions,
                image_size=config.image_size, max_frames=config.recovery_frames, root=config.root,
                height_mm=config.subject_height_mm,
            )  # fmt: skip
        parts = [dataclasses.replace(part, calibration=calibrations[part.recording.name]) for part in parts]
    elif config.sessions:
        log.warning("--data.sessions is for projects without a calibration: ignored (the calibration files give each recording's rig)")
    distinct, rig_index = distinct_rigs(calibrations)
    rigs = Rigs.of([in_view_order(rig, camera_order) for rig in distinct])
    cache_dir = cache_folder(config)
    temporary = cache.start(cache_dir, cache_key)
    preparation = Preparation(
        rigs, rig_index, lambda: lifting_skeleton(next(iter(layouts.values()))),
        cache.Assembly(temporary), phases, threshold_px=config.person_threshold_px, recovered=bool(sessions),
        check_unit=config.calibration_unit == "auto" and not sessions,
        labels={"subject": np.dtype(f"<U{len(f'rig{len(rig_index) - 1}')}"),
                "recording": np.dtype(f"<U{max(len(recording.name) for recording in recordings)}")},
    )  # fmt: skip
    try:
        preparation.run(parts)
    except BaseException:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)
        raise
    finally:
        phases.close()
    for summary, recording in zip(preparation.summaries, recordings):
        summary["cameras"] = [camera for camera in camera_order if camera in recording.cameras]
    meta = {
        "camera_names": camera_order,
        "layout": next(iter(layouts.values())),
        "recordings": preparation.summaries,
        "ground_truth_seen": preparation.ground_truth_seen,
        "warnings": preparation.warnings,
        "sessions": [session.summary() for session in sessions],
        "rigs": {field: np.stack([np.asarray(getattr(c.cameras, field), np.float32) for c in rigs.calibrations]).tolist() for field in ("K", "R", "t")},
        "inputs": inputs,
    }
    prepared = cache.finish(cache_dir, temporary, cache_key, preparation.assembly, meta, sessions)
    note = "" if prepared.folder is None else f"; {cache.size_note(cache_dir)}"
    log.info("%d recordings (%d instants) %s in %.1f s%s", len(recordings), len(prepared.arrays["frame"]), prepared.how, time.perf_counter() - started, note)
    return prepared


def _aligned(
    config: RigProjectConfig,
    recordings: Sequence[Recording],
    calibrations: Mapping[str, RigCalibration | None],
    camera_order: Sequence[str],
    given: dict[tuple[str, str], int],
    phases: Phases,
    layouts: dict[str, str],
) -> Iterator[Aligned]:
    """Each recording read, on one time axis at every instant, one at a time, with its rig (`calibrations`) and
    its offsets (`given` by --data.frame-offsets, or estimated with --data.sync auto); `layouts` collects each
    recording's layout."""
    parsed = cache_folder(config) / PARSED
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


def recorded_settings(config: RigProjectConfig, layout: str) -> dict:
    """The settings a run records of its project (`RunRecord.project`): every field but the recordings and
    the split, JSON-ready, with the layout the loader resolved."""
    settings = {field.name: getattr(config, field.name) for field in dataclasses.fields(config) if field.name not in _NOT_RECORDED}
    settings["skeleton"] = layout
    return {name: str(value) if isinstance(value, pathlib.Path) else list(value) if isinstance(value, tuple) else value for name, value in settings.items()}


def with_recorded_settings(config: RigProjectConfig, recorded: dict, source: str) -> tuple[RigProjectConfig, list[str]]:
    """`config` with each field left at its default taken from the run's recorded settings; and one line for
    each field given that differs from the record (the given value is used)."""
    defaults, changes, notes = RigProjectConfig(), {}, []
    for field in dataclasses.fields(config):
        if field.name not in recorded or field.name in _NOT_RECORDED:
            continue
        value = recorded[field.name]
        if isinstance(value, list):
            value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
        if field.name in ("root", "calibration", "cache_dir") and value is not None:
            value = pathlib.Path(value)
        given = getattr(config, field.name)
        if given == getattr(defaults, field.name):
            changes[field.name] = value
        elif given != value:
            flag = "--data." + field.name.replace("_", "-")
            notes.append(f"{flag} {given} differs from the run's {value} ({source}): using {given}")
    return dataclasses.replace(config, **changes), notes
