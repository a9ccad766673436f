"""pytest plugin for benchmarks/suite_time.py (not loaded otherwise): per test, its wall time, the time spent in
each kernel's first launch (its compile, or its load from Taichi's offline cache) and in ti.init, and how many
times Taichi was started, and each kernel's first launches by the kernel's name. One JSON line per test into
$SUITE_TIME_OUT/<pid>.jsonl."""
import json
import os
import time

import pytest

_acc = {"compile": 0.0, "inits": 0, "kernels": {}}
_seen = set()


def _install():
    import taichi as ti
    from taichi.lang import kernel_impl

    launch = kernel_impl.Kernel.launch_kernel

    def timed_launch(self, t_kernel, *args):
        if id(t_kernel) in _seen:
            return launch(self, t_kernel, *args)
        t = time.perf_counter()
        try:
            return launch(self, t_kernel, *args)
        finally:
            dt = time.perf_counter() - t
            _acc["compile"] += dt
            _acc["kernels"].setdefault(self.func.__name__, []).append(round(dt, 4))
            _seen.add(id(t_kernel))

    init = ti.init

    def timed_init(*args, **kwargs):
        t = time.perf_counter()
        try:
            return init(*args, **kwargs)
        finally:
            _acc["compile"] += time.perf_counter() - t
            _acc["inits"] += 1

    kernel_impl.Kernel.launch_kernel, ti.init = timed_launch, timed_init


_install()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    c0, i0, t0 = _acc["compile"], _acc["inits"], time.perf_counter()
    _acc["kernels"] = {}
    yield
    row = dict(test=item.nodeid, seconds=time.perf_counter() - t0, compile_s=_acc["compile"] - c0,
               inits=_acc["inits"] - i0, kernels=_acc["kernels"])
    with open(os.path.join(os.environ["SUITE_TIME_OUT"], f"{os.getpid()}.jsonl"), "a") as out:
        out.write(json.dumps(row) + "\n")
