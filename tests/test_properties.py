"""Property-based tests (hypothesis) where examples miss cases: the keyed streams, the channels' counts, the
checkpoint's JSON-and-arrays split, and the public API's exports."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_array_equal

from dgtd import streams
from dgtd.channels.base import counted
from dgtd.channels.perfect import Counts
from dgtd.run.checkpoint import _join, _split

U64 = st.integers(0, 2**64 - 1)
U32 = st.integers(0, 2**32 - 1)


@settings(max_examples=60, deadline=None)
@given(key=U64, purpose=st.integers(0, 255), step=U64, entity=U32)
def test_a_number_depends_on_its_own_words_only_and_lies_in_the_unit_interval(key, purpose, step, entity):
    """Drawn alone or beside others (any batch, any order), a number is the same: what keyed streams promise."""
    alone = streams.uniforms(np.uint64(key), purpose, step, entity)
    batch = streams.uniforms(np.uint64(key), purpose, step, np.array([entity ^ 1, entity, entity ^ 2], np.uint64))
    for u, v in zip(alone, batch):
        assert float(u) == float(v[1])
        assert 0.0 <= float(u) < 1.0


@settings(max_examples=40, deadline=None)
@given(key=U64, step=st.integers(0, 2**40), ids=st.lists(st.integers(0, 10_000), min_size=1, max_size=20))
def test_singles_of_any_ids_are_those_of_each_id_alone(key, step, ids):
    """An entity's single number is the same whichever other entities are drawn with it (a rank's share of the edges,
    the whole network's)."""
    together = streams.singles(np.uint64(key), streams.EDGE_UP, step, np.array(ids))
    each = [float(streams.singles(np.uint64(key), streams.EDGE_UP, step, np.array([i]))[0]) for i in ids]
    assert_array_equal(together, each)


@settings(max_examples=40, deadline=None)
@given(
    arrivals=st.lists(st.lists(st.integers(0, 1_000), min_size=3, max_size=3), min_size=1, max_size=30),
    messages=st.integers(1, 4),
    numbers=st.integers(1, 64),
)
def test_counts_add_up_in_any_order_and_any_grouping(arrivals, messages, numbers):
    """The channel's counts are whole numbers: a block's arrivals added at once equal them added step by step, in
    any order (the compiled driver adds a block's, the NumPy channels a step's)."""
    start = Counts(np.zeros(3), np.zeros(3))
    stepwise = start
    for a in arrivals:
        stepwise = counted(stepwise, np.array(a, float), messages, numbers)
    backwards = start
    for a in reversed(arrivals):
        backwards = counted(backwards, np.array(a, float), messages, numbers)
    at_once = counted(start, np.array(arrivals, float).sum(axis=0), messages, numbers)
    for x in (backwards, at_once):
        assert_array_equal(x.messages, stepwise.messages)
        assert_array_equal(x.bits, stepwise.bits)
    assert_array_equal(stepwise.bits, stepwise.messages / messages * numbers * 64)


arrays = st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5).map(np.array)
snapshots = st.recursive(
    st.one_of(arrays, st.integers(-(2**62), 2**62), st.text(max_size=5), st.none()),
    lambda children: st.dictionaries(st.text("abc_", min_size=1, max_size=4), children, max_size=4),
    max_leaves=12,
)


@settings(max_examples=60, deadline=None)
@given(snap=st.dictionaries(st.text("kcs", min_size=1, max_size=3), snapshots, max_size=4))
def test_a_checkpoints_split_into_json_and_arrays_comes_back_bit_for_bit(snap):
    arrays_out: dict = {}
    meta = _split(snap, "s", arrays_out)
    back = _join(meta, arrays_out)

    def same(a, b):
        if isinstance(a, np.ndarray):
            assert isinstance(b, np.ndarray) and a.tobytes() == b.tobytes()
        elif isinstance(a, dict):
            assert set(a) == set(b)
            for k in a:
                same(a[k], b[k])
        else:
            assert a == b

    same(snap, back)


def test_the_public_api_exports_every_registered_algorithm():
    import dgtd
    from dgtd.algorithms import ALGORITHMS

    for cls in ALGORITHMS.values():
        assert getattr(dgtd, cls.__name__) is cls


@settings(max_examples=80, deadline=None)
@given(data=st.binary(max_size=300), prefix=st.sampled_from([b"", b"PK\x03\x04", b"{", b"\x93NUMPY", b"\xef\xbb\xbf"]))
def test_any_bytes_are_read_or_refused_in_one_line_never_a_traceback(tmp_path_factory, data, prefix):
    """Whatever a file holds, each reader returns or raises `DgtdInputError` (one line, naming the file)."""
    from dgtd.errors import DgtdInputError
    from dgtd.files import read_csv, read_json, read_npz

    path = tmp_path_factory.mktemp("f") / "x"
    path.write_bytes(prefix + data)
    for read in (read_npz, read_json, read_csv):
        try:
            read(path, "input", "fix it")
        except DgtdInputError as e:
            assert str(path) in str(e) and "\n" not in str(e)
