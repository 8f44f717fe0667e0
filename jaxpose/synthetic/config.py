"""What the synthetic data set simulates (`SyntheticConfig`), and its independent random streams."""

from __future__ import annotations

import dataclasses
import enum

import numpy as np


@dataclasses.dataclass(frozen=True)
class SyntheticConfig:
    """What to simulate.  Lengths mm, image quantities px, rates are fractions in [0, 1]."""

    num_train_subjects: int = 5
    num_test_subjects: int = 2
    samples_per_subject: int = 8000  # instants per subject, split over sequences of the motion families
    num_views: int = 4  # any C >= 2
    fps: float = 10.0  # sampling rate of the generated sequences
    image_size: tuple[int, int] = (1000, 1000)  # (width, height)
    focal_length: float = 1150.0  # px, jittered a few % per camera
    camera_distance: tuple[float, float] = (4000.0, 6000.0)  # mm from the room centre
    camera_height: tuple[float, float] = (1200.0, 2000.0)  # mm
    capture_area: float = 4000.0  # mm, side of the square the subject moves in
    noise_sigma_scale: float = 1.0  # multiplies the per-joint detector sigma (3-8 px)
    outlier_rate: float = 0.02  # fraction of joint detections replaced by gross outliers
    swap_rate: float = 0.01  # fraction of view-detections with a left/right swap
    missing_rate: float = 0.01  # fraction of joint detections missing (confidence 0, coords 0)
    seed: int = 0
    sequence_length: int = 250  # nominal frames per sequence (a subject's samples split evenly)
    outlier_distance: tuple[float, float] = (30.0, 150.0)  # px, range of a gross outlier's displacement

    def __post_init__(self):
        if self.num_views < 2:
            raise ValueError(f"num_views must be >= 2 for multi-view geometry, got {self.num_views}")
        if self.num_train_subjects < 0 or self.num_test_subjects < 0 or self.num_subjects == 0:
            raise ValueError("need at least one subject and no negative subject counts")
        if self.samples_per_subject < 1 or self.sequence_length < 1 or self.fps <= 0:
            raise ValueError("samples_per_subject, sequence_length and fps must be positive")
        for name in ("outlier_rate", "swap_rate", "missing_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        # Cameras on a circle outside the capture square's corners keep every joint in front of them.
        if self.camera_distance[0] <= self.capture_area / np.sqrt(2.0) + 500.0:
            raise ValueError(
                f"camera_distance {self.camera_distance} must exceed the capture area's half diagonal"
                f" ({self.capture_area / np.sqrt(2.0):.0f} mm) by 500 mm so that no joint is behind a camera"
            )

    @property
    def num_subjects(self) -> int:
        return self.num_train_subjects + self.num_test_subjects


class Stream(enum.IntEnum):
    """Independent random streams: (seed, stream, subject) keys a generator, so one subject's
    motion, a rig or the detector can be regenerated alone."""

    ROOM = 0
    RIG = 1
    BODY = 2
    MOTION = 3
    DETECTOR = 4


def stream_rng(config: SyntheticConfig, stream: Stream, subject: int = 0) -> np.random.Generator:
    """The generator of `stream` for `subject` under `config.seed`."""
    return np.random.default_rng([config.seed, stream, subject])
