"""Bytes per particle as features are added: model only what the scene requires.

Starts from a minimal 2D elastic scene in f32 and adds one feature at a time (APIC's affine matrix, f64, a second
material, a viscous fluid, a body force, 3D, MUSL, FLIP). Bytes per particle come from the fields the solver
allocated (Simulation.bytes_per_particle, structure of arrays).

    python benchmarks/memory.py
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import block_config, parser, report  # noqa: E402


def cases(tiny):
    n = 16 if tiny else 64
    base = block_config(2, n, transfer="pic", model="fixed_corotated")
    yield "2D f32 PIC elastic (minimal)", base, None
    c = block_config(2, n, transfer="apic", model="fixed_corotated")
    yield "+ APIC", c, None
    c = block_config(2, n, transfer="apic", model="fixed_corotated", precision="f64")
    yield "+ APIC, f64", c, None
    c = block_config(2, n, transfer="apic", model="fixed_corotated")
    c["materials"]["soft"] = {"model": "neo_hookean", "E": 100.0, "nu": 0.3, "density": 1.0}
    c["bodies"].append({"shape": {"type": "box", "lower": [0.6, 0.6], "upper": [0.8, 0.8]}, "material": "soft"})
    yield "+ APIC, two materials", c, None
    c = block_config(2, n, transfer="pic", model="fluid")
    c["materials"]["m"]["viscosity"] = 0.1
    yield "PIC viscous fluid (stores grad v)", c, None
    c = block_config(2, n, transfer="pic", model="fixed_corotated")
    yield "PIC + body force", c, (lambda X, t: 0 * X)
    yield "3D f32 APIC elastic", block_config(3, 16 if tiny else 32, transfer="apic"), None


def main(argv=None):
    a = parser(__doc__).parse_args(argv)
    import taichi_mpm as tm

    rows = []
    for name, cfg, force in cases(a.tiny):
        sim = tm.Simulation(cfg, body_force=force)
        if not a.tiny:  # the fields exist once the Simulation does; a step (7 cold compiles) shows it also runs
            sim.step()
        rows.append(dict(case=name, particles=sim.n, bytes_per_particle=sim.bytes_per_particle))
    report(rows, a.json)
    return rows


if __name__ == "__main__":
    main()
