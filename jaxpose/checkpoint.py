"""Orbax checkpoints of the train state, with recovery from a corrupt latest checkpoint.

The train state is all a run needs to resume: the data order and the dropout keys are pure
functions of (seed, step), so the checkpoint holds `TrainState` and nothing else.  Orbax writes
each step into a temporary directory and renames it when complete, so a process killed mid-save
leaves no half-written step behind; a step that is present but unreadable (disk corruption, a
truncated file) is reported and the previous one is used.
"""

from __future__ import annotations

import logging
import pathlib
import warnings

import jax
import orbax.checkpoint as ocp

from jaxpose.train import TrainState

log = logging.getLogger(__name__)


class CheckpointError(RuntimeError):
    """No checkpoint under a directory could be restored."""


def checkpoint_manager(directory: str | pathlib.Path, max_to_keep: int = 3, asynchronous: bool = True) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(
        max_to_keep=max_to_keep, create=True, enable_async_checkpointing=asynchronous, cleanup_tmp_directories=True
    )
    return ocp.CheckpointManager(pathlib.Path(directory).absolute(), options=options)


def save(manager: ocp.CheckpointManager, state: TrainState) -> None:
    """Start saving `state` at its step (asynchronous; `manager.wait_until_finished()` to block)."""
    step = int(jax.device_get(state.step))
    if step in manager.all_steps():
        return
    manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state)))


def restore_latest(
    manager: ocp.CheckpointManager, template: TrainState, discard_unreadable: bool = False
) -> TrainState | None:
    """The newest readable checkpoint as a `TrainState` shaped (and sharded) like `template`.

    Returns None when the directory holds no checkpoint.  An unreadable newest step is reported
    with a warning and the next older one tried; if none can be read, raises `CheckpointError`.

    discard_unreadable: delete the unreadable steps newer than the one restored.  A resuming run
    wants this: `save` skips a step that exists, so a corrupt step would otherwise never be
    rewritten (a run whose final checkpoint was corrupt would keep it after training again).  Only
    done once an older step was read with `template`, so a template that fits no step deletes nothing.
    """
    steps = sorted(manager.all_steps(), reverse=True)
    if not steps:
        return None
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
    failures = []
    for step in steps:
        try:
            restored = manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))
        except Exception as error:  # noqa: BLE001 - any failure to read means "try the previous one"
            message = f"checkpoint step {step} in {manager.directory} is unreadable ({type(error).__name__}: {error})"
            warnings.warn(message + "; falling back to the previous checkpoint", stacklevel=2)
            failures.append((step, message))
            continue
        if discard_unreadable:
            for bad_step, _ in failures:
                manager.delete(bad_step)
                log.warning("deleted unreadable checkpoint step %d (training replays it from step %d)", bad_step, step)
        return restored["state"]
    raise CheckpointError("no readable checkpoint:\n  " + "\n  ".join(message for _, message in failures))
