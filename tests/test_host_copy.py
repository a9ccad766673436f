"""host_copy moves several particle fields in one kernel each way; what it writes and reads must be exactly what
Taichi's own from_numpy / to_numpy give (same casts, same dtypes), in any chunking."""
import numpy as np
import pytest
import taichi as ti

from taichi_mpm import host_copy
from taichi_mpm.backend import init_taichi


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_packed_copies_equal_taichis_own(precision, monkeypatch):
    monkeypatch.setattr(host_copy, "CHUNK", 3)   # 7 rows in chunks of 3: the offsets of every chunk count
    init_taichi("cpu", precision)
    n, rng = 7, np.random.default_rng(1)

    def fields():
        return [ti.Vector.field(2, float, n), ti.Matrix.field(2, 2, float, n), ti.field(float, n),
                ti.field(ti.u8, n), ti.field(ti.i32, n), ti.Matrix.field(1, 1, float, n)]

    arrays = [rng.normal(size=(n, 2)), rng.normal(size=(n, 2, 2)), rng.normal(size=n),
              np.arange(n, dtype=np.uint8) * 30, np.arange(n) * 7 - 20, rng.normal(size=(n, 1, 1))]
    ours, theirs = fields(), fields()
    host_copy.upload(list(zip(ours, arrays)))
    for f, a in zip(theirs, arrays):
        f.from_numpy(a)
    read = host_copy.download(ours)
    for mine, f, ref in zip(read, ours, theirs):
        expected = ref.to_numpy()
        assert np.array_equal(f.to_numpy(), expected)            # written as from_numpy writes
        assert mine.dtype == expected.dtype and np.array_equal(mine.reshape(expected.shape), expected)
    assert read[0].dtype == (np.float64 if precision == "f64" else np.float32)


def test_a_mismatched_array_is_refused_before_anything_is_written():
    init_taichi("cpu", "f64")
    x, v = ti.Vector.field(2, float, 4), ti.field(float, 4)
    with pytest.raises(ValueError, match="shape"):
        host_copy.upload([(v, np.ones(4)), (x, np.ones((4, 3)))])
    assert not v.to_numpy().any()
