"""Running a jitted function over many rows in chunks of one fixed size.

A jitted function compiles once per input shape.  Feeding it the rows of a large array in chunks
of one size, the last chunk padded by repeating its last row, keeps it to one compilation and
bounds the memory of one call, whatever the number of rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np


def map_in_chunks(fn: Callable[..., Any], arrays: Sequence[np.ndarray], chunk_size: int) -> Any:
    """`fn(*rows)` over fixed-size row chunks of `arrays` (equal leading lengths), unpadded and joined.

    `fn` returns a pytree of arrays whose leading axis is the chunk's rows; the result is the same
    pytree of numpy arrays over all rows.  Rows are independent: padding never changes a real row.
    """
    count = len(arrays[0])
    if count == 0 or any(len(a) != count for a in arrays):
        raise ValueError(f"map_in_chunks: expected arrays of one non-zero length, got lengths {[len(a) for a in arrays]}")
    size = max(1, min(chunk_size, count))
    pieces = []
    for start in range(0, count, size):
        rows = np.minimum(np.arange(start, start + size), count - 1)
        kept = min(size, count - start)
        pieces.append(jax.tree.map(lambda x, kept=kept: np.asarray(x)[:kept], fn(*(a[rows] for a in arrays))))
    return pieces[0] if len(pieces) == 1 else jax.tree.map(lambda *parts: np.concatenate(parts), *pieces)
