"""`jaxpose.chunks`: fixed compiled shapes, and the same rows as one call over everything."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxpose.chunks import ChunkedMap, chunk_rows, map_in_chunks, map_over_parts


@pytest.mark.parametrize("count, chunk_size, rows", [(1, 4, 1), (7, 3, 3), (8, 4, 4), (9, 4, 4), (5, 100, 8), (3, 100, 4)])
def test_chunks_match_one_call_and_compile_once(count, chunk_size, rows):
    rng = np.random.default_rng(count)
    a, b = rng.normal(size=(count, 3)).astype(np.float32), rng.normal(size=(count,)).astype(np.float32)
    shapes = set()

    @jax.jit
    def fn(x, y):
        return {"sum": x.sum(-1) + y, "scaled": x * y[:, None]}

    def traced(x, y):
        shapes.add(x.shape)
        return fn(x, y)

    out = map_in_chunks(traced, (a, b), chunk_size)
    np.testing.assert_allclose(out["sum"], a.sum(-1) + b, rtol=1e-6)
    np.testing.assert_allclose(out["scaled"], a * b[:, None], rtol=1e-6)
    # The next power of two: a small input does not pay for a full chunk, and sizes stay few.
    assert shapes == {(rows, 3)} and chunk_rows(count, chunk_size) == rows


def test_tuple_outputs_and_none_leaves_pass_through():
    x = np.arange(10, dtype=np.float32)
    doubled, nothing = map_in_chunks(lambda v: (jnp.asarray(v) * 2, None), (x,), 4)
    np.testing.assert_array_equal(doubled, 2 * x)
    assert nothing is None


@pytest.mark.parametrize("arrays", [(np.zeros((0, 2)),), (np.zeros((3, 2)), np.zeros((4,)))])
def test_empty_or_unequal_rows_are_refused(arrays):
    with pytest.raises(ValueError, match="one non-zero length"):
        map_in_chunks(lambda *a: a[0], arrays, 2)


@given(st.lists(st.integers(1, 9), min_size=1, max_size=6), st.integers(1, 5))
def test_parts_run_through_one_shape_and_come_back_whole_and_in_order(lengths, chunk_size):
    """Many parts of any lengths: every call has exactly `chunk_size` rows, chunks span parts, and
    each part's results are its own rows, in order; a part is returned as soon as its rows are through."""
    parts = [(np.arange(n, dtype=np.float32) + 100 * i,) for i, n in enumerate(lengths)]
    calls = []

    def fn(x):
        calls.append(len(x))
        return {"twice": 2 * x}

    results = list(map_over_parts(fn, parts, chunk_size))
    assert set(calls) == {chunk_size} and len(calls) == -(-sum(lengths) // chunk_size)
    for (x,), result in zip(parts, results, strict=True):
        np.testing.assert_array_equal(result["twice"], 2 * x)
    mapper = ChunkedMap(fn, chunk_size)
    returned = [tag for i, (x,) in enumerate(parts) for tag, _ in mapper.add((x,), tag=i)]
    # Every part whose last row fell in a full chunk is back before the final flush.
    full = sum(lengths) // chunk_size * chunk_size
    assert returned == [i for i, end in enumerate(np.cumsum(lengths)) if end <= full]
    assert [tag for tag, _ in mapper.flush()] == [i for i in range(len(lengths)) if i not in returned]
