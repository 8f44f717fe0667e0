"""The library's training configuration dataclasses: losses, optimizer, pseudo-labels, input augmentation
(the lifter's own, `ModelConfig`, sits beside the network it builds in `jaxpose.model`).

Each builds what it describes (`OptimizerConfig.build`, `LossConfig.weights`;
`jaxpose.training.pseudo_labelling.label` takes a `PseudoLabelConfig`), so there is one place that turns
settings into objects.  They live in the library, not in `experiments/`, because a checkpoint must
be loadable (the model rebuilt from its saved config) by code that knows nothing of the
experiments.  The experiments' config tree (`jaxpose.training.experiment`) composes them with data, run and
parallelism settings.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

import jax
import jax.numpy as jnp
import optax
import tyro

from jaxpose import robust
from jaxpose.losses import LossWeights
from jaxpose.robust import PseudoLabelMethod


@dataclasses.dataclass(frozen=True)
class InputAugmentation:
    """The detector's failure modes, imposed on the lifter's INPUT during training (the losses still see
    the batch as given), so that a missing or wild joint changes little else of the prediction.

    Each view-pose gets at most one of them, with these probabilities (their sum must be <= 1); the
    joint (never the root) or the left/right pair is drawn uniformly.  Besides, a view may be seen in a
    mirror (`mirror`).  Drawn inside the jitted train step from the step's key
    (`jaxpose.training.step.augment_inputs`, `jaxpose.training.step.mirror_views`), so a resumed run draws what an
    uninterrupted one would.  All 0 (the default): the train step is exactly the one without it.
    """

    drop: float = 0.0
    """Probability that one joint is given as missing (confidence 0)."""
    displace: float = 0.0
    """Probability that one joint is moved in a random direction by a distance drawn uniformly up to
    `displace_scale` times the pose's median joint distance to the root (in the image)."""
    displace_scale: float = 4.0
    """See `displace`."""
    swap: float = 0.0
    """Probability that the two joints of one left/right pair trade places (a detector's left/right confusion)."""
    mirror: float = 0.0
    """Probability that a view is lifted from its mirror image (`jaxpose.flip.mirror_input`: the camera
    K diag(-1, 1, 1), left and right swapped) and its lift mirrored back (`jaxpose.flip.mirror_pose3d`)
    before every loss, so that the losses, the pseudo-labels and the multi-view geometry are those of the
    batch as given.  Drawn independently of the failures above.  A lifter that never saw mirror images
    lifts them badly, which is why test-time flip (--train.eval-flip) loses without it."""

    @property
    def imposes_failures(self) -> bool:
        return self.drop > 0 or self.displace > 0 or self.swap > 0

    def __post_init__(self):
        for name in ("drop", "displace", "swap", "mirror"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"input augmentation {name}: a probability in [0, 1], got {getattr(self, name)}")
        if self.drop + self.displace + self.swap > 1.0 + 1e-9:
            raise ValueError("input augmentation: drop + displace + swap must be <= 1 (one failure per view-pose)")


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """Loss weights (defaults: the paper's values; see `RESCALED_LOSS` for weights suited to this
    library's units), the output-triangulation schedule, and the supervision mode."""

    input_triangulation: float = 1.0
    """omega_1: pseudo-label (input triangulation) term, metres^2."""
    reprojection: float = 1.0
    """omega_2: re-projection term, focal-normalized image units."""
    consistency: float = 0.001
    """omega_3: cross-view consistency term, metres."""
    output_triangulation: float = 0.01
    """omega_4: output triangulation term, metres^2."""
    output_triangulation_start: float = 0.9
    """Fraction of training after which the output triangulation term is switched on (paper: last 10%)."""
    label_robust_scale_mm: float = 0.0
    """0: L_in and L_out are squared distances (the paper's L2).  > 0: a pseudo-Huber of this scale
    (mm): squared below it, linear above, so that gross pseudo-label errors pull no harder than
    moderate ones."""
    triangulation: Literal["svd", "eigh", "normal"] = "normal"
    """Solver of the output triangulation inside the train step (see jaxpose.triangulation): the
    closed-form "normal" is as accurate as the reference "svd" and ~10x faster on CPU."""
    supervision: Annotated[Literal["self", "full"], tyro.conf.arg(aliases=("--supervision",))] = "self"
    """"self": the four geometric losses; "full": L2 to the 3D ground truth (the supervised upper bound)."""

    def weights(self, output_triangulation_on: bool | jax.Array = True) -> LossWeights:
        """omega_1..omega_4 as the losses take them; omega_4 is 0 until `output_triangulation_on`
        (a traced bool inside the train step, so switching L_out on does not recompile it)."""
        return LossWeights(
            input_triangulation=self.input_triangulation,
            reprojection=self.reprojection,
            consistency=self.consistency,
            output_triangulation=jnp.where(output_triangulation_on, self.output_triangulation, 0.0),
        )


# The paper's weights rescaled to this library's units.  The terms are means over views and joints
# with 3D in metres and 2D in focal-normalised image units, and at unit weight their gradients with
# respect to the lifter output are within an order of magnitude of each other.  The paper's
# omega_3 = 0.001 and omega_4 = 0.01 were set for its own units: with ours, on the real Human3.6M
# development split, L_con and L_out end training with 0.2% and 0.3% of that gradient, i.e. they
# do nothing.  Ten times larger, they carry 2-3% each.  A hundred times larger (shares of
# 10-22%) cost 0.5-1.6 mm P-MPJPE there in three comparisons: both terms pull each view's
# prediction towards the views' consensus, which on real detections holds the same detector biases
# as the pseudo-labels, and away from L_in and L_proj.  L_out starts at half of training rather than
# in the last 10%: under a cosine schedule the learning rate in the last 10% is below 3% of its
# peak, too little for a new term to move the model; at the half it is still at 50%.
RESCALED_LOSS = LossConfig(consistency=0.01, output_triangulation=0.1, output_triangulation_start=0.5)


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
    """Adam with an optional learning-rate schedule."""

    learning_rate: float = 1e-3
    """Peak learning rate (paper: 1e-3)."""
    schedule: Literal["constant", "cosine"] = "constant"
    """"constant" (paper) or "cosine" decay to `final_learning_fraction` of the peak."""
    warmup_steps: int = 0
    """Linear warm-up steps before the schedule."""
    final_learning_fraction: float = 0.01
    """With "cosine": the final learning rate as a fraction of the peak."""
    gradient_clip_norm: float = 0.0
    """Clip the global gradient norm to this value (0 = no clipping)."""

    def learning_rate_schedule(self, total_steps: int) -> optax.Schedule:
        """The learning rate at each step of a run of `total_steps` steps."""
        if self.schedule == "constant":
            main = optax.constant_schedule(self.learning_rate)
        elif self.schedule == "cosine":
            main = optax.cosine_decay_schedule(
                self.learning_rate, max(total_steps - self.warmup_steps, 1), alpha=self.final_learning_fraction
            )
        else:
            raise ValueError(f"unknown learning-rate schedule {self.schedule!r}")
        if self.warmup_steps <= 0:
            return main
        warmup = optax.linear_schedule(0.0, self.learning_rate, self.warmup_steps)
        return optax.join_schedules([warmup, main], [self.warmup_steps])

    def build(self, total_steps: int) -> optax.GradientTransformation:
        """Adam on `learning_rate_schedule(total_steps)`, after gradient clipping when it is set."""
        adam = optax.adam(self.learning_rate_schedule(total_steps))
        if self.gradient_clip_norm > 0:
            return optax.chain(optax.clip_by_global_norm(self.gradient_clip_norm), adam)
        return adam


@dataclasses.dataclass(frozen=True)
class PseudoLabelConfig:
    """How the input triangulation (the pseudo-labels) is computed, once, before training
    (`jaxpose.training.pseudo_labelling.label`)."""

    method: PseudoLabelMethod = "svd"
    """"svd" (reference), "eigh" or "normal" (closed form): the DLT with views weighted by detector
    confidence; "unweighted": the paper's DLT, every detected view weight 1; "irls" / "ransac":
    robust, views that disagree with the others are down-weighted / rejected (see jaxpose.robust),
    and no loss takes a rejected detection as its target."""
    min_views: int = 2
    """A joint seen (confidence > 0) by fewer views (with "irls"/"ransac": fewer agreeing views)
    gets no pseudo-label (weight 0)."""
    threshold_px: float = robust.DEFAULT_THRESHOLD_PX
    """"irls"/"ransac": a view agrees with a joint's 3D point when it reprojects within this many pixels."""
    irls_iterations: int = robust.DEFAULT_IRLS_ITERATIONS
    """"irls": re-weighting rounds before the final solve on the agreeing views."""
    irls_scale_px: float = robust.DEFAULT_IRLS_SCALE_PX
    """"irls": scale of the Cauchy weight 1 / (1 + (residual / scale)^2), pixels."""
