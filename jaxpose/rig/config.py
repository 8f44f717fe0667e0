"""A rig project's settings (`RigProjectConfig`, the --data flags of `experiments.rig` and
`jaxpose.reconstruct`), and the part of them a run records for the commands that use it.

The fields fall in three kinds: where the project and its cache are (`root`, `cache_dir`); the split into
training and validation parts (`SPLIT_FIELDS`: row selections made after loading, `jaxpose.rig.split`);
and everything else, which changes the prepared arrays (the cache's key: `jaxpose.rig.project`) and is
what a run records (`recorded_settings`: the commands that use the run take it as their defaults, and
say where a flag given differs, `differences`).
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Literal

from jaxpose.formats.rig_cameras import CalibrationUnit
from jaxpose.rig.people import DEFAULT_THRESHOLD_PX

CACHE_DIR = ".jaxpose_cache"
"""A project's cache folder in the project folder, where --data.cache-dir names none."""
SPLIT_FIELDS = ("validation_recordings", "validation_fraction", "train_stride", "validation_stride")
"""The fields of a training split: row selections of the prepared instants (`jaxpose.rig.split`), not part
of the cache's key (a reconstruction takes every instant of every recording)."""
NOT_PREPARED = ("root", "cache_dir", *SPLIT_FIELDS)
"""The fields that change no prepared array: where the project and its cache are, and the split."""
_NOT_RECORDED = ("recordings", *SPLIT_FIELDS)  # which recordings a command reads is its own choice
_PATHS = ("root", "calibration", "cache_dir")


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
    people: int | None = None
    """How many people the recordings hold, where you know it: no more tracks than that are started, and a
    person beyond them goes to the unseen track of the closest limb lengths (`jaxpose.rig.tracks`); None: as
    many as the views agree on."""
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
        if self.people is not None and self.people < 1:
            raise ValueError(f"--data.people is how many people the recordings hold (at least 1), got {self.people}")

    def resolved(self) -> RigProjectConfig:
        """The same settings with the paths absolute and resolved, as the commands take them: the project's
        cache key and a run's record then name one project however the command line named it."""
        return dataclasses.replace(self, **{name: getattr(self, name).resolve() for name in _PATHS if getattr(self, name) is not None})

    @property
    def cache(self) -> pathlib.Path:
        """The project's cache: --data.cache-dir, else PROJECT/.jaxpose_cache."""
        return self.cache_dir if self.cache_dir is not None else self.root / CACHE_DIR


def recorded_settings(config: RigProjectConfig, layout: str) -> RigProjectConfig:
    """The settings a run records of its project (`RunRecord.project`), and the defaults of the commands that
    use the run: every field but the recordings and the split (left at their defaults: a command's own choice),
    with the layout the loader resolved and the paths absolute and resolved (a run used from another working
    directory, or naming the project by another path, reads the same project)."""
    defaults = RigProjectConfig()
    unrecorded = {name: getattr(defaults, name) for name in _NOT_RECORDED}
    return dataclasses.replace(config.resolved(), skeleton=layout, **unrecorded)


def differences(given: RigProjectConfig, trained: RigProjectConfig) -> list[str]:
    """One line per setting the command line gives that differs from the run's (the given value is used)."""
    return [
        f"--data.{field.name.replace('_', '-')} {getattr(given, field.name)} given; the run was trained with {getattr(trained, field.name)}"
        for field in dataclasses.fields(given)
        if field.name not in _NOT_RECORDED and getattr(given, field.name) != getattr(trained, field.name)
    ]

