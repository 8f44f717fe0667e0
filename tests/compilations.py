"""Counting the programs JAX lowers and compiles while a block runs (`jax.monitoring` events)."""

from __future__ import annotations

import collections
import contextlib

import jax

# Lowering precedes every compilation, also one that JAX's persistent cache then serves from disk.
_COUNTED = {"/jax/core/compile/jaxpr_to_mlir_module_duration": "lowered", "/jax/core/compile/backend_compile_duration": "compiled"}
_counts = collections.Counter()
jax.monitoring.register_event_duration_secs_listener(lambda event, _, **__: _counts.update([_COUNTED[event]]) if event in _COUNTED else None)


@contextlib.contextmanager
def compilations():
    """{"lowered": n, "compiled": n} while the block runs."""
    start, found = dict(_counts), {}
    yield found
    found.update({name: _counts[name] - start.get(name, 0) for name in _COUNTED.values()})
