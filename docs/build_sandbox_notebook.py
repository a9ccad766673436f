"""Builds docs/sandbox.ipynb: runs its cells here (headless, matplotlib Agg) and stores their outputs in the
notebook, so that GitHub shows the pictures without a Jupyter installation. Run from the repository root:

    python docs/build_sandbox_notebook.py

The cells are the notebook's whole content (CELLS below); tests/test_notebook.py runs them too (-m slow).
"""
from __future__ import annotations

import base64
import contextlib
import io
import json
import sys
from pathlib import Path

CELLS = [
    ("markdown", """# The taichi-mpm sandbox in a notebook

This notebook runs a scene, shows its frames inline and compares two settings of it, with the same tools as the
command line (`taichi-mpm run`, `render`, `compare`). It needs only the package (`pip install -e .`) and Jupyter;
rendering is off-screen (pyvista/VTK), so it also works on a server without a display.

The scene is Sulsky's two colliding elastic disks (`configs/colliding_disks.yaml`), coarsened so that every cell
runs in seconds once Taichi has compiled its kernels (the first run of a setting compiles them: tens of seconds)."""),
    ("code", """import numpy as np
import matplotlib.pyplot as plt
import taichi_mpm as tm
from taichi_mpm.io.render import FrameRenderer, field_values, sequence_limits

cfg = tm.load_config("configs/colliding_disks.yaml",
                     overrides={"domain.dx": 0.04, "solver.end_time": 3.0, "output.every": 0.5})
sim = tm.Simulation(cfg)
print(sim.n, "particles;", cfg.solver.basis, "basis,", cfg.solver.transfer, "transfer")"""),
    ("markdown", """## Frames inline

`sim.particles()` gives numpy arrays; a `FrameRenderer` turns them into pictures. The colour range is fixed for the
whole sequence from percentiles of every frame (`sequence_limits`), so that a colour means the same stress in every
picture: step first, keep the states, then render."""),
    ("code", """states = []
sim.run(on_output=lambda s: states.append((s.time, s.particles())))
render = {"color_by": "von_mises", "size": [360, 360]}
limits = sequence_limits(render, [field_values(p, "von_mises", 2) for _, p in states])
r = FrameRenderer(render, 2, cfg.domain.lower, cfg.domain.upper, limits=limits)
pick = [0, 3, 4, 6]   # before, at, during and after the impact
fig, axes = plt.subplots(1, len(pick), figsize=(3 * len(pick), 3))
for ax, k in zip(axes, pick):
    t, p = states[k]
    ax.imshow(r.image(p["x"], field_values(p, "von_mises", 2), t, spacing=float(np.sqrt(np.median(p["volume"])))))
    ax.axis("off")
r.close()
plt.tight_layout()
plt.show()"""),
    ("markdown", """## A small study: what the transfer does to the energy

`taichi_mpm.tools.compare.compare` runs the scene once per value of a key and writes side-by-side frames, a movie, curves
and a summary (the `taichi-mpm compare` command). Here PIC against APIC: PIC's averaging dissipates kinetic energy
that APIC keeps; the curves come from the returned variants."""),
    ("code", """from taichi_mpm.tools.compare import compare

res = compare(cfg, "solver.transfer=pic,apic", out="runs/notebook_compare", overwrite=True, movie=False)
fig, ax = plt.subplots(figsize=(6, 3))
for v in res["variants"]:
    rows = v.rows
    ax.plot([r["time"] for r in rows], [r["kinetic"] + r["strain"] for r in rows], label=v.label)
ax.set_xlabel("time [s]"); ax.set_ylabel("kinetic + strain energy [J/m]"); ax.legend(); ax.grid(alpha=0.3)
plt.tight_layout()
plt.show()
print(open(res["summary"]).read())"""),
    ("markdown", """The comparison's side-by-side frames are in `runs/notebook_compare/frames/` (one colour range for
both panels); `taichi-mpm compare configs/colliding_disks.yaml --vary solver.basis=linear,cubic` makes the same for
the full scene, with its movie."""),
]


def run_cells(cells=CELLS, capture=True):
    """Run the code cells in one namespace; returns their outputs in notebook form (stdout, figures as PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns: dict = {"__name__": "__main__"}
    outputs = []
    for kind, source in cells:
        if kind != "code":
            outputs.append(None)
            continue
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf) if capture else contextlib.nullcontext():
            exec(compile(source, "<cell>", "exec"), ns)
        out = []
        text = "\n".join(line for line in buf.getvalue().splitlines() if not line.startswith("[Taichi]"))
        for num in plt.get_fignums():
            png = io.BytesIO()
            plt.figure(num).savefig(png, format="png", dpi=72)
            out.append({"output_type": "display_data", "metadata": {},
                        "data": {"image/png": base64.b64encode(png.getvalue()).decode(), "text/plain": ["<Figure>"]}})
        plt.close("all")
        if text.strip():
            out.insert(0, {"output_type": "stream", "name": "stdout", "text": text.strip() + "\n"})
        outputs.append(out)
    return outputs


def build(path="docs/sandbox.ipynb"):
    outputs = run_cells()
    cells, count = [], 0
    for (kind, source), out in zip(CELLS, outputs):
        lines = source.splitlines(keepends=True)
        if kind == "markdown":
            cells.append({"cell_type": "markdown", "metadata": {}, "source": lines})
        else:
            count += 1
            cells.append({"cell_type": "code", "execution_count": count, "metadata": {}, "outputs": out,
                          "source": lines})
    nb = {"cells": cells, "metadata": {"kernelspec": {"display_name": "Python 3", "language": "python",
                                                      "name": "python3"},
                                       "language_info": {"name": "python"}},
          "nbformat": 4, "nbformat_minor": 5}
    Path(path).write_text(json.dumps(nb, indent=1) + "\n")
    return path


if __name__ == "__main__":
    sys.exit(print(build()) and 0)
