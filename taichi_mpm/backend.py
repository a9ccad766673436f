"""Which Taichi backend a simulation runs on, and with which grid (`arch:` in the config, `--arch`).

`choose(cfg)` decides and says why:
- `arch: cpu`: Taichi's x64 (or arm64) backend, which has every feature the solver uses (sparse grids, f64, i64).
- `arch: auto`: cuda where Taichi finds it (every feature, sparse grids included); else vulkan or metal when the
  device is a real GPU and can run the scene, with a dense grid, since those backends have no pointer SNodes (the
  sparse grid's blocks); else cpu. A CPU-emulated GPU (Mesa's llvmpipe/lavapipe, SwiftShader: what
  `mesa-vulkan-drivers` gives a machine without a GPU) is never chosen: Taichi's x64 backend runs the same kernels
  many times faster. When auto passes over a backend Taichi found, or gives a dense grid instead of the config's
  sparse one, `Backend.note` is one line saying which and why (the solver prints it to stderr).
- `arch: cuda|vulkan|metal` named explicitly: that backend or a ConfigError (key `arch`) saying what it lacks (not on
  this machine, no f64/i64/i8 shaders on this device, a crack finder's sparse node cache, a dense grid that does not
  fit); vulkan and metal get a dense grid, with the note.

A Vulkan device's kind and shader features are read from the Vulkan loader itself (ctypes, `vulkan_device`), the
same device Taichi's Vulkan backend picks (the highest-ranked kind: discrete, integrated, virtual, other, CPU; or
`TI_VISIBLE_DEVICE`). Taichi's own `ti.gpu` list also probes OpenGL/GLES, which crashes the process (segmentation
fault) on headless machines without a GL driver, so those are never probed.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import warnings
from dataclasses import dataclass
from functools import lru_cache

from .config import Config, ConfigError

GPU_ARCHS = ("cuda", "vulkan", "metal")
EMULATED = ("llvmpipe", "lavapipe", "swiftshader", "softpipe")   # software Vulkan drivers, by device name
_live = {"id": 0, "key": None}   # the newest Simulation's id (solver.Simulation._check_live)


class BackendNote(UserWarning):
    """Which backend `arch: auto` passed over, or which grid a backend gets instead of the config's, and why."""


@dataclass(frozen=True)
class Backend:
    arch: str                 # the Taichi arch a simulation starts: cpu, cuda, vulkan or metal
    sparse: bool              # the grid it gets there: domain.sparse, or False on a backend without pointer SNodes
    note: str | None = None   # one line: which backend auto passed over or which grid changed, and why


@dataclass(frozen=True)
class VulkanDevice:
    name: str
    kind: str          # discrete, integrated, virtual, cpu, other (VkPhysicalDeviceType)
    float64: bool      # shaderFloat64
    int64: bool        # shaderInt64
    int8: bool         # shaderInt8 and 8-bit storage buffers (u8 fields)

    @property
    def emulated(self) -> bool:
        """A GPU emulated on the CPU (Mesa's llvmpipe/lavapipe, SwiftShader)."""
        return self.kind == "cpu" or any(word in self.name.lower() for word in EMULATED)


@lru_cache(maxsize=1)
def _found() -> tuple[str, ...]:
    from taichi.lang.misc import is_arch_supported
    import taichi as ti

    ti.set_logging_level(ti.ERROR)  # no "libcuda.so not found" warning on machines without CUDA
    return tuple(name for name in GPU_ARCHS if is_arch_supported(getattr(ti, name))) + ("cpu",)


def available_archs() -> list[str]:
    """The GPU backends Taichi finds on this machine (in the order of GPU_ARCHS), then cpu; probed once."""
    return list(_found())


# ---------------------------------------------------------------- the Vulkan device (ctypes)
_KINDS = {0: "other", 1: "integrated", 2: "discrete", 3: "virtual", 4: "cpu"}
_RANK = {"discrete": 0, "integrated": 1, "virtual": 2, "other": 3, "cpu": 4}   # Taichi's preference
_FEATURE_FLOAT64, _FEATURE_INT64 = 39, 40          # VkBool32 indices in VkPhysicalDeviceFeatures
_STYPE_FEATURES2 = 1000059000                      # VkPhysicalDeviceFeatures2
_STYPE_FLOAT16_INT8 = 1000082000                   # VkPhysicalDeviceShaderFloat16Int8Features
_STYPE_8BIT_STORAGE = 1000177000                   # VkPhysicalDevice8BitStorageFeatures


def _vulkan_library():
    names = {"darwin": ["libvulkan.1.dylib", "libMoltenVK.dylib"], "win32": ["vulkan-1.dll"]}.get(
        sys.platform, ["libvulkan.so.1", "libvulkan.so"])
    for name in names:
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    # elsewhere than Linux, where the loader's soname is fixed: on Linux find_library runs `ldconfig -p`, a
    # process (also under `taichi-mpm validate`), for a name libvulkan.so.1 already covers
    found = ctypes.util.find_library("vulkan") if not sys.platform.startswith("linux") else None
    try:
        return ctypes.CDLL(found) if found else None
    except OSError:
        return None


@lru_cache(maxsize=1)
def vulkan_devices() -> tuple[VulkanDevice, ...]:
    """Every Vulkan physical device the loader lists (empty without a loader or a driver)."""
    try:
        return tuple(_probe_vulkan())
    except Exception:   # a broken loader or driver: no device
        return ()


def _probe_vulkan() -> list[VulkanDevice]:
    lib = _vulkan_library()
    if lib is None:
        return []
    p, u32 = ctypes.c_void_p, ctypes.c_uint32

    class AppInfo(ctypes.Structure):
        _fields_ = [("sType", u32), ("pNext", p), ("pApplicationName", ctypes.c_char_p), ("applicationVersion", u32),
                    ("pEngineName", ctypes.c_char_p), ("engineVersion", u32), ("apiVersion", u32)]

    class InstanceInfo(ctypes.Structure):
        _fields_ = [("sType", u32), ("pNext", p), ("flags", u32), ("pApplicationInfo", ctypes.POINTER(AppInfo)),
                    ("enabledLayerCount", u32), ("ppEnabledLayerNames", p),
                    ("enabledExtensionCount", u32), ("ppEnabledExtensionNames", p)]

    class Chained(ctypes.Structure):   # sType, pNext, then VkBool32s (feature structs)
        _fields_ = [("sType", u32), ("pNext", p), ("flags", u32 * 64)]

    app = AppInfo(0, None, b"taichi-mpm", 1, b"taichi-mpm", 1, (1 << 22) | (1 << 12))   # Vulkan 1.1
    info = InstanceInfo(1, None, 0, ctypes.pointer(app), 0, None, 0, None)
    instance = p()
    lib.vkCreateInstance.argtypes = [ctypes.POINTER(InstanceInfo), p, ctypes.POINTER(p)]
    if lib.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance)) != 0:
        return []
    get_proc = lib.vkGetInstanceProcAddr
    get_proc.restype, get_proc.argtypes = p, [p, ctypes.c_char_p]

    def fn(name, *argtypes):
        address = get_proc(instance, name)
        return ctypes.CFUNCTYPE(ctypes.c_int, *argtypes)(address) if address else None

    devices = []
    try:
        enumerate_ = fn(b"vkEnumeratePhysicalDevices", p, ctypes.POINTER(u32), p)
        properties = fn(b"vkGetPhysicalDeviceProperties", p, p)
        features = fn(b"vkGetPhysicalDeviceFeatures", p, p)
        features2 = fn(b"vkGetPhysicalDeviceFeatures2", p, p)
        count = u32(0)
        enumerate_(instance, ctypes.byref(count), None)
        handles = (p * count.value)()
        enumerate_(instance, ctypes.byref(count), handles)
        for handle in handles[:count.value]:
            props = (ctypes.c_ubyte * 4096)()
            properties(handle, props)
            kind = _KINDS.get(int.from_bytes(bytes(props[16:20]), "little"), "other")
            name = bytes(props[20:276]).split(b"\0", 1)[0].decode("utf-8", "replace")
            bools = (u32 * 64)()
            features(handle, bools)
            int8 = False
            if features2 is not None:
                storage = Chained(_STYPE_8BIT_STORAGE, None)
                small = Chained(_STYPE_FLOAT16_INT8, ctypes.cast(ctypes.pointer(storage), p))
                both = Chained(_STYPE_FEATURES2, ctypes.cast(ctypes.pointer(small), p))
                features2(handle, ctypes.byref(both))
                int8 = bool(small.flags[1]) and bool(storage.flags[0])   # shaderInt8; storageBuffer8BitAccess
            devices.append(VulkanDevice(name, kind, bool(bools[_FEATURE_FLOAT64]), bool(bools[_FEATURE_INT64]),
                                        int8))
    finally:
        destroy = get_proc(instance, b"vkDestroyInstance")
        if destroy:
            ctypes.CFUNCTYPE(None, p, p)(destroy)(instance, None)
    return devices


def vulkan_device() -> VulkanDevice | None:
    """The device Taichi's Vulkan backend runs on: TI_VISIBLE_DEVICE's, else the best-ranked kind."""
    devices = vulkan_devices()
    if not devices:
        return None
    visible = os.environ.get("TI_VISIBLE_DEVICE", "")
    if visible.isdigit() and int(visible) < len(devices):
        return devices[int(visible)]
    return min(devices, key=lambda d: _RANK[d.kind])


# ---------------------------------------------------------------- the choice
def _gpu_problem(arch: str, cfg: Config | None, size_check=None) -> str | None:
    """What keeps `arch` (vulkan or metal) from running this scene, or None. Both lack pointer SNodes (the scene
    then gets a dense grid, checked against the memory limit here); the solver's diagnostics sum in f64, the crack
    finder indexes nodes in i64 and a scene of several materials keeps u8 ids. size_check(cfg) raises ConfigError
    when a run does not fit (budget.check, passed in by the caller: budget asks this module for the arch)."""
    if arch == "metal":
        return "Taichi's metal backend has no f64, which the solver's energy and momentum sums use"
    device = vulkan_device()
    if device is None:
        return "no Vulkan device answers"
    lacks = [what for what, has in (("f64", device.float64), ("i64", device.int64)) if not has]
    if cfg is not None and len({b.material for b in cfg.bodies}) > 1 and not device.int8:
        lacks.append("u8 (several materials)")
    if lacks:
        return f"the Vulkan device {device.name} has no {', '.join(lacks)} shaders"
    if cfg is None:
        return None
    if cfg.crack is not None and cfg.crack.normal_refresh > 0:
        return "the crack finder's node-normal cache (crack.normal_refresh > 0) needs a sparse grid (pointer SNodes)"
    if cfg.domain.sparse and size_check is not None:
        dense = cfg.model_copy(update={"arch": "cpu", "domain": cfg.domain.model_copy(update={"sparse": False})})
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                size_check(dense)
        except ConfigError as e:
            return f"the dense grid it would need does not fit: {e.message}"
    return None


def _dense_grid(arch: str, cfg: Config) -> str | None:
    """What the note says when a sparse grid becomes dense on `arch`; None for a dense grid asked for."""
    if not cfg.domain.sparse:
        return None
    return (f"a dense grid (Taichi's {arch} backend has no sparse grids; the run uses more memory than with "
            "domain.sparse on cpu or cuda)")


def choose(cfg: Config, size_check=None) -> Backend:
    """The backend and grid this scene gets on this machine (see the module docstring); ConfigError (key `arch`)
    for an explicit arch that cannot run it. size_check: see _gpu_problem (without it a dense grid is not sized)."""
    arch = cfg.arch
    if arch == "cpu":
        return Backend("cpu", cfg.domain.sparse)
    found = available_archs()
    if arch != "auto":
        if arch not in found:
            raise ConfigError(f"arch {arch} is not available on this machine (available: {', '.join(found)}); "
                              "use arch: auto or cpu", key="arch")
        if arch == "cuda":
            return Backend("cuda", cfg.domain.sparse)
        problem = _gpu_problem(arch, cfg, size_check)
        if problem:
            raise ConfigError(f"arch {arch} cannot run this scene: {problem}; use arch: auto or cpu", key="arch")
        said = [_dense_grid(arch, cfg)]
        device = vulkan_device() if arch == "vulkan" else None
        if device is not None and device.emulated:
            said.append(f"{device.name} is a CPU-emulated GPU, much slower than arch: cpu")
        said = [s for s in said if s]
        return Backend(arch, False, f"arch {arch}: " + "; ".join(said) if said else None)
    if "cuda" in found:
        return Backend("cuda", cfg.domain.sparse)
    skipped = []
    for gpu in ("vulkan", "metal"):
        if gpu not in found:
            continue
        device = vulkan_device() if gpu == "vulkan" else None
        if device is not None and device.emulated:
            skipped.append(f"{gpu} skipped ({device.name} is a CPU-emulated GPU, slower than Taichi's cpu backend)")
            continue
        problem = _gpu_problem(gpu, cfg, size_check)
        if problem:
            skipped.append(f"{gpu} skipped ({problem})")
            continue
        dense = _dense_grid(gpu, cfg)
        said = f"arch auto: {gpu}" + (f" with {dense}" if dense else "")
        return Backend(gpu, False, "; ".join([said, *skipped]) if (dense or skipped) else None)
    return Backend("cpu", cfg.domain.sparse, ("arch auto: cpu; " + "; ".join(skipped)) if skipped else None)


def resolve_arch(arch: str, cfg: Config | None = None, size_check=None) -> str:
    """The arch name a config's `arch` gets here: `choose(cfg).arch` with a config. Without one, auto's choice
    before the scene's own needs (cuda, else a real GPU's vulkan with f64 and i64 shaders, else cpu); an explicit
    arch this machine lacks is a ConfigError (key `arch`)."""
    if cfg is not None:
        return choose(cfg, size_check).arch
    if arch == "cpu":
        return arch
    found = available_archs()
    if arch != "auto":
        if arch not in found:
            raise ConfigError(f"arch {arch} is not available on this machine (available: {', '.join(found)}); "
                              "use arch: auto or cpu", key="arch")
        return arch
    if "cuda" in found:
        return "cuda"
    device = vulkan_device() if "vulkan" in found else None
    if device is not None and not device.emulated and _gpu_problem("vulkan", None) is None:
        return "vulkan"
    return "cpu"   # metal: no f64 (_gpu_problem)


def init_taichi(arch: str | Backend, precision: str, deterministic: bool = False, order_free: bool = False):
    """(Re)start Taichi for a new simulation; only the newest Simulation stays live. `arch`: choose()'s answer
    (its note, if any, is warned as a BackendNote), or a config's arch (resolved by resolve_arch without a scene).

    deterministic: no fast math and, unless the scene is `order_free` (thread_independent), one CPU thread (atomic
    adds and reductions then run in one fixed order), so runs are bit-identical whatever the thread count or load.
    GPU float atomics have no fixed order: there `deterministic` cannot hold and a warning says so
    (docs/reliability.md)."""
    import taichi as ti

    from . import jit

    fp = ti.f64 if precision == "f64" else ti.f32
    if isinstance(arch, Backend):
        name = arch.arch
        if arch.note:
            warnings.warn_explicit(arch.note, BackendNote, "taichi-mpm", 0)   # one line, no source excerpt
    else:
        name = resolve_arch(arch)
    jit.install()   # kernel building without Taichi's repeated source excerpts (jit.py)
    options = {}
    if deterministic:
        if name == "cpu":
            options = dict(fast_math=False) if order_free else dict(cpu_max_num_threads=1, fast_math=False)
        else:
            warnings.warn(f"solver.deterministic: on {name} float atomic adds are not ordered, so runs may differ "
                          "in the last digits; use arch: cpu for bit-identical runs", RuntimeWarning, stacklevel=3)
            options = dict(fast_math=False)
    ti.init(arch=getattr(ti, name), default_fp=fp, default_ip=ti.i32, offline_cache=True,
            log_level=ti.ERROR, random_seed=0, **options)
    _live["id"] += 1
    return _live["id"]
