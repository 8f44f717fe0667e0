"""Orbax checkpoints of the train state, with recovery from a corrupt latest checkpoint.

Each step holds three items:

  state      the `TrainState`: all a run needs to resume (the data order and the dropout keys are
             pure functions of (seed, step))
  variables  its params and BatchNorm statistics alone, which is all inference restores
  lifter     JSON: the skeleton and `ModelConfig` (input normalisation included) of the network,
             so that a checkpoint can be lifted with by code that knows nothing of the run

Orbax writes each step into a temporary directory and renames it when complete, so a process
killed mid-save leaves no half-written step behind; a step that is present but unreadable (disk
corruption, a truncated file) is reported and the previous one is used.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from jaxpose.model import ModelConfig
from jaxpose.skeleton import Skeleton, get_skeleton
from jaxpose.training.step import TrainState

log = logging.getLogger(__name__)


class CheckpointError(RuntimeError):
    """No checkpoint under a directory could be restored."""


@dataclasses.dataclass(frozen=True)
class LifterRecord:
    """What rebuilds a checkpoint's network: saved with every step as the `lifter` item."""

    skeleton: Skeleton
    """The joint layout the network lifts (input and output)."""
    model: ModelConfig

    def to_json(self) -> dict[str, Any]:
        return {"skeleton": self.skeleton.name, "model": dataclasses.asdict(self.model)}

    @classmethod
    def from_json(cls, record: dict[str, Any]) -> LifterRecord:
        return cls(skeleton=get_skeleton(record["skeleton"]), model=ModelConfig(**record["model"]))

    def abstract_variables(self) -> dict[str, Any]:
        """Shapes and dtypes of the network's {"params", "batch_stats"}, computing nothing."""
        model = self.model.build(self.skeleton.num_joints)
        dummy = jnp.zeros(model.input_shape(1), jnp.float32)
        return jax.eval_shape(lambda: model.init(jax.random.key(0), dummy, train=False))


def checkpoint_manager(directory: str | pathlib.Path, max_to_keep: int = 3, asynchronous: bool = True) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(
        max_to_keep=max_to_keep, create=True, enable_async_checkpointing=asynchronous, cleanup_tmp_directories=True
    )
    return ocp.CheckpointManager(pathlib.Path(directory).absolute(), options=options)


def save(manager: ocp.CheckpointManager, state: TrainState, lifter: LifterRecord) -> None:
    """Start saving `state` at its step, with its variables and `lifter` as separate items
    (asynchronous; `manager.wait_until_finished()` to block)."""
    step = int(jax.device_get(state.step))
    if step in manager.all_steps():
        return
    items = ocp.args.Composite(
        state=ocp.args.StandardSave(state),
        variables=ocp.args.StandardSave(state.variables),
        lifter=ocp.args.JsonSave(lifter.to_json()),
    )
    manager.save(step, args=items)


_Restored = TypeVar("_Restored")


def _newest_readable(
    manager: ocp.CheckpointManager, restore_step: Callable[[int], _Restored], discard_unreadable: bool = False
) -> _Restored | None:
    """`restore_step` of the newest step it succeeds on; None when there is no step.

    A step it fails on is reported with a warning and the next older one tried; if it fails on every
    step, raises `CheckpointError`.  discard_unreadable: see `restore_latest`.
    """
    failures = []
    for step in sorted(manager.all_steps(), reverse=True):
        try:
            restored = restore_step(step)
        except Exception as error:  # noqa: BLE001 - any failure to read means "try the previous one"
            message = f"checkpoint step {step} in {manager.directory} is unreadable ({type(error).__name__}: {error})"
            warnings.warn(message + "; falling back to the previous checkpoint", stacklevel=3)
            failures.append((step, message))
            continue
        if discard_unreadable:
            for bad_step, _ in failures:
                manager.delete(bad_step)
                log.warning("deleted unreadable checkpoint step %d (training replays it from step %d)", bad_step, step)
        return restored
    if not failures:
        return None
    raise CheckpointError("no readable checkpoint:\n  " + "\n  ".join(message for _, message in failures))


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
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)

    def restore_state(step: int) -> TrainState:
        return manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))["state"]

    return _newest_readable(manager, restore_state, discard_unreadable)


def _shapes(tree) -> dict[str, tuple[int, ...]]:
    """{path: shape} of every leaf (arrays, ShapeDtypeStructs or Orbax array metadata)."""
    return {jax.tree_util.keystr(path): tuple(leaf.shape) for path, leaf in jax.tree_util.tree_leaves_with_path(tree)}


def restore_lifter(
    directory: str | pathlib.Path, sharding: jax.sharding.Sharding
) -> tuple[int, LifterRecord, dict[str, Any]] | None:
    """(step, lifter record, variables placed with `sharding`) of the newest readable checkpoint.

    Reads the `lifter` and `variables` items only, never the optimizer state, and writes nothing
    (no directory is created; the temporary directory of a save in progress, by a run training right
    now, is left alone).  None when the directory holds no checkpoint; `CheckpointError` when no
    step can be read, naming each step's fault (a step without a `lifter` item was written before
    checkpoints recorded their network).
    """
    options = ocp.CheckpointManagerOptions(create=False, cleanup_tmp_directories=False, enable_async_checkpointing=False)
    handlers = {name: ocp.StandardCheckpointHandler() for name in ("state", "variables")}
    handlers["lifter"] = ocp.JsonCheckpointHandler()

    def restore_step(step: int) -> tuple[int, LifterRecord, dict[str, Any]]:
        if not (pathlib.Path(manager.directory) / str(step) / "lifter").is_dir():
            raise CheckpointError(
                "it has no 'lifter' item (the skeleton and model config), so it was written before checkpoints"
                " recorded their network; train the run again to lift with it"
            )
        record = manager.restore(step, args=ocp.args.Composite(lifter=ocp.args.JsonRestore()))["lifter"]
        try:
            lifter = LifterRecord.from_json(record)
        except (KeyError, TypeError) as error:
            raise CheckpointError(f"its 'lifter' item {record} is not a skeleton and a ModelConfig ({error!r})") from None
        # Compared before restoring: a clear message, and Orbax is not left with a half-done read.
        abstract = lifter.abstract_variables()
        expected, saved = _shapes(abstract), _shapes(manager.item_metadata(step)["variables"])
        if saved != expected:
            differ = sorted(path for path in expected.keys() | saved.keys() if expected.get(path) != saved.get(path))
            raise CheckpointError(
                f"its variables do not match the network of its 'lifter' item {record}: {differ[0]} is"
                f" {saved.get(differ[0])} in the checkpoint, {expected.get(differ[0])} in that network"
                f" ({len(differ)} leaves differ)"
            )
        abstract = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, s.dtype, sharding=sharding), abstract)
        restored = manager.restore(step, args=ocp.args.Composite(variables=ocp.args.StandardRestore(abstract)))
        return step, lifter, restored["variables"]

    with ocp.CheckpointManager(pathlib.Path(directory).absolute(), options=options, item_handlers=handlers) as manager:
        return _newest_readable(manager, restore_step)
