"""taichi-mpm: an interactive Material Point Method sandbox on Taichi.

`Simulation` (and the solver behind it) is imported on first use, so that `import taichi_mpm`
and the command line's config checks do not start Taichi.
"""
from .config import Config, load_config
from .errors import ConfigError, InstabilityError

__all__ = ["Config", "ConfigError", "InstabilityError", "Simulation", "load_config"]
__version__ = "0.1.0"


def __getattr__(name):
    if name == "Simulation":
        from .io.runner import Simulation  # the solver's Simulation whose run() writes outputs

        globals()["Simulation"] = Simulation
        return Simulation
    raise AttributeError(f"module 'taichi_mpm' has no attribute {name!r}")
