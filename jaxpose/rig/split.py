"""A prepared rig project split into training and validation parts, row selections of its instants (`split`),
or taken whole (`every_instant`, what a reconstruction reads).

The prepared project (`jaxpose.rig.cache.PreparedProject`, `jaxpose.rig.project.prepared_project`) holds every instant of
every recording, one recording after the other; a split takes, per recording, the whole recording as
validation where --data.validation-recordings names it, else its final --data.validation-fraction, then
every --data.train-stride-th / --data.validation-stride-th instant of each part (`split`).  Each part is
memory-mapped from the cache where there is one (`jaxpose.rig.cache.selected_rows`), and every instant is
its context: a temporal lifter's window is the neighbouring instants of the same recording.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.data import ground_truth
from jaxpose.data.dataset import FrameContext, MultiViewDataset, consecutive_spans
from jaxpose.data.samples import Samples
from jaxpose.layouts import lifting_skeleton
from jaxpose.rig import cache
from jaxpose.rig.cache import PreparedProject, RecordingSummary
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.recovered import RecoveredSession

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class RigProject:
    """A loaded project: the training and validation parts and how they were made."""

    train: MultiViewDataset
    validation: MultiViewDataset
    camera_names: tuple[str, ...]
    layout: str
    recordings: tuple[RecordingSummary, ...]
    ground_truth_joints: tuple[str, ...]
    """The lifting skeleton's joints that the ground truth has (empty without ground truth)."""
    sessions: tuple[RecoveredSession, ...] = ()
    """Without a calibration: the sessions and the rig recovered from each (`jaxpose.rig.recovered`)."""
    prepared: str = ""
    """How the prepared arrays were had: read from the cache, prepared and cached, or prepared in memory."""
    warnings: tuple[str, ...] = ()
    """What the checks of the calibrations found suspect (people of an unlikely size), for the report."""

    @property
    def recovered_calibration(self) -> object | None:
        """The `jaxpose.calibration.Calibration` recovered from the recordings of a project of one session."""
        return self.sessions[0].calibration if len(self.sessions) == 1 else None


@dataclasses.dataclass(frozen=True)
class ProjectInstants:
    """Every prepared instant of a project, recording after recording (what a reconstruction takes: no split),
    and what loading did to each recording."""

    instants: MultiViewDataset
    recordings: tuple[RecordingSummary, ...]
    prepared: str
    """How the prepared arrays were had (as `RigProject.prepared`)."""


def every_instant(prepared: PreparedProject, recordings: tuple[str, ...] = ()) -> ProjectInstants:
    """The prepared instants themselves as one data set (memory-mapped where the cache holds them): every
    recording's, or those of `recordings` (names the prepared project holds)."""
    arrays = prepared.arrays
    sequence = person_names(arrays["recording"], arrays["person"])
    spans = _spans(arrays, sequence)
    summaries = prepared.meta.recordings
    rows = np.arange(len(arrays["frame"]))
    if recordings:
        summaries = tuple(summary for summary in summaries if summary.name in recordings)
        rows = np.flatnonzero(np.isin(arrays["recording"], np.asarray(recordings)))
    instants = _dataset(prepared, spans, "every", rows, sequence)
    return ProjectInstants(instants, summaries, prepared.how)


def split(prepared: PreparedProject, config: RigProjectConfig) -> RigProject:
    """The training and validation parts of the prepared instants: per recording and person, the validation
    part is the whole recording where --data.validation-recordings names it, else the person's final
    --data.validation-fraction of instants; then every --data.train-stride-th / --data.validation-stride-th
    instant of the person in each part.  Each part's windows of frames are cut from every instant (its context)."""
    meta, arrays = prepared.meta, prepared.arrays
    held_out, sample = [], []
    for recording, person, start, stop in person_runs(arrays):
        out = _held_out(config, recording, stop - start)
        position = np.arange(stop - start)
        held_out.append(out)
        sample.append(np.where(out, position % config.validation_stride == 0, position % config.train_stride == 0))
    held_out, sample = np.concatenate(held_out), np.concatenate(sample)
    sequence = person_names(arrays["recording"], arrays["person"])
    spans = _spans(arrays, sequence)
    train = _dataset(prepared, spans, "train", np.flatnonzero(sample & ~held_out), sequence)
    validation = _dataset(prepared, spans, "validation", np.flatnonzero(sample & held_out), sequence)
    if train.samples.target3d is not None and not np.isfinite(train.samples.target3d).all():
        # Ground truth for only some joints or recordings serves evaluation, not the supervised twin.
        log.info("the ground truth does not cover every training instant and joint: no --supervision full")
        train = train.with_samples(target3d=None)
    return RigProject(
        train=train,
        validation=validation,
        camera_names=meta.camera_names,
        layout=meta.layout,
        recordings=meta.recordings,
        warnings=meta.warnings,
        ground_truth_joints=ground_truth.ground_truth_joint_names(validation),
        sessions=prepared.sessions,
        prepared=prepared.how,
    )


def person_runs(arrays) -> list[tuple[str, int, int, int]]:
    """(recording, person, first row, one-past-last row) of each person's rows, in row order (the rows of a
    recording person after person: `jaxpose.rig.tracked`)."""
    recording, person = np.asarray(arrays["recording"]), np.asarray(arrays["person"])
    starts = np.flatnonzero(np.r_[True, (recording[1:] != recording[:-1]) | (person[1:] != person[:-1])])
    stops = np.r_[starts[1:], len(recording)]
    return [(str(recording[a]), int(person[a]), int(a), int(b)) for a, b in zip(starts, stops)]


def person_names(recording: np.ndarray, person: np.ndarray) -> np.ndarray:
    """str[N]: each row's person as its files name it: the recording's name where it has one person, else
    ``<recording>.person<k>``."""
    recording, person = np.asarray(recording), np.asarray(person)
    if not (person > 1).any():  # one person in every recording: the names are the recordings'
        return recording
    names, inverse = np.unique(recording, return_inverse=True)
    most = np.zeros(len(names), np.int64)
    np.maximum.at(most, inverse, person)
    several = most[inverse] > 1
    suffixed = np.char.add(np.char.add(recording.astype(str), ".person"), person.astype(str))
    return np.where(several, suffixed, recording.astype(str))


def _spans(arrays, sequence: np.ndarray) -> np.ndarray:
    """Each row's stretch of consecutive frames of one recording and person (`sequence`, `person_names`)."""
    return consecutive_spans({"frame": arrays["frame"], "sequence": sequence})


def _dataset(prepared: PreparedProject, spans: np.ndarray, part: str, rows: np.ndarray, sequence: np.ndarray) -> MultiViewDataset:
    """The prepared instants `rows` as a data set (`jaxpose.rig.cache.selected_rows`), with every instant as
    its context (`spans`: each instant's stretch of consecutive frames).  Its labels: "recording", "person"
    (1, 2, ...) and "sequence" the person's name (`person_names`)."""
    meta, arrays = prepared.meta, prepared.arrays
    skeleton = lifting_skeleton(meta.layout)
    rigs = Cameras(**meta.rigs)
    selected = cache.selected_rows(prepared.folder, part, arrays, rows)
    samples = Samples(
        keypoints2d=selected["keypoints2d"], confidence=selected["confidence"], rig_index=selected["rig_index"], target3d=selected.get("target3d"),
        labels={"subject": selected["subject"], "recording": selected["recording"], "sequence": sequence[rows], "frame": selected["frame"],
                "person": selected["person"]},
        context_row=rows.astype(np.int32), context_span=spans[rows],
    )  # fmt: skip
    return MultiViewDataset(skeleton, rigs, samples, context=FrameContext(arrays["keypoints2d"], arrays["confidence"]))


def _held_out(config: RigProjectConfig, recording: str, instants: int) -> np.ndarray:
    """bool[instants]: which of a recording's instants validate (--data.validation-recordings, else the
    final --data.validation-fraction of each recording)."""
    if recording in config.validation_recordings:
        return np.ones(instants, bool)
    if config.validation_recordings:
        return np.zeros(instants, bool)
    return np.arange(instants) >= int(round(instants * (1.0 - config.validation_fraction)))
