"""Outputs: safe files, VTU/PVD series, diagnostics and checkpoints (`files`), the output-writing run (`runner`),
probes, plots and off-screen rendering.

`from taichi_mpm import io; io.load_checkpoint(...)` (docs/contract.md) reaches `files`' public names; they are
looked up on first use so that importing a submodule (config validation reads `render_options`) loads no more.
"""
import importlib

_SUBMODULES = {"files", "runner", "probes", "render", "render_options", "plots", "colour_range"}


def __getattr__(name):
    # a submodule not yet imported is not an attribute: the import system then loads it
    if name.startswith("_") or name in _SUBMODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.files"), name)
