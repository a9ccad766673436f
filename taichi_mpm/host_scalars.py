"""The solver's runtime parameters and its per-step status: 0-D and small Taichi fields the kernels read, which the
host sets and reads through one kernel each way. A field's own accessors (`field[None] = x`) compile a kernel per
field and vector component on first use, ~30 ms each on a cold kernel cache: a plain 2D scene's parameters, status
flags and accumulators took 0.5 s of its first steps that way (13 accessors; docs/performance.md)."""

import numpy as np
import taichi as ti


class RuntimeParams:
    """What the host changes between steps without recompiling (set_gravity, set_flip_blend,
    set_stiffness_scale): gravity, the last step's gravity (the leapfrog kick's), FLIP's blend and each material's
    stiffness scale. `upload` writes all of them in one kernel, cast to the fields' precision as an accessor's
    write would."""

    def __init__(self, dim: int, materials: int):
        self.gravity = ti.Vector.field(dim, float, ())
        self.gravity_before = ti.Vector.field(dim, float, ())
        self.flip_blend = ti.field(float, ())
        self.stiffness = ti.field(float, materials)
        gravity, before, blend, stiffness = self.gravity, self.gravity_before, self.flip_blend, self.stiffness

        @ti.kernel
        def upload(g: ti.types.ndarray(), gb: ti.types.ndarray(), a: ti.f64, scales: ti.types.ndarray()):
            for k in ti.static(range(dim)):
                gravity[None][k] = ti.cast(g[k], float)
                before[None][k] = ti.cast(gb[k], float)
            blend[None] = ti.cast(a, float)
            for k in ti.static(range(materials)):
                stiffness[k] = ti.cast(scales[k], float)

        self._upload = upload

    def upload(self, gravity, gravity_before, flip_blend: float, stiffness):
        self._upload(np.ascontiguousarray(gravity, np.float64), np.ascontiguousarray(gravity_before, np.float64),
                     float(flip_blend), np.ascontiguousarray(stiffness, np.float64))


class StepStatus:
    """A step's failure code (the smallest particle x codes + cause any kernel found, `none` if none) and the
    largest squared particle speed G2P saw: reset before G2P (`clear` at the end of the kernel before it, or
    `reset`), read after the step (`values` returned by the step's last kernel, or `read`)."""

    def __init__(self, none: int):
        self.fail = ti.field(ti.i32, ())
        self.vmax2 = ti.field(float, ())
        fail, vmax2 = self.fail, self.vmax2

        @ti.func
        def clear():
            fail[None] = none
            vmax2[None] = 0.0

        @ti.func
        def values():
            return ti.Vector([ti.cast(fail[None], ti.f64), ti.cast(vmax2[None], ti.f64)])   # the code: < 2^31

        @ti.kernel
        def reset():
            clear()

        @ti.kernel
        def read() -> ti.types.vector(2, ti.f64):
            return values()

        self.clear, self.values = clear, values
        self.reset, self._read = reset, read

    def read(self) -> tuple[int, float]:
        """(failure code, largest squared speed)."""
        return self.decode(self._read())

    @staticmethod
    def decode(values) -> tuple[int, float]:
        """(failure code, largest squared speed) from `values` as a kernel returned them."""
        code, vmax2 = values
        return int(code), float(vmax2)
