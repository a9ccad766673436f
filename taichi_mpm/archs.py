"""Which Taichi backend a run gets (`arch`): the GPU backends this machine has and what `auto` resolves to. Its own
module because the size estimate (budget.py) needs the answer as well as the solver, which imports budget.

Physics code only: no CLI, rendering or file I/O here.
"""
import taichi as ti

from .errors import ConfigError

GPU_ARCHS = ("cuda", "vulkan", "metal")


def available_archs() -> list[str]:
    """cpu and the GPU backends Taichi finds. Taichi's own `ti.gpu` list also probes OpenGL/GLES, which crashes
    the process (segmentation fault) on headless machines without a GL driver, so those are never probed."""
    from taichi.lang.misc import is_arch_supported

    ti.set_logging_level(ti.ERROR)  # no "libcuda.so not found" warning on machines without CUDA
    return [name for name in GPU_ARCHS if is_arch_supported(getattr(ti, name))] + ["cpu"]


def resolve_arch(arch: str) -> str:
    """`auto` -> the first of cuda, vulkan, metal that Taichi finds, else cpu. An arch named explicitly that
    this machine lacks is a ConfigError (Taichi itself would fall back to the CPU without a word)."""
    if arch == "cpu":
        return arch
    found = available_archs()
    if arch == "auto":
        return found[0]
    if arch not in found:
        raise ConfigError(f"arch {arch} is not available on this machine (available: {', '.join(found)}); "
                          "use arch: auto or cpu", key="arch")
    return arch
