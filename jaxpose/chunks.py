"""Running a jitted function over many rows in chunks of fixed sizes.

A jitted function compiles once per input shape.  Feeding it rows in chunks of one size, the last
chunk padded by repeating its last row, keeps it to one compilation and bounds the memory of one
call, whatever the number of rows.

- `ChunkedMap` / `map_over_parts`: the rows of many parts (a project's recordings, say) as one
  sequence, in chunks of exactly `chunk_size` rows, so that neither the number nor the lengths of the
  parts add a compilation, and a short part does not pay for a chunk of its own.  Each part's results
  come back as soon as its last row is through, and parts are added one by one (or produced lazily),
  so only the parts in flight are held.
- `map_in_chunks`: one set of rows, in chunks of the next power of two at least as large as the
  rows, at most `chunk_size`: a small input does not pay for a full chunk, and any sequence of
  calls compiles at most log2(chunk_size) + 1 times.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

import jax
import numpy as np


def chunk_rows(count: int, chunk_size: int) -> int:
    """Rows per call for `count` rows: the next power of two >= count, at most chunk_size."""
    return max(1, min(chunk_size, 1 << max(count - 1, 0).bit_length()))


def map_in_chunks(fn: Callable[..., Any], arrays: Sequence[np.ndarray], chunk_size: int) -> Any:
    """`fn(*rows)` over row chunks of `arrays` (equal leading lengths) of `chunk_rows` rows, unpadded and joined.

    `fn` returns a pytree of arrays whose leading axis is the chunk's rows; the result is the same
    pytree of numpy arrays over all rows.  Rows are independent: padding never changes a real row.
    """
    count = len(arrays[0])
    if count == 0 or any(len(a) != count for a in arrays):
        raise ValueError(f"map_in_chunks: expected arrays of one non-zero length, got lengths {[len(a) for a in arrays]}")
    return next(map_over_parts(fn, [arrays], chunk_rows(count, chunk_size)))


class ChunkedMap:
    """`fn(*rows)` over the rows of parts added one by one (each a sequence of arrays of equal leading
    lengths, the same number of arrays in every part), in chunks of exactly `chunk_size` rows: `add`
    and `flush` return the parts whose rows are all through, in order, as (tag, results), the results a
    pytree of numpy arrays over the part's rows (as `map_in_chunks` returns)."""

    def __init__(self, fn: Callable[..., Any], chunk_size: int):
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        self.fn, self.chunk_size = fn, chunk_size
        self._queue: list[tuple[dict, int, int]] = []  # (part, first row, rows) of the next chunk
        self._queued = 0
        self._waiting: list[dict] = []  # parts with rows not yet through, in order

    @property
    def pending(self) -> int:
        """Parts added whose results have not been returned."""
        return len(self._waiting)

    def add(self, arrays: Sequence[np.ndarray], tag: Any = None) -> list[tuple[Any, Any]]:
        count = len(arrays[0])
        if count == 0 or any(len(a) != count for a in arrays):
            raise ValueError(f"expected arrays of one non-zero length, got lengths {[len(a) for a in arrays]}")
        part = {"arrays": arrays, "tag": tag, "count": count, "done": 0, "result": None}
        self._waiting.append(part)
        finished = []
        start = 0
        while start < count:
            n = min(self.chunk_size - self._queued, count - start)
            self._queue.append((part, start, n))
            self._queued += n
            start += n
            if self._queued == self.chunk_size:
                self._run()
                finished += self._finished()
        return finished

    def flush(self) -> list[tuple[Any, Any]]:
        """Run the rows queued (padded to a full chunk) and return every part still waiting."""
        if self._queue:
            self._run()
        return self._finished()

    def _run(self) -> None:
        columns = zip(*(part["arrays"] for part, _, _ in self._queue))
        rows = [np.concatenate([a[start : start + n] for a, (_, start, n) in zip(column, self._queue)]) for column in columns]
        if self._queued < self.chunk_size:  # repeat the last row: one shape for every call
            rows = [np.concatenate([a, np.repeat(a[-1:], self.chunk_size - self._queued, axis=0)]) for a in rows]
        out = jax.tree.map(np.asarray, self.fn(*rows))
        offset = 0
        for part, _, n in self._queue:
            if part["result"] is None:  # filled in place, chunk by chunk: a part's results are held once
                part["result"] = jax.tree.map(lambda x, count=part["count"]: np.empty((count, *x.shape[1:]), x.dtype), out)
            done = part["done"]
            jax.tree.map(lambda whole, x, offset=offset, n=n, done=done: whole.__setitem__(slice(done, done + n), x[offset : offset + n]),
                         part["result"], out)  # fmt: skip
            part["done"] += n
            offset += n
        self._queue, self._queued = [], 0

    def _finished(self) -> list[tuple[Any, Any]]:
        finished = []
        while self._waiting and self._waiting[0]["done"] == self._waiting[0]["count"]:
            part = self._waiting.pop(0)
            finished.append((part["tag"], part["result"]))
        return finished


def map_over_parts(fn: Callable[..., Any], parts: Iterable[Sequence[np.ndarray]], chunk_size: int) -> Iterator[Any]:
    """`fn(*rows)` over the rows of every part, in chunks of exactly `chunk_size` rows (`ChunkedMap`);
    yields each part's results in order, as soon as its last row is through."""
    mapper = ChunkedMap(fn, chunk_size)
    for arrays in parts:
        for _, result in mapper.add(arrays):
            yield result
    for _, result in mapper.flush():
        yield result
