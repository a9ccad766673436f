"""Small problems for the study tests, importable from a study's case process (`type: study_problems:NAME`)."""
import math

import numpy as np


class MMS1D:
    """u = A sin(pi X) sin(pi t / T) on [0, 1], neo-Hookean (nu = 0), both ends sticky; body force from the PDE."""

    def __init__(self, spec):
        self.name = "mms1d_test"
        self.A = float(spec.get("amplitude", 0.01))
        self.E, self.rho = 1.0e4, 1.0
        self.c = math.sqrt(self.E / self.rho)
        self.T = 2.0 / self.c          # one full period of the sin(pi t / T) factor ... shortened run
        self.end_time = float(spec.get("end_time", 0.5 * self.T))
        self.mu, self.lam = self.E / 2.0, 0.0

    def config(self):
        return dict(name=self.name, dim=1, precision="f64", arch="cpu",
                    domain=dict(lower=[0.0], upper=[1.0], dx=1 / 16, boundaries=dict(default="sticky")),
                    solver=dict(basis="quadratic", transfer="apic", cfl=0.4, end_time=self.end_time),
                    materials=dict(m=dict(model="neo_hookean", E=self.E, nu=0.0, density=self.rho)),
                    bodies=[dict(name="bar", shape=dict(type="box", lower=[0.0], upper=[1.0]), material="m",
                                 particles_per_cell=2)])

    def _u(self, X, t):
        return self.A * np.sin(np.pi * X) * np.sin(np.pi * t / self.T)

    def body_force(self, X0, t):
        X = X0[:, 0]
        w = np.pi / self.T
        s, c = np.sin(np.pi * X), np.cos(np.pi * X)
        u_tt = -w * w * self.A * s * math.sin(w * t)
        F = 1.0 + self.A * np.pi * c * math.sin(w * t)
        dF = -self.A * np.pi**2 * s * math.sin(w * t)
        dP = self.mu * (1.0 + 1.0 / F**2) + self.lam * (1.0 - np.log(F)) / F**2
        return (u_tt - dP * dF / self.rho)[:, None]

    def setup(self, sim):
        X = sim.particles()["x"][:, 0]
        self.X = X
        sim.set_particles(v=(self.A * np.pi / self.T * np.sin(np.pi * X))[:, None])

    def errors(self, sim):
        x = sim.particles()["x"][:, 0]
        e = x - (self.X + self._u(self.X, sim.time))
        return dict(error_rms=float(np.sqrt(np.mean(e**2))), error_max=float(np.max(np.abs(e))))


def mms1d(spec):
    return MMS1D(spec)


class Broken(MMS1D):
    """A valid config whose setup fails: the case must end as `error` with the message."""

    def setup(self, sim):
        raise RuntimeError("broken setup on purpose")


def broken(spec):
    return Broken(spec)


def mean_x(sim):
    """An observable of the user's own (`observe: study_problems:mean_x`): the particles' mean x position."""
    return float(sim.particles()["x"][:, 0].mean())
