"""The presets: the real data sets' development protocol and a user's rig derive from one named recipe
(`cpu_recipe`), not from each other; their --help lines are made from their configs."""

from __future__ import annotations

import dataclasses

import pytest

from experiments import h36m, humaneva, rig, synthetic
from jaxpose.training.experiment import cpu_recipe, recipe_summary

ALL = {f"{module.__name__}.{name}": preset for module in (h36m, humaneva, rig, synthetic) for name, preset in module.PRESETS.items()}


def test_the_rig_and_development_presets_are_the_cpu_recipe_not_diffs_of_a_benchmark_preset():
    for preset in (h36m.CPU, h36m.DEV, rig.CPU):
        recipe = cpu_recipe(preset.data, warmup_steps=preset.optimizer.warmup_steps, run_dir=str(preset.run.run_dir),
                            max_samples=preset.train.max_samples, drop=preset.train.augment.drop, eval_every=preset.train.eval_every)  # fmt: skip
        assert dataclasses.replace(preset, run=recipe.run) == recipe
    # The rig's differences from the benchmark preset are its own: its budget, its input augmentation, its warm-up.
    assert (rig.CPU.train.max_samples, rig.CPU.train.augment.drop, h36m.CPU.train.max_samples, h36m.CPU.train.augment.drop) == (rig.RIG_SAMPLES, 0.1, 0, 0.0)


@pytest.mark.parametrize("name", sorted(ALL))
def test_a_presets_help_line_says_what_its_config_holds(name):
    preset = ALL[name]
    text = recipe_summary(preset)
    assert text.startswith(f"width-{preset.model.width} lifter of {preset.model.stages} stage")
    assert f"batch {preset.train.batch_size}," in text and f"{preset.pseudo_labels.method} pseudo-labels" in text
    assert (f"at most {preset.train.max_samples / 1e6:.1f}M samples" in text) == bool(preset.train.max_samples)
    changed = dataclasses.replace(preset, model=dataclasses.replace(preset.model, width=preset.model.width * 2))
    assert recipe_summary(changed) != text
