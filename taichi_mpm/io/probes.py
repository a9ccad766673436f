"""Probes: quantities over time, one CSV per probe in RUN_DIR/probes/NAME.csv (config `output.probes`).

Types (selection made once, from the particles' positions at t = 0, so a resumed run follows the same ones):
- point:  the particle nearest `point` at t = 0: position, displacement, velocity, Cauchy stress components.
- body:   all particles of a body (name or index); region: those inside a box or sphere at t = 0. Both give the
          mass-weighted mean displacement and velocity (centre of mass), the volume-weighted mean Cauchy stress
          (current volumes: the stress a homogeneous sample would carry) and the kinetic energy sum m v^2 / 2.
- contact: the force the other bodies exert on a body: the change of its momentum since the last sample divided
          by the elapsed time, minus its weight (the contact force while the body touches no wall and has no body
          force). The t = 0 row has no interval yet: nan.
- wall:   the force a domain face exerts on the material: the impulse its wall condition gives the grid nodes
          (Simulation.wall_impulse), summed since the last sample and divided by that time, so a sample is the
          mean force over the interval, not one noisy step. The t = 0 row has no interval yet: nan.
- grip:   the same for a bodies[].prescribed_velocity entry (Simulation.prescribed_impulse): a grip's force.
Elapsed time for contact, wall and grip: between the samples' Simulation.velocity_time. The velocities, and so
momenta, belong to that time (leapfrog: half a step behind the clock), and the impulses of the steps in between
cover exactly that span (each step's kick runs from t - dt_prev/2 to t + dt/2), so force x elapsed time equals
the momentum change to round-off.

Sampling (`output.probe_every`): null samples at every output, a number every that many seconds (at the first
step on or after each multiple), `step` after every step; t = 0 is always sampled. Each row is flushed, so the
files are complete up to a stop or a failure; `--resume` keeps the rows up to the checkpoint's time. A probe whose
file holds rows must be resumed with the definition that wrote them (`check_resume`): a changed type, point, body,
region, face or grip would drop or mix its rows, so `--resume` refuses it (exit 2) before writing anything; give the
changed probe a new name. Files are written through io's helpers (never through a link in the run folder).

No physics here: everything comes from the Simulation's public state (particles(), scene, wall_impulse()).
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from . import files as io
from ..config import ConfigError
from ..scene import inside

PROBES_DIR = "probes"
AXES = "xyz"


def _per_depth(unit: str, dim: int) -> str:
    """2D quantities are per metre of depth, 1D per m^2 of cross-section."""
    return {3: unit, 2: f"{unit}/m", 1: f"{unit}/m^2"}[dim]


def stress_components(dim: int) -> list[tuple[int, int]]:
    """The components of the full 3x3 stress that can be non-zero: normal ones always (plane strain and uniaxial
    strain have out-of-plane normal stress), shear ones between the axes that exist."""
    normal = [(a, a) for a in range(3)]
    shear = [(a, b) for a in range(dim) for b in range(a + 1, dim)]
    return normal + shear


def _stress_columns(dim: int, prefix: str = "s") -> list[str]:
    return [f"{prefix}{AXES[a]}{AXES[b]} [Pa]" for a, b in stress_components(dim)]


def probe_columns(spec, dim: int) -> list[str]:
    """The CSV columns (after time and step) of a probe of this spec in a `dim`-D scene."""
    axes = AXES[:dim]
    if spec.type == "point":
        return ([f"{a} [m]" for a in axes] + [f"u{a} [m]" for a in axes] + [f"v{a} [m/s]" for a in axes]
                + _stress_columns(dim))
    if spec.type in ("body", "region"):
        return ([f"u{a} [m]" for a in axes] + [f"v{a} [m/s]" for a in axes] + _stress_columns(dim)
                + [f"kinetic [{_per_depth('J', dim)}]"])
    return [f"f{a} [{_per_depth('N', dim)}]" for a in axes]   # wall, contact


class PointProbe:
    needs_particles = True

    def __init__(self, spec, sim, key):
        x0 = sim.scene.x
        self.index = int(np.argmin(np.sum((x0 - np.asarray(spec.point)) ** 2, axis=1)))
        self.x0 = x0[self.index].copy()
        self.columns = probe_columns(spec, sim.dim)

    def row(self, p, sim, impulse, elapsed):
        i = self.index
        s = p["stress3"][i]
        return [*p["x"][i], *(p["x"][i] - self.x0), *p["v"][i], *(s[a, b] for a, b in stress_components(sim.dim))]


class GroupProbe:
    """Means over a fixed set of particles (a body, or a region at t = 0)."""
    needs_particles = True

    def __init__(self, spec, sim, key):
        s = sim.scene
        if spec.type == "body":
            index = spec.body if isinstance(spec.body, int) else [b.name for b in sim.cfg.bodies].index(spec.body)
            self.mask = s.body == index
        else:
            self.mask = inside(spec.region, s.x)
        if not self.mask.any():
            raise ConfigError(f"the probe '{spec.name}' selects no particle", key=f"{key}.{spec.type}")
        self.x0 = s.x[self.mask]
        self.columns = probe_columns(spec, sim.dim)

    def row(self, p, sim, impulse, elapsed):
        m, vol = p["mass"][self.mask], p["volume"][self.mask]
        u = p["x"][self.mask] - self.x0
        v = p["v"][self.mask]
        w = m / m.sum()
        stress = np.einsum("n,nij->ij", vol / vol.sum(), p["stress3"][self.mask])
        kinetic = 0.5 * float(np.sum(m * np.sum(v * v, axis=1)))
        return [*(w @ u), *(w @ v), *(stress[a, b] for a, b in stress_components(sim.dim)), kinetic]


class WallProbe:
    needs_particles = False

    def __init__(self, spec, sim, key):
        self.slot = 2 * AXES.index(spec.face[0]) + (spec.face.endswith("max"))
        self.columns = probe_columns(spec, sim.dim)

    def row(self, p, sim, impulse, elapsed):
        if elapsed <= 0:
            return [math.nan] * sim.dim
        return list(impulse[self.slot] / elapsed)


class ContactProbe:
    """Force of the other bodies on one body: d(momentum)/dt - m g over each sampling interval."""
    needs_particles = True

    def __init__(self, spec, sim, key):
        s = sim.scene
        index = spec.body if isinstance(spec.body, int) else [b.name for b in sim.cfg.bodies].index(spec.body)
        self.mask = s.body == index
        self.columns = probe_columns(spec, sim.dim)
        p = sim.particles()   # the momentum at the start (or at the checkpoint's time, resuming)
        m = p["mass"][self.mask]
        self.mass = float(m.sum())
        self.momentum = m @ p["v"][self.mask]

    def row(self, p, sim, impulse, elapsed):
        momentum = p["mass"][self.mask] @ p["v"][self.mask]
        change, self.momentum = momentum - self.momentum, momentum
        if elapsed <= 0:
            return [math.nan] * sim.dim
        return list(change / elapsed - self.mass * sim.gravity)  # gravity now (Simulation.set_gravity)


class GripProbe(WallProbe):
    """The force a grip (bodies[].prescribed_velocity entry) exerts on the material: its impulse over the interval
    (Simulation.prescribed_impulse) divided by the interval."""

    def __init__(self, spec, sim, key):
        self.slot = spec.grip
        d = sim.dim
        self.columns = [f"f{AXES[a]} [{_per_depth('N', d)}]" for a in range(d)]


KINDS = {"point": PointProbe, "body": GroupProbe, "region": GroupProbe, "wall": WallProbe, "contact": ContactProbe,
         "grip": GripProbe}


class Probes:
    """The probes of a run: `on_step(sim)` after every step, `on_output(sim)` at every output, `close()`."""

    def __init__(self, sim, out_dir, resume: bool = False, submit=None):
        out = sim.cfg.output
        # submit(fn, *args): how rows are written (the run's writer thread); default: at once
        self._submit = submit or (lambda fn, *args: fn(*args))
        self.every = out.probe_every
        self.root = Path(out_dir)
        self.dir = self.root / PROBES_DIR
        self.probes = []
        for i, spec in enumerate(out.probes):
            self.probes.append((spec.name, KINDS[spec.type](spec, sim, f"output.probes.{i}")))
        if not resume:
            for f in io.files_in(self.dir, "*.csv", root=self.root):  # an earlier run's probes (a link: itself)
                io.remove_file(f, root=self.root)
        self._files = {}
        if self.probes:
            io.ensure_folder(self.dir, root=self.root)
        for name, probe in self.probes:
            self._files[name] = self._open(self.dir / f"{name}.csv", ["time [s]", "step"] + probe.columns,
                                           sim.time if resume else None, self.root)
        self._particles = any(p.needs_particles for _, p in self.probes)
        self._walls = any(type(p) is WallProbe for _, p in self.probes)
        self._grips = any(isinstance(p, GripProbe) for _, p in self.probes)
        self._since = sim.velocity_time        # start of the interval the impulses cover (see the docstring)
        self._last_step = sim.n_steps if resume else None
        self._next = self._next_time(sim.time)

    @staticmethod
    def _open(path: Path, header: list[str], keep_until, root=None):
        """A fresh file with its header, or (resuming) the old rows up to the checkpoint's time: written to a
        temporary file and renamed over the old one (a link there is replaced, never followed), then kept open
        for the rows to come. check_resume has made sure that a file with rows has this header."""
        rows = []
        if keep_until is not None and os.path.lexists(path):
            old = list(csv.reader(io.read_regular(path).splitlines()))
            if old and old[0] == header:
                rows = [r for r in old[1:] if len(r) == len(header) and _time(r[0]) <= keep_until * (1 + 1e-12)]
        with io.atomic_write(path, "w", root=root, newline="", keep_open=True) as f:
            w = csv.writer(f)
            w.writerow(header)
            w.writerows(rows)
        return f

    def _next_time(self, t: float) -> float:
        if not isinstance(self.every, float):
            return math.inf
        return (math.floor(t / self.every + 1e-9) + 1) * self.every

    # ------------------------------------------------------------ sampling
    def on_step(self, sim):
        if self.every == "step" or sim.time >= self._next * (1 - 1e-12):
            self.sample(sim)

    def on_output(self, sim):
        if self.every is None or self._last_step is None:
            self.sample(sim)

    def sample(self, sim):
        """One row in every probe's file (once per step: a step sampled already is skipped)."""
        if not self.probes or sim.n_steps == self._last_step:
            return
        p = sim.particles() if self._particles else None
        impulse = sim.wall_impulse() if self._walls else None
        grip_impulse = sim.prescribed_impulse() if self._grips else None
        elapsed = sim.velocity_time - self._since
        rows = []
        for name, probe in self.probes:
            values = probe.row(p, sim, grip_impulse if isinstance(probe, GripProbe) else impulse, elapsed)
            rows.append((name, [repr(float(sim.time)), sim.n_steps] + [repr(float(v)) for v in values]))
        self._submit(self._write, rows)
        self._since, self._last_step = sim.velocity_time, sim.n_steps
        self._next = self._next_time(sim.time)

    def _write(self, rows):
        """One sample's rows, each flushed (in the run's writer thread)."""
        for name, line in rows:
            f = self._files[name]
            try:
                csv.writer(f).writerow(line)
                f.flush()
            except OSError as e:  # disk full, file-size limit: the rows up to the checkpoint are kept for --resume
                raise io.as_file_error(e, "write", self.dir / f"{name}.csv") from None

    def close(self):
        """Close the files after the rows handed over (through `submit`) are written."""
        self._submit(self._close)

    def _close(self):
        for f in self._files.values():
            try:
                f.close()
            except OSError:  # a failed flush was reported when the row was written
                pass
        self._files = {}


def _time(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.inf   # not a time: not kept


def _definition(spec: dict) -> dict:
    """A probe's definition without its name (what decides which rows it writes), unset keys left out."""
    return {k: v for k, v in spec.items() if k != "name" and v is not None}


def check_resume(cfg, out_dir, old_config: dict, dim: int) -> None:
    """Before a --resume writes anything: a probe whose file already holds rows must be the probe that wrote them.
    A changed definition (type, point, body, region, face, grip) would drop its rows (another header) or mix two
    quantities in one file (the same header): a ConfigError naming the probe, what changed and the file. A file
    whose header is not this probe's (edited, or from another tool) is refused as well, never emptied."""
    out_dir = Path(out_dir)
    old_probes = ((old_config or {}).get("output") or {}).get("probes") or []
    before = {p.get("name"): p for p in old_probes if isinstance(p, dict)}
    for i, spec in enumerate(cfg.output.probes):
        path = out_dir / PROBES_DIR / f"{spec.name}.csv"
        if not os.path.lexists(path):
            continue
        rows = [r for r in csv.reader(io.read_regular(path).splitlines())]
        n = sum(1 for r in rows[1:] if r)
        if n == 0:
            continue   # nothing to lose
        now = spec.model_dump(mode="json")
        old = before.get(spec.name)
        if old is not None and _definition(old) != _definition(now):
            keys = ["type"] + sorted(set(_definition(old)) | set(_definition(now)))   # a changed type first
            k = next(k for k in keys if _definition(old).get(k) != _definition(now).get(k))
            raise ConfigError(f"--resume: {path} holds {n} rows of the probe '{spec.name}' as it was "
                              f"({k}: {old.get(k)!r}); it is now {k}: {now.get(k)!r}, which would drop or mix "
                              f"those rows. Keep its definition to resume, or give the changed probe a new name "
                              f"(the old file stays as it is)", key=f"output.probes.{i}.{k}")
        header = ["time [s]", "step"] + probe_columns(spec, dim)
        if rows[0] != header:
            raise ConfigError(f"--resume: {path} holds {n} rows under another header than the probe '{spec.name}' "
                              f"writes ({', '.join(rows[0][:4])}, ... instead of {', '.join(header[:4])}, ...); "
                              f"resuming would drop them: move the file aside or restore the probe's definition",
                              key=f"output.probes.{i}")


def read_probe(path) -> dict[str, np.ndarray]:
    """A probe CSV as {column header: values}. An empty or malformed file (no header, no time column, a row of
    the wrong length, a value that is not a number) is a ValueError naming the file and the line."""
    return io.read_csv_columns(path, required=("time [s]",), what="probe file")
