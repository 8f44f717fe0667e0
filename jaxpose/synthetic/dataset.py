"""The synthetic data set: every subject's motion, seen by its rig through the detector."""

from __future__ import annotations

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.data.samples import Samples
from jaxpose.synthetic.config import Stream, SyntheticConfig, stream_rng
from jaxpose.synthetic.detector import simulate_detector
from jaxpose.synthetic.motion import simulate_subject
from jaxpose.synthetic.rig import jitter_rig, make_rig, project_points
from jaxpose.skeleton import H36M_17


def generate(config: SyntheticConfig = SyntheticConfig()) -> MultiViewDataset:
    """The synthetic multi-view data set: all subjects, one rig per subject, noisy detections.

    Subjects "S1".."Sn": the first `num_train_subjects` have split "train", the rest "test".  Each
    subject's rig is the shared room (`make_rig`) with its own small calibration jitter.  Labels:
    subject, split, motion, sequence (unique over the data set), frame.  Every sample is a frame of a
    sequence in order, so the data set is its own `FrameContext` (windows for a temporal lifter).
    """
    room = make_rig(stream_rng(config, Stream.ROOM), config)
    keypoints, confidence, targets, rigs = [], [], [], []
    labels: dict[str, list[np.ndarray]] = {name: [] for name in ("subject", "split", "motion", "sequence", "frame")}
    sequence_offset = 0
    for subject in range(config.num_subjects):
        motion = simulate_subject(config, subject)
        rig = jitter_rig(stream_rng(config, Stream.RIG, subject), room)
        clean, depth = project_points(rig, motion.poses)
        if depth.min() <= 0.0:
            raise ValueError(f"subject {subject}: a joint lies behind a camera; enlarge camera_distance")
        detections = simulate_detector(stream_rng(config, Stream.DETECTOR, subject), clean, config)
        count = len(motion.poses)
        keypoints.append(detections.keypoints2d)
        confidence.append(detections.confidence)
        targets.append(motion.poses)
        rigs.append(rig)
        labels["subject"].append(np.full(count, f"S{subject + 1}"))
        labels["split"].append(np.full(count, "train" if subject < config.num_train_subjects else "test"))
        labels["motion"].append(motion.motion)
        labels["sequence"].append(motion.sequence + sequence_offset)
        labels["frame"].append(motion.frame)
        sequence_offset += int(motion.sequence.max()) + 1
    return MultiViewDataset(
        skeleton=H36M_17,
        rigs=Cameras(
            K=np.stack([r.K for r in rigs]), R=np.stack([r.R for r in rigs]), t=np.stack([r.t for r in rigs]), dist=None
        ),
        samples=Samples(
            keypoints2d=np.concatenate(keypoints),
            confidence=np.concatenate(confidence),
            rig_index=np.repeat(np.arange(config.num_subjects, dtype=np.int32), config.samples_per_subject),
            target3d=np.concatenate(targets),
            labels={name: np.concatenate(values) for name, values in labels.items()},
        ),
    ).with_own_context()
