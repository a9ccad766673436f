"""jit.py: cached source excerpts and source lines give Taichi exactly the text it would build itself."""
import pytest
import taichi as ti

from taichi_mpm import jit


def test_cached_source_positions_equal_taichis_own(monkeypatch, cfg_factory):
    """Every excerpt the cache returns while a 2D scene's kernels are built equals the one Taichi formats (the
    same node visited through different inlined calls and unrolled loops included), and compile errors still name
    the right line."""
    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

    import taichi_mpm as tm

    jit.install()
    cached = ASTTransformerContext.get_pos_info
    original = cached._original
    seen = {"calls": 0}

    def checked(self, node):
        text = cached(self, node)
        assert text == original(self, node)
        seen["calls"] += 1
        return text

    monkeypatch.setattr(ASTTransformerContext, "get_pos_info", checked)
    sim = tm.Simulation(tm.load_config(cfg_factory(2, velocity=[0.5, 0.0])))
    sim.step()
    assert seen["calls"] > 1000      # the step's kernels went through the check

    @ti.func
    def broken(a):
        return a + not_defined  # noqa: F821 (the error under test)

    @ti.kernel
    def k() -> float:
        return broken(1.0)

    with pytest.raises(Exception) as e:
        k()
    assert "not_defined" in str(e.value) and "test_jit.py" in str(e.value)


def test_class_check_tells_class_kernels_from_free_ones():
    """The linecache-based class check answers as Taichi's getframeinfo one: a kernel and a func in a
    @ti.data_oriented class body are class members, free ones are not, and a class kernel still runs."""
    from taichi.lang import kernel_impl

    from taichi_mpm.solver import init_taichi

    init_taichi("cpu", "f64")
    assert getattr(kernel_impl._inside_class, "_cached", False)
    out = ti.field(float, ())

    @ti.data_oriented
    class Holder:
        @ti.func
        def twice(self, a):
            return 2.0 * a

        @ti.kernel
        def run(self):
            out[None] = self.twice(21.0)

    @ti.kernel
    def free():
        out[None] = 1.0

    assert Holder.run._is_classkernel and Holder.twice.func.classfunc
    assert not free._is_classkernel
    Holder().run()
    assert out[None] == 42.0
