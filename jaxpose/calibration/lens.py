"""The lens of every camera in the bundle adjustment: which intrinsics are free, where they start,
their priors, and what the adjustment made of them.

One camera's lens is seven numbers, `INTRINSICS`: the focal length (square pixels, fx = fy up to
the given aspect), the principal point and OpenCV's radial (k1, k2) and tangential (p1, p2)
distortion; k3 stays where it starts (0 when unknown).  The adjustment works on offsets from the
starting lens, theta f64[C, 7], each of order one over its plausible range:

    log(f / f0),  (cx - cx0) / f0,  (cy - cy0) / f0,  k1 - k1_0,  k2 - k2_0,  p1 - p1_0,  p2 - p2_0

A parameter the input gives is held (its mask is false); an unknown one is free under a Gaussian
prior around where cameras put it: the focal length near the image-size guess (wide), the principal
point near the image centre, the distortion near none.  The priors matter where the person's
detections say little: a distortion coefficient of a lens whose images the person never fills, a
principal point of a rig of two views.  After the adjustment a free parameter whose posterior 1-sigma
is still close to its prior's (`PRIOR_DOMINATED`) was not determined by the data; it is put back at its
prior mean, held there, and reported as such (`LensEstimate.state`).

Tangential distortion is off by default: to first order p1 and p2 displace a point by 2 p r^2-sized
amounts that, over the small part of the image a person covers, look like a principal-point offset
and a rotation, which the data already determine weakly (docs/calibration.md); and real lenses' p
are ~1e-4 to 1e-3, a displacement below the detector's noise.  `LensConfig.estimate_tangential` turns them on.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

INTRINSICS = ("focal", "cx", "cy", "k1", "k2", "p1", "p2")
UNITS = ("px", "px", "px", "", "", "", "")
# A free parameter whose posterior sigma is at least this share of its prior sigma was determined
# by the prior, not the data: the data carry less than a quarter of the prior's information
# (1 / 0.9^2 - 1 = 0.23).
PRIOR_DOMINATED = 0.9
HELD, ESTIMATED, AT_PRIOR = "held", "estimated", "prior"


@dataclasses.dataclass(frozen=True)
class LensConfig:
    """Which unknown intrinsics the bundle adjustment estimates, and their priors."""

    estimate_principal_point: bool = False
    """Estimate the principal points of cameras whose K the input does not give (else: the image
    centre).  Off by default: on wide-angle synthetic rigs the principal point traded against the
    camera's rotation (docs/calibration.md: 6.7 instead of 1.5 degrees)."""
    estimate_distortion: bool = False
    """Estimate OpenCV radial distortion (k1, k2) of cameras whose dist the input does not give (else:
    none).  Off by default: on wide-angle synthetic rigs whose person covers the image centre it did
    not improve on k = 0 (docs/calibration.md)."""
    estimate_tangential: bool = False
    """Estimate the tangential distortion (p1, p2) too, where distortion is estimated.  Off by default:
    over the part of the image a person covers it acts like a principal-point offset (module docstring)."""
    focal_log_sigma: float = 0.5
    """Prior 1-sigma of log(focal / image-size guess): 0.5 is a factor of 1.65 either way."""
    principal_point_sigma: float = 0.03
    """Prior 1-sigma of the principal point's offset from the image centre, as a share of the longer image side."""
    k1_sigma: float = 0.25
    """Prior 1-sigma of k1 around 0."""
    k2_sigma: float = 0.1
    """Prior 1-sigma of k2 around 0."""
    tangential_sigma: float = 0.002
    """Prior 1-sigma of p1 and p2 around 0."""

    def __post_init__(self):
        sigmas = (self.focal_log_sigma, self.principal_point_sigma, self.k1_sigma, self.k2_sigma, self.tangential_sigma)
        if min(sigmas) <= 0:
            raise ValueError(f"calibration lens prior sigmas must be positive, got {sigmas}")


@dataclasses.dataclass(frozen=True)
class LensSetup:
    """The bundle adjustment's view of the lenses (numpy): start, free mask, priors, all in theta units."""

    K: np.ndarray
    """f64[C, 3, 3] the starting intrinsics (the given ones or the image-size guess)."""
    dist: np.ndarray
    """f64[C, 5] the starting distortion (the given one, or zeros)."""
    model: str
    """The distortion model: the input's when given, else "opencv"."""
    free: np.ndarray
    """bool[C, 7] the parameters estimated."""
    prior_mean: np.ndarray
    """f64[C, 7] prior means in theta units (relative to the start): the given intrinsics, or the
    image-size guess (centred, no distortion)."""
    prior_sigma: np.ndarray
    """f64[C, 7] prior 1-sigmas in theta units (of the free parameters; 1 elsewhere, unused)."""

    @property
    def any_free(self) -> bool:
        return bool(self.free.any())


def lens_setup(
    K: np.ndarray | None, dist: np.ndarray | None, model: str, image_size: np.ndarray, estimate_focal: bool,
    config: LensConfig, focal_guess: float,
) -> LensSetup:  # fmt: skip
    """What is free and how it is held, from what the input gives (K [C, 3, 3] and dist [C, 5] or None)."""
    C = len(image_size)
    given_K = K is not None
    if K is None:  # square pixels, focal `focal_guess` x the longer side, centred
        K = np.tile(np.eye(3), (C, 1, 1))
        K[:, 0, 0] = K[:, 1, 1] = focal_guess * image_size.max(-1)
        K[:, :2, 2] = image_size / 2.0
    estimate_pp = config.estimate_principal_point and not given_K
    estimate_dist = config.estimate_distortion and dist is None
    free = np.zeros((C, 7), bool)
    free[:, 0] = estimate_focal
    free[:, 1:3] = estimate_pp
    free[:, 3:5] = estimate_dist
    free[:, 5:7] = estimate_dist and config.estimate_tangential
    f0 = np.asarray(K[:, 0, 0], np.float64)
    longer = image_size.max(-1).astype(np.float64)
    sigma = np.ones((C, 7))
    sigma[:, 0] = config.focal_log_sigma
    sigma[:, 1:3] = (config.principal_point_sigma * longer / f0)[:, None]
    sigma[:, 3], sigma[:, 4] = config.k1_sigma, config.k2_sigma
    sigma[:, 5:7] = config.tangential_sigma
    start_dist = np.zeros((C, 5)) if dist is None else np.asarray(dist, np.float64)
    return LensSetup(
        K=np.asarray(K, np.float64), dist=start_dist, model=model if dist is not None else "opencv", free=free,
        prior_mean=np.zeros((C, 7)), prior_sigma=sigma,
    )  # fmt: skip


def lens_from_theta(theta: jax.Array, K0: jax.Array, dist0: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(K [C, 3, 3], dist [C, 5]) of offsets theta [C, 7] from the start (K0, dist0); jittable."""
    f0 = K0[:, 0, 0]
    K = K0.at[:, :2, :2].multiply(jnp.exp(theta[:, 0])[:, None, None])
    K = K.at[:, 0, 2].add(f0 * theta[:, 1]).at[:, 1, 2].add(f0 * theta[:, 2])
    dist = dist0.at[:, :4].add(theta[:, 3:7])
    return K, dist


# Compiled once per shape: run op by op, `lens_from_theta` compiles a program for every operation.
_lens_from_theta_compiled = jax.jit(lens_from_theta)


def theta_in_units(theta: np.ndarray, K0: np.ndarray, dist0: np.ndarray) -> np.ndarray:
    """f64[C, 7] the lens in `INTRINSICS` units (focal and principal point px, distortion as is)."""
    K, dist = (np.asarray(a) for a in _lens_from_theta_compiled(theta, K0, dist0))
    return np.concatenate([K[:, :1, 0], K[:, :2, 2], dist[:, :4]], axis=1)


def sigma_in_units(sigma: np.ndarray, theta: np.ndarray, K0: np.ndarray) -> np.ndarray:
    """f64[C, 7] 1-sigmas in `INTRINSICS` units from 1-sigmas in theta units at theta (linearized)."""
    f0 = K0[:, 0, 0]
    scale = np.stack([f0 * np.exp(theta[:, 0]), f0, f0] + [np.ones_like(f0)] * 4, axis=1)
    return sigma * scale


@dataclasses.dataclass(frozen=True)
class LensEstimate:
    """Every camera's intrinsics after the adjustment, in `INTRINSICS` order and units."""

    value: np.ndarray
    """f64[C, 7] focal (px), cx, cy (px), k1, k2, p1, p2."""
    sigma: np.ndarray
    """f64[C, 7] 1-sigma: the posterior's for estimated parameters, the prior's for those left at the
    prior, 0 for held ones."""
    prior_mean: np.ndarray
    """f64[C, 7] the priors' means (the held value where held)."""
    prior_sigma: np.ndarray
    """f64[C, 7] the priors' 1-sigmas (0 where held)."""
    state: np.ndarray
    """str[C, 7]: "held" (at the input's value, or at the start when not estimated), "estimated", or "prior" (the data did not
    determine it beyond its prior: held at the prior mean)."""

    def summary(self, camera_names) -> str:
        """A markdown table: each camera's intrinsics with their 1-sigma and how they were obtained."""
        lines = ["| camera | " + " | ".join(f"{n} ({u})" if u else n for n, u in zip(INTRINSICS, UNITS)) + " |",
                 "|---" * (len(INTRINSICS) + 1) + "|"]  # fmt: skip
        for c, name in enumerate(camera_names):
            cells = []
            for i in range(len(INTRINSICS)):
                digits = 1 if i < 3 else 4
                value = f"{self.value[c, i]:.{digits}f}"
                state = self.state[c, i]
                cells.append(value if state == HELD else f"{value} ± {self.sigma[c, i]:.{digits}f}" + (" (prior)" if state == AT_PRIOR else ""))
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        return "\n".join(lines)
