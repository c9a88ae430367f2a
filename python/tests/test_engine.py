"""broadphase.Engine against the numpy oracle, frame by frame; the golden values; bad input."""

import threading
import zlib

import numpy as np
import pytest

import broadphase
from oracle import Oracle, as_set, sorted_pairs

ALGORITHMS = ["brute_force", "segmented_sap", "batch_sap", "dynamic_octree",
              "grid_segmented_sap", "grid_batch_sap", "grid_dense"]
DTYPES = ["float32", "float64", "int32"]


def random_boxes(rng, n, dims, dtype, side=40.0, width=3.0):
    lo = rng.uniform(0, side, size=(n, dims))
    hi = lo + rng.uniform(0.2, width, size=(n, dims))
    if dtype == "int32":
        return np.floor(lo).astype(np.int32), np.ceil(hi).astype(np.int32)
    return lo.astype(dtype), hi.astype(dtype)


def check_events(events, before, after):
    """The events are exactly the difference of the oracle's sets, in canonical order."""
    collides, uncollides = events
    assert collides.dtype == np.uint64 and collides.shape[1:] == (2,)
    np.testing.assert_array_equal(collides, sorted_pairs(after - before))
    np.testing.assert_array_equal(uncollides, sorted_pairs(before - after))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_random_scene_matches_oracle_frame_by_frame(algorithm, dims, dtype):
    rng = np.random.default_rng(zlib.crc32(f"{algorithm}-{dims}-{dtype}".encode()))
    engine = broadphase.Engine(algorithm, dims=dims, dtype=dtype)
    oracle = Oracle(dims)
    n = 120
    keys = rng.permutation(10 * n)[:n].astype(np.uint64) + np.uint64(2**40)
    lo, hi = random_boxes(rng, n, dims, dtype)
    # A third in a category that pairs only with category 1; a few static.
    category = np.where(np.arange(n) % 3 == 0, 2, 1).astype(np.uint64)
    mask = np.where(np.arange(n) % 3 == 0, np.uint64(1), np.uint64(2**64 - 1))
    static = np.arange(n) % 7 == 0
    engine.insert(keys, lo, hi, category=category, mask=mask, static=static)
    oracle.insert(keys, lo, hi, category, mask, static)
    before = set()
    for frame in range(12):
        events = engine.query()
        after = as_set(oracle.pairs())
        check_events(events, before, after)
        np.testing.assert_array_equal(engine.overlaps(), oracle.pairs())
        assert len(engine) == len(oracle.boxes)
        engine.validate()
        before = after
        live = np.array(sorted(oracle.boxes), np.uint64)
        moved = rng.choice(live, size=len(live) // 3, replace=False)
        mlo, mhi = random_boxes(rng, len(moved), dims, dtype)
        engine.update(moved, mlo, mhi)
        oracle.update(moved, mlo, mhi)
        gone = rng.choice(np.setdiff1d(live, moved), size=5, replace=False)
        engine.erase(gone)
        oracle.erase(gone)
        new = np.arange(5, dtype=np.uint64) + np.uint64(10**6 + 10 * frame)
        nlo, nhi = random_boxes(rng, 5, dims, dtype)
        engine.insert(new, nlo, nhi)
        oracle.insert(new, nlo, nhi)


def test_golden_scene_reproduces():
    g = broadphase.golden("S2a")
    scene = broadphase.Scene("S2a")
    engine = broadphase.Engine("grid_dense", dims=g["dims"])
    keys, lo, hi = scene.initial()
    engine.insert(keys, lo, hi)
    engine.query()
    assert len(engine.overlaps()) == g["pairs_frame0"]
    collides = uncollides = 0
    for _ in range(g["frames"]):
        f = scene.next_frame()
        engine.erase(f["erase"])
        engine.update(f["update_keys"], f["update_lo"], f["update_hi"])
        engine.insert(f["insert_keys"], f["insert_lo"], f["insert_hi"])
        c, u = engine.query()
        collides += len(c)
        uncollides += len(u)
    assert (collides, uncollides) == (g["collides"], g["uncollides"])
    assert len(engine.overlaps()) == g["pairs_end"]
    assert broadphase.set_hash(engine.overlaps()) == g["set_hash_end"]


def test_spot_query_and_keys_match_oracle():
    rng = np.random.default_rng(7)
    engine = broadphase.Engine("grid_dense", dims=3, dtype="float64")
    n = 300
    keys = np.arange(n, dtype=np.uint64)
    lo, hi = random_boxes(rng, n, 3, "float64")
    engine.insert(keys, lo, hi, category=np.uint64(4), mask=np.uint64(0))  # pairs with nothing
    engine.query()
    assert len(engine.overlaps()) == 0
    for _ in range(10):
        qlo = rng.uniform(0, 40, 3)
        qhi = qlo + rng.uniform(0, 15, 3)
        expect = keys[np.all((lo <= qhi) & (qlo <= hi), axis=1)]
        np.testing.assert_array_equal(engine.overlapping(qlo, qhi), expect)
    np.testing.assert_array_equal(engine.keys(), keys)


def test_refused_items_are_reported_and_the_rest_applied():
    engine = broadphase.Engine("grid_dense", dims=2)
    engine.insert([1, 2], [[0, 0], [5, 5]], [[1, 1], [6, 6]])
    nan = float("nan")
    with pytest.raises(broadphase.RefusedError) as info:
        engine.insert([3, 1, 4, 5, 3], [[0, 0], [0, 0], [nan, 0], [2, 2], [0, 0]],
                      [[1, 1], [1, 1], [1, 1], [1, 1], [1, 1]])
    err = info.value
    assert list(err.indices) == [1, 2, 3, 4]
    assert err.applied == 1
    assert "AlreadyExists" in err.reasons[0] and "AlreadyExists" in err.reasons[3]
    assert "InvalidArgument" in err.reasons[1] and "InvalidArgument" in err.reasons[2]
    assert "4 of 5 items refused" in str(err)
    c, u = engine.query()
    np.testing.assert_array_equal(c, [[1, 3]])
    with pytest.raises(broadphase.RefusedError) as info:
        engine.update([9, 2], [[0, 0], [0.5, 0.5]], [[1, 1], [2, 2]])
    assert list(info.value.indices) == [0] and "NotFound" in info.value.reasons[0]
    with pytest.raises(broadphase.RefusedError) as info:
        engine.erase([3, 3, 8])
    assert list(info.value.indices) == [1, 2]
    c, u = engine.query()
    np.testing.assert_array_equal(c, [[1, 2]])
    np.testing.assert_array_equal(u, [[1, 3]])
    np.testing.assert_array_equal(engine.keys(), [1, 2])


@pytest.mark.parametrize("call,kwargs,error,text", [
    ("insert", dict(keys=[1, 2], lo=[[0, 0, 0]], hi=[[1, 1, 1]]), ValueError, "expected shape (2, 3)"),
    ("insert", dict(keys=[[1]], lo=[[0, 0, 0]], hi=[[1, 1, 1]]), ValueError, "1-D array of keys"),
    ("insert", dict(keys=[1], lo=[[0, 0]], hi=[[1, 1]]), ValueError, "expected shape (1, 3)"),
    ("insert", dict(keys=[1.5], lo=[[0, 0, 0]], hi=[[1, 1, 1]]), TypeError, "unsigned 64-bit"),
    ("insert", dict(keys=[True], lo=[[0, 0, 0]], hi=[[1, 1, 1]]), TypeError, "unsigned 64-bit"),
    ("insert", dict(keys=[-3], lo=[[0, 0, 0]], hi=[[1, 1, 1]]), ValueError, "keys[0] is -3"),
    ("insert", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1, 1]], mask=-1), ValueError, "insert: mask[0] is -1"),
    ("insert", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1, 1]], static=[2]), ValueError, "static[0] is 2"),
    ("insert", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1, 1]], category=[1.0]), TypeError, "category"),
    ("insert", dict(keys=[1], lo=np.array([[True] * 3]), hi=[[1, 1, 1]]), TypeError, "real numbers"),
    ("insert", dict(keys=[1], lo=np.array([[1j] * 3]), hi=[[1, 1, 1]]), TypeError, "real numbers"),
    ("insert", dict(keys=[1], lo=[["a", "b", "c"]], hi=[[1, 1, 1]]), TypeError, "real numbers"),
    ("insert", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1, 1]], category=[1, 2]), ValueError,
     "expected 1 keys"),
    ("insert", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1, 1]], static=[0.5]), TypeError, "booleans"),
    ("overlapping", dict(lo=[0, 0], hi=[1, 1, 1]), ValueError, "expected shape (3,) or (1, 3)"),
    ("update", dict(keys=[1], lo=[[0, 0, 0]], hi=[[1, 1]]), ValueError, "update: hi"),
    ("erase", dict(keys=np.zeros((2, 2), np.uint64)), ValueError, "1-D array of keys"),
])
def test_bad_arrays_raise_and_apply_nothing(call, kwargs, error, text):
    engine = broadphase.Engine("grid_dense", dims=3)
    engine.insert([7], [[0, 0, 0]], [[1, 1, 1]])
    engine.query()
    with pytest.raises(error) as info:
        getattr(engine, call)(**kwargs)
    assert text in str(info.value)
    assert len(engine.query()) == 0
    np.testing.assert_array_equal(engine.keys(), [7])


def test_non_contiguous_and_other_dtypes_give_the_same_events():
    rng = np.random.default_rng(3)
    lo, hi = random_boxes(rng, 200, 3, "float64")
    keys = np.arange(400, dtype=np.int64)[::2]             # strided, signed
    both = np.concatenate([lo, hi], axis=1)                # lo and hi as column views
    a = broadphase.Engine("grid_dense", dims=3, dtype="float64")
    a.insert(keys, both[:, :3], both[:, 3:])
    b = broadphase.Engine("grid_dense", dims=3, dtype="float64")
    b.insert(np.ascontiguousarray(keys, np.uint64), lo.copy(), hi.copy())
    np.testing.assert_array_equal(a.query().collides, b.query().collides)
    f = broadphase.Engine("grid_dense", dims=3, dtype=np.float32)   # float64 rounded to float32
    f.insert(keys, lo, hi)
    g = broadphase.Engine("grid_dense", dims=3, dtype="float32")
    g.insert(keys, lo.astype(np.float32), hi.astype(np.float32))
    np.testing.assert_array_equal(f.query().collides, g.query().collides)


def test_int32_range_and_engine_arguments_are_checked():
    e = broadphase.Engine("grid_dense", dims=2, dtype="int32")
    with pytest.raises(ValueError, match="outside int32"):
        e.insert([1], [[0, 0]], [[1, 2**31]])
    with pytest.raises(ValueError, match="outside int32"):
        e.insert([1], [[-2**31 - 1, 0]], [[1, 1]])
    with pytest.raises(ValueError, match=r"hi\[0, 1\] is 4294967295: outside int32"):
        e.insert([1], np.zeros((1, 2), np.uint32), np.array([[1, 2**32 - 1]], np.uint32))
    e.insert([1], np.array([[-2**31, 0]]), np.array([[2**31 - 1, 5]], np.int64))   # the limits
    assert len(e.query()) == 0 and len(e) == 1
    with pytest.raises(TypeError, match="integer arrays"):
        e.insert([1], [[0.5, 0]], [[1, 1]])
    with pytest.raises(ValueError, match="no engine named"):
        broadphase.Engine("octree")
    with pytest.raises(ValueError, match="dims must be 2 or 3"):
        broadphase.Engine(dims=4)
    with pytest.raises(TypeError, match="not supported"):
        broadphase.Engine(dtype="int64")
    with pytest.raises(TypeError, match="has no option 'chunk_capacity'"):
        broadphase.Engine("grid_dense", chunk_capacity=16)
    with pytest.raises(ValueError, match="margin"):
        broadphase.Engine(margin=-1)
    with pytest.raises(ValueError, match="integer margin"):
        broadphase.Engine(dtype="int32", margin=1e12)
    with pytest.raises(TypeError, match="dtype None"):
        broadphase.Engine(dtype=None)
    for option, value, error in (("threads", 0, ValueError), ("threads", 10**6, ValueError),
                                 ("threads", -1, ValueError), ("threads", 1.5, TypeError),
                                 ("threads", True, TypeError), ("cell_size", -1, ValueError),
                                 ("cell_size", float("nan"), ValueError),
                                 ("objects_per_cell", 0, ValueError), ("threads", 2**70, ValueError)):
        with pytest.raises(error, match=f"option {option}"):
            broadphase.Engine("grid_dense", **{option: value})
    with pytest.raises(ValueError, match="power of two"):
        broadphase.Engine("segmented_sap", chunk_capacity=24)
    with pytest.raises(ValueError, match="global_sort_fraction"):
        broadphase.Engine("batch_sap", global_sort_fraction=2)
    e = broadphase.Engine("grid_segmented_sap", chunk_capacity=16, threads=2, cell_size=4.0)
    assert e.algorithm == "grid_segmented_sap" and e.stats()["threads"] == 2


def test_empty_batches_and_numpy_errors():
    e = broadphase.Engine("grid_dense", dims=3)
    e.insert([], [], [])                     # a Python [] is float64 to numpy: taken when empty
    e.erase([])
    e.update(np.zeros(0, np.uint64), np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(e.query()) == 0
    with np.errstate(over="raise"):          # numpy's own error, raised, not a crash
        with pytest.raises(FloatingPointError):
            e.insert([1], [[1e300, 0, 0]], [[1e301, 1, 1]])
    assert len(e.query()) == 0 and len(e) == 0
    with pytest.raises(ValueError, match="2\\*\\*32"):
        broadphase.set_hash([[1, 2**32]])


def test_margin_engine_reports_pairs_of_fattened_boxes():
    e = broadphase.Engine("grid_dense", dims=2, dtype="float64", margin=0.5)
    e.insert([1, 2], [[0, 0], [1.8, 0]], [[1, 1], [2.8, 1]])   # 0.8 apart: fattened, they meet
    np.testing.assert_array_equal(e.query().collides, [[1, 2]])
    assert e.margin == 0.5


def test_threads_share_an_engine():
    e = broadphase.Engine("grid_dense", dims=3)
    rng = np.random.default_rng(11)
    errors = []

    def work(base):
        try:
            for f in range(30):
                keys = np.arange(50, dtype=np.uint64) + np.uint64(base + 1000 * f)
                lo, hi = random_boxes(rng, 50, 3, "float32")
                e.insert(keys, lo, hi)
                e.query()
                e.erase(keys)
        except Exception as x:  # noqa: BLE001 - reported below
            errors.append(x)

    threads = [threading.Thread(target=work, args=(10**6 * t,)) for t in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    e.query()
    assert len(e) == 0
    e.validate()
