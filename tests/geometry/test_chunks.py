"""`jaxpose.chunks.map_in_chunks`: one compiled shape, and the same rows as one call over everything."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.chunks import map_in_chunks


@pytest.mark.parametrize("count, chunk_size", [(1, 4), (7, 3), (8, 4), (9, 4), (5, 100)])
def test_chunks_match_one_call_and_compile_once(count, chunk_size):
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
    assert shapes == {(min(chunk_size, count), 3)}


def test_tuple_outputs_and_none_leaves_pass_through():
    x = np.arange(10, dtype=np.float32)
    doubled, nothing = map_in_chunks(lambda v: (jnp.asarray(v) * 2, None), (x,), 4)
    np.testing.assert_array_equal(doubled, 2 * x)
    assert nothing is None


@pytest.mark.parametrize("arrays", [(np.zeros((0, 2)),), (np.zeros((3, 2)), np.zeros((4,)))])
def test_empty_or_unequal_rows_are_refused(arrays):
    with pytest.raises(ValueError, match="one non-zero length"):
        map_in_chunks(lambda *a: a[0], arrays, 2)
