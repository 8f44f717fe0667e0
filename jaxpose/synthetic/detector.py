"""The simulated 2D detector: joint-dependent noise, gross outliers, left/right swaps, missing joints."""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.synthetic.config import SyntheticConfig
from jaxpose.skeleton import H36M_17

# Per-axis standard deviation (px) of the detector's Gaussian noise at noise_sigma_scale 1: the
# torso is easy to localize, distal joints (wrists, ankles) move fast and are small.
DETECTOR_SIGMA_PX: dict[str, float] = {
    "Hip": 3.0, "RHip": 3.5, "RKnee": 5.0, "RFoot": 8.0, "LHip": 3.5, "LKnee": 5.0, "LFoot": 8.0,
    "Spine": 3.0, "Thorax": 3.0, "Neck/Nose": 4.0, "Head": 4.5,
    "LShoulder": 4.0, "LElbow": 6.0, "LWrist": 8.0, "RShoulder": 4.0, "RElbow": 6.0, "RWrist": 8.0,
}  # fmt: skip


def detector_sigma(config: SyntheticConfig) -> np.ndarray:
    """f64[J] per-axis noise standard deviation (px) of each H36M_17 joint under `config`."""
    return config.noise_sigma_scale * np.array([DETECTOR_SIGMA_PX[name] for name in H36M_17.joint_names])


# Confidence = exp(-0.5 (error / (width * sigma))^2) + noise: ~0.85 for typical Gaussian errors,
# ~0 for gross outliers of the torso; a floor of half a pixel keeps noise-free configs finite.
_CONFIDENCE_WIDTH = 2.5
_CONFIDENCE_NOISE = 0.03
_MIN_CONFIDENCE = 0.01  # a detected joint keeps confidence > 0; exactly 0 means missing


@dataclasses.dataclass(frozen=True)
class SimulatedDetections:
    """Simulated detector output with the ground truth of what went wrong."""

    keypoints2d: np.ndarray  # f32[N, C, J, 2] pixels; 0 where missing
    confidence: np.ndarray  # f32[N, C, J] in [0, 1]; 0 exactly where missing
    outlier: np.ndarray  # bool[N, C, J] gross outlier (not missing)
    swapped: np.ndarray  # bool[N, C] the view's left/right joints were exchanged
    missing: np.ndarray  # bool[N, C, J]


def simulate_detector(rng: np.random.Generator, clean2d: np.ndarray, config: SyntheticConfig) -> SimulatedDetections:
    """Corrupt exact projections f[N, C, J, 2] (H36M_17 joints) as a 2D pose detector would.

    In order: whole-view left/right swaps (`swap_rate` of views), Gaussian noise of per-axis sigma
    `detector_sigma(config)`, gross outliers (`outlier_rate` of joints, displaced by a distance in
    `outlier_distance` in a random direction), missing joints (`missing_rate`; coordinates and
    confidence 0).  The root stays detected in at least two views of every sample, the minimum
    for triangulating it, so every sample remains usable.  Confidence falls with the error against
    the true joint, so swapped and outlying joints score low.
    """
    N, C, J, _ = clean2d.shape
    sigma = detector_sigma(config)
    swapped = rng.random((N, C)) < config.swap_rate
    detected = np.array(clean2d, np.float64)
    detected[swapped] = detected[swapped][:, H36M_17.flip_permutation()]
    detected += rng.standard_normal((N, C, J, 2)) * sigma[:, None]
    outlier = rng.random((N, C, J)) < config.outlier_rate
    count = int(outlier.sum())
    distance = rng.uniform(*config.outlier_distance, count)
    direction = rng.uniform(0.0, 2.0 * np.pi, count)
    detected[outlier] += distance[:, None] * np.stack([np.cos(direction), np.sin(direction)], axis=-1)
    missing = rng.random((N, C, J)) < config.missing_rate
    root_missing = missing[:, :, 0]
    shortfall = np.maximum(2 - (C - root_missing.sum(1)), 0)
    missing[:, :, 0] &= ~(root_missing & (np.cumsum(root_missing, axis=1) <= shortfall[:, None]))
    error = np.linalg.norm(detected - clean2d, axis=-1)
    width = _CONFIDENCE_WIDTH * np.maximum(sigma, 0.5)
    confidence = np.exp(-0.5 * (error / width) ** 2) + rng.normal(0.0, _CONFIDENCE_NOISE, (N, C, J))
    confidence = np.where(missing, 0.0, np.clip(confidence, _MIN_CONFIDENCE, 1.0))
    detected = np.where(missing[..., None], 0.0, detected)
    return SimulatedDetections(
        keypoints2d=detected.astype(np.float32),
        confidence=confidence.astype(np.float32),
        outlier=outlier & ~missing,
        swapped=swapped,
        missing=missing,
    )
