"""The presets: the real data sets' development protocol and a user's rig derive from one named recipe
(`cpu_recipe`), not from each other; their --help lines are made from their configs."""

from __future__ import annotations

import dataclasses

import pytest

from experiments import h36m, humaneva, rig, synthetic
from jaxpose.training.config import RESCALED_LOSS, InputAugmentation, OptimizerConfig, PseudoLabelConfig
from jaxpose.training.experiment import TrainConfig, recipe_summary

ALL = {f"{module.__name__}.{name}": preset for module in (h36m, humaneva, rig, synthetic) for name, preset in module.PRESETS.items()}


def test_the_rig_and_development_presets_are_the_cpu_recipe_not_diffs_of_a_benchmark_preset():
    # The recipe as experiments/h36m.py documents it (its measurements), stated here rather than rebuilt from the
    # presets' own fields.
    for preset in (h36m.CPU, h36m.DEV, rig.CPU):
        model, train, loss, optimizer = preset.model, preset.train, preset.loss, preset.optimizer
        assert (model.width, model.stages, model.dropout_rate, model.temporal_window) == (512, 1, 0.1, 1)
        assert (train.batch_size, train.epochs, train.checkpoint_every) == (128, 70, 4000)
        assert dataclasses.replace(loss, label_robust_scale_mm=0.0) == dataclasses.replace(RESCALED_LOSS, label_robust_scale_mm=0.0)
        assert loss.label_robust_scale_mm == 50.0
        assert preset.pseudo_labels == PseudoLabelConfig(method="ransac")
        assert (optimizer.schedule, optimizer.learning_rate) == ("cosine", OptimizerConfig().learning_rate)
    # What each preset sets of its own: warm-up, sample cap, joints dropped, periodic evaluation.
    own = {
        name: (p.optimizer.warmup_steps, p.train.max_samples, p.train.augment.drop, p.train.eval_every)
        for name, p in (("h36m.CPU", h36m.CPU), ("h36m.DEV", h36m.DEV), ("rig.CPU", rig.CPU))
    }
    assert own == {"h36m.CPU": (1700, 0, 0.0, 0), "h36m.DEV": (150, 0, 0.0, 0), "rig.CPU": (150, 5_000_000, 0.1, 2000)}
    assert rig.RIG_SAMPLES == 5_000_000
    # Nothing else differs from the recipe's defaults.
    for preset in (h36m.CPU, h36m.DEV, rig.CPU):
        assert dataclasses.replace(preset.train, max_samples=0, augment=InputAugmentation(), eval_every=0) == TrainConfig(
            batch_size=128, epochs=70, checkpoint_every=4000
        )


@pytest.mark.parametrize("name", sorted(ALL))
def test_a_presets_help_line_says_what_its_config_holds(name):
    preset = ALL[name]
    text = recipe_summary(preset)
    assert text.startswith(f"width-{preset.model.width} lifter of {preset.model.stages} stage")
    assert f"batch {preset.train.batch_size}," in text and f"{preset.pseudo_labels.method} pseudo-labels" in text
    assert (f"at most {preset.train.max_samples / 1e6:.1f}M samples" in text) == bool(preset.train.max_samples)
    changed = dataclasses.replace(preset, model=dataclasses.replace(preset.model, width=preset.model.width * 2))
    assert recipe_summary(changed) != text
