"""The step's kernel package (taichi_mpm/step/): the features as a frozen description, and the extensions' moments
(which run, in which order, what they declare)."""
import dataclasses

import numpy as np
import pytest

import taichi_mpm as tm
from taichi_mpm.step import Features
from taichi_mpm.step.extensions import ColouredScatter, DualDomainFill, Extension, VolumeAverage, Walls
from conftest import make_cfg


def test_features_are_frozen_attributes():
    sim = tm.Simulation(make_cfg(2, transfer="flip", update="musl"))
    f = sim.feat
    assert isinstance(f, Features)
    assert (f.flip, f.musl, f.apic, f.grips) == (True, True, False, False)
    with pytest.raises(TypeError):
        f["flip"]   # no lookup by name: every reader takes the attribute
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.flip = False


class Recorder(Extension):
    """Records the moments the solver calls, in order."""

    def __init__(self):
        self.calls = []

    def bytes_per_particle(self):
        return 3

    def before_p2g(self):
        self.calls.append("before_p2g")

    def after_g2p(self):
        self.calls.append("after_g2p")

    def particles_set(self, names):
        self.calls.append(("particles_set", tuple(sorted(names))))


def test_extensions_of_a_scene_and_their_moments():
    """ddmp with F-bar on the CPU: the nodal-volume pre-pass, the coloured scatter, F-bar; their memory is in
    bytes_per_particle. An extension added to the list takes part in every moment, in order."""
    sim = tm.Simulation(make_cfg(2, basis="ddmp", volumetric="fbar", scatter="coloured"))
    assert [type(e) for e in sim.extensions] == [DualDomainFill, ColouredScatter, VolumeAverage, Walls]
    assert [e.name for e in sim.extensions] == ["ddmp", "scatter", "fbar", "walls"] and sim.extension("crack") is None
    assert sim.extensions[1].p2g_passes == 4 and sim._p2g_passes == 4
    before = sim.bytes_per_particle
    assert before == sim._bytes_per_particle()
    rec = Recorder()
    sim.extensions.append(rec)
    assert sim._bytes_per_particle() == before + 3
    sim.step()
    sim.step()
    sim.set_particles(v=np.zeros((sim.n, 2)))
    assert rec.calls == ["before_p2g", "after_g2p"] * 2 + [("particles_set", ("v",))]
