"""Granular column collapse (2D, drucker_prager) against the quasi-2D experiments of Lube et al. 2005 (Phys. Rev. E 72,
041301): a column of width L0 and height a L0 against the channel's end wall is released and spreads along the
floor. Lube et al. measured the normalised run-out (L_inf - L0) / L0 = 1.2 a for a < 1.8 and 1.9 a^(2/3) for
a > 2.8, and a final height H_inf = a L0 (the top is not reached) for a < 1.15.

    python demos/column_collapse_lube.py [--aspects 0.5 1 2 3] [--cells 20] [--plot docs/images/column_collapse_lube.png]
    python demos/column_collapse_lube.py --aspects 1 --cells 20 40 60 80 --profiles docs/images/collapse_profiles.png

Each run starts from configs/granular_collapse.yaml (phi = 30 deg, plane-strain fit, rough floor), sets the column's
height, the domain and dx = L0 / cells (default 20), runs until the sand
is at rest (kinetic energy below 1e-4 of the released potential energy, or `--end` seconds) and measures the front
(the 99.5th percentile of x, so a few lone grains do not count), the height at the wall (the 99.5th percentile of y
over x < dx) and the slope of the deposit's flank. Several `--cells` run each column at each resolution; `--profiles`
plots the deposits' thickness along the floor (`thickness_profile`), one panel per aspect ratio: where the deposits
of two resolutions agree, and where only the toe moves; with two or more, each column's run-out is also extrapolated
to dx -> 0 at first order from the two finest (`first_order_limit`). Measured figures and the plots:
docs/materials.md.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

import taichi_mpm as tm

ROOT = Path(__file__).resolve().parents[1]
L0 = 0.1


def lube_runout(a):
    """Lube et al. 2005's fits of (L_inf - L0) / L0 in the two regimes (None in between: a transition)."""
    a = np.asarray(a, float)
    return np.where(a < 1.8, 1.2 * a, np.where(a > 2.8, 1.9 * a ** (2 / 3), np.nan))


PROFILE_BIN = L0 / 20   # bins of the thickness profile: the same physical width at every resolution


def resolution(cells=20):
    """dx = L0 / cells. The run-out converges only from about L0/60 (docs/materials.md, "Where the run-out
    converges": at a = 1 it grows 1.16, 1.51, 1.71, 1.76 at L0/20, 40, 60, 80; the deposits agree but for a toe one
    or two cells thick that each finer grid carries further), so every column of a table is run at the same dx."""
    return L0 / cells


def first_order_limit(fine: float, coarse: float, dx_fine: float, dx_coarse: float) -> float:
    """Richardson's extrapolation for an error proportional to dx: f0 = f(dx) + (f(dx) - f(dx')) dx / (dx' - dx).
    The front of a layer sheared over sand at rest converges at first order (tests/test_sliding_layer.py), so two
    grids fine enough to be in that regime give an estimate of the converged run-out (docs/materials.md, "Why the
    low columns' run-out moves with dx")."""
    return fine + (fine - coarse) * dx_fine / (dx_coarse - dx_fine)


def thickness_profile(x, volume, bin_width=PROFILE_BIN):
    """The deposit's thickness along the floor: bin centres and, per bin, the particles' volume over the bin's width
    (a depth average, so it does not depend on how the particles are spaced)."""
    edges = np.arange(0.0, x[:, 0].max() + 2 * bin_width, bin_width)
    h = np.histogram(x[:, 0], edges, weights=volume)[0] / bin_width
    return 0.5 * (edges[:-1] + edges[1:]), h


def collapse_config(aspect, dx=0.005, overrides=None):
    H0 = aspect * L0
    # room for twice Lube et al.'s run-out: a converged drucker_prager deposit runs 50 % further, its toe beyond that
    reach = L0 * (1 + 2.0 * max(1.9 * aspect ** (2 / 3), 1.2 * aspect)) + 8 * dx
    width = dx * np.ceil(reach / dx)
    height = dx * np.ceil((H0 + 4 * dx) / dx)
    sets = {"domain.dx": dx, "domain.upper": [float(width), float(height)],
            "bodies.0.shape.upper": [L0, H0], "output.formats": []}
    sets.update(overrides or {})
    return tm.load_config(ROOT / "configs" / "granular_collapse.yaml", overrides=sets)


def collapse(aspect, dx=0.005, end=None, overrides=None, verbose=False):
    """Run one column to rest; returns dict(aspect, runout = (L_inf - L0) / L0, height = H_inf / L0, time, steps)."""
    from taichi_mpm.solver import Simulation

    cfg = collapse_config(aspect, dx, overrides)
    sim = Simulation(cfg)
    g = 9.81
    released = float(np.sum(sim.scene.mass) * g * aspect * L0 / 2)   # potential energy above the floor
    end = end or 3.0 * np.sqrt(aspect * L0 / g) + 0.6                  # collapse + spreading + margin
    while sim.time < end:
        sim.advance(0.05)
        if sim.time > 0.2 and sim.energy()["kinetic"] < 1e-4 * released:
            break
        if verbose:
            print(f"  a={aspect:g} t={sim.time:.2f} kinetic/released={sim.energy()['kinetic'] / released:.2e}",
                  file=sys.stderr)
    p = sim.particles()
    x = p["x"]
    front = float(np.percentile(x[:, 0], 99.5))
    wall = x[x[:, 0] < dx]
    top = float(np.percentile(wall[:, 1], 99.5)) if len(wall) else 0.0
    at_end = int(np.sum(x[:, 0] > cfg.domain.upper[0] - 2 * dx))   # particles stopped by the channel's far end
    return dict(aspect=aspect, runout=(front - L0) / L0, height=top / L0, slope=surface_slope(x, dx), time=sim.time,
                steps=sim.n_steps, particles=sim.n, dx=dx, profile=thickness_profile(x, p["volume"]), at_end=at_end)


def surface_slope(x, dx):
    """Angle (degrees) of the deposit's free surface: a line fitted to the top of each column of width dx where the
    surface lies between 20 % and 80 % of the deposit's height (the flank, without the plateau and the thin toe)."""
    bins = np.floor(x[:, 0] / dx).astype(int)
    cols = np.unique(bins)
    top = np.array([x[bins == b, 1].max() for b in cols])
    xc = (cols + 0.5) * dx
    sel = (top > 0.2 * top.max()) & (top < 0.8 * top.max())
    if sel.sum() < 3:
        return float("nan")
    return float(np.degrees(np.arctan(-np.polyfit(xc[sel], top[sel], 1)[0])))


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.array([r["aspect"] for r in rows])
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.8))
    s = np.linspace(0.3, max(4.0, a.max() * 1.1), 200)
    ax[0].plot(s[s < 1.8], 1.2 * s[s < 1.8], "k-", label="Lube et al. 2005: 1.2 a")
    ax[0].plot(s[s > 2.8], 1.9 * s[s > 2.8] ** (2 / 3), "k--", label="1.9 a^(2/3)")
    ax[0].fill_between(s[s < 1.8], 0.75 * 1.2 * s[s < 1.8], 1.25 * 1.2 * s[s < 1.8], color="0.85")
    ax[0].fill_between(s[s > 2.8], 0.75 * 1.9 * s[s > 2.8] ** (2 / 3), 1.25 * 1.9 * s[s > 2.8] ** (2 / 3), color="0.85",
                       label="+-25 %")
    ax[0].plot(a, [r["runout"] for r in rows], "o", color="C3", label="drucker_prager (MPM)")
    ax[0].set(xlabel="aspect ratio a = H0 / L0", ylabel="(L_inf - L0) / L0", title="run-out")
    ax[0].legend(fontsize=8)
    ax[1].plot(s[s < 1.15], s[s < 1.15], "k-", label="Lube et al.: H_inf = a L0 (a < 1.15)")
    ax[1].fill_between(s[s < 1.15], 0.75 * s[s < 1.15], 1.25 * s[s < 1.15], color="0.85", label="+-25 %")
    ax[1].plot(a, [r["height"] for r in rows], "o", color="C3", label="drucker_prager (MPM)")
    ax[1].set(xlabel="aspect ratio a", ylabel="H_inf / L0", title="final height")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_profiles(rows, path):
    """The deposits' thickness profiles, one panel per aspect ratio, one line per resolution."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    aspects = sorted({r["aspect"] for r in rows})
    fig, axes = plt.subplots(1, len(aspects), figsize=(4.5 * len(aspects), 3.4), squeeze=False)
    for ax, aspect in zip(axes[0], aspects):
        for r in sorted((r for r in rows if r["aspect"] == aspect), key=lambda r: -r["dx"]):
            xc, h = r["profile"]
            ax.plot(xc / L0, h / L0, label=f"dx = L0/{L0 / r['dx']:.0f}: run-out {r['runout']:.2f}")
        ref = float(lube_runout(aspect))
        if np.isfinite(ref):
            ax.axvline(1 + ref, color="k", ls="--", lw=1, label=f"Lube et al. 2005: {ref:.2f}")
        ax.set(xlabel="x / L0", ylabel="deposit thickness / L0", title=f"a = {aspect:g}", xlim=(0, None),
               ylim=(0, None))
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--aspects", type=float, nargs="+", default=[0.5, 1.0, 2.0, 3.0, 4.0])
    ap.add_argument("--cells", type=int, nargs="+", default=[20],
                    help="dx = L0 / cells; several values run every column at each")
    ap.add_argument("--end", type=float, default=None)
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--profiles", type=Path, default=None, help="plot the deposits' thickness profiles here")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    from taichi_mpm.config import parse_overrides

    rows = []
    for aspect, cells in ((aspect, cells) for aspect in a.aspects for cells in a.cells):
        r = collapse(aspect, resolution(cells), a.end, parse_overrides(a.overrides), verbose=True)
        ref = float(lube_runout(aspect))
        r["lube_runout"] = ref
        rows.append(r)
        lube = (f"Lube {ref:.3f}, {r['runout'] / ref - 1:+.0%}" if np.isfinite(ref) else
                f"Lube: transition, 1.2 a = {1.2 * aspect:.2f} to 1.9 a^(2/3) = {1.9 * aspect ** (2 / 3):.2f}")
        print(f"a={aspect:g}: run-out {r['runout']:.3f} ({lube}), "
              f"height {r['height']:.3f} L0 (dx = L0/{L0 / r['dx']:.0f}), slope {r['slope']:.1f} deg, t={r['time']:.2f} s, {r['steps']} steps, {r['particles']} particles"
              + (f", {r['at_end']} AT THE FAR END WALL: the domain is too short" if r["at_end"] else ""))
    if len(set(a.cells)) >= 2:
        for aspect in a.aspects:
            coarse, fine = sorted((r for r in rows if r["aspect"] == aspect), key=lambda r: -r["dx"])[-2:]
            f0 = first_order_limit(fine["runout"], coarse["runout"], fine["dx"], coarse["dx"])
            ref = float(lube_runout(aspect))
            lube = f" (Lube {ref:.3f}, {f0 / ref - 1:+.0%})" if np.isfinite(ref) else ""
            print(f"a={aspect:g}: first-order extrapolation from L0/{L0 / coarse['dx']:.0f} and "
                  f"L0/{L0 / fine['dx']:.0f}: {f0:.3f}{lube}")
    if a.plot:
        plot([r for r in rows if r["dx"] == resolution(a.cells[-1])], a.plot)
    if a.profiles:
        plot_profiles(rows, a.profiles)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
