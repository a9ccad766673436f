"""taichi-mpm: an interactive Material Point Method sandbox on Taichi."""
from .config import Config, load_config
from .errors import ConfigError, InstabilityError
from .solver import Simulation

__all__ = ["Config", "ConfigError", "InstabilityError", "Simulation", "load_config"]
__version__ = "0.1.0"
