"""RecentRows: the last rows of a stream as an array, exactly what a bounded deque held."""

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from node.runtime.rows import RecentRows

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=200, deadline=None)
@given(maxlen=st.integers(0, 40), block=st.integers(1, 17), width=st.integers(1, 4),
       data=st.data())
def test_the_rows_are_a_bounded_deques_to_the_last_bit(maxlen, block, width, data):
    rows = RecentRows(maxlen, block)
    reference: deque = deque(maxlen=maxlen)
    for op in data.draw(st.lists(st.one_of(st.just("clear"), st.tuples(*[FLOATS] * width)), max_size=120)):
        if op == "clear":
            rows.clear()
            reference.clear()
        else:
            rows.push(op)
            reference.append(op)
        assert len(rows) == len(reference) and bool(rows) == bool(reference)
        if reference:
            got, want = rows.array(), np.asarray(reference)
            assert got.shape == want.shape and got.dtype == np.float64
            assert got.tobytes() == want.tobytes()  # NaN, -0.0 and all, bit for bit


def test_memory_is_bounded_by_maxlen_and_one_block():
    rows = RecentRows(maxlen=50, block=8)
    for i in range(10_000):
        rows.push((float(i),))
    assert len(rows._blocks) * rows.block <= 50 + rows.block and len(rows._open) < rows.block
    assert rows.array()[:, 0].tolist() == [float(i) for i in range(9_950, 10_000)]


@pytest.mark.parametrize("maxlen, block", [(-1, 4), (4, 0)])
def test_a_bad_size_is_refused(maxlen, block):
    with pytest.raises(ValueError, match="maxlen"):
        RecentRows(maxlen, block)
