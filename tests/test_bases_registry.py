"""The bases registry (bases/registry.py): each declaration agrees with the shape functions its factory builds, the
tools' lists and the config's messages come from it, and config validation reads it without importing Taichi."""
import subprocess
import sys

import pytest

import taichi_mpm as tm
from conftest import make_cfg
from taichi_mpm.bases import registry
from taichi_mpm.bases.shape_functions import make_basis


@pytest.mark.parametrize("name", registry.BUILT_IN)
def test_declaration_matches_its_shape_functions(name):
    spec, basis = registry.get(name), make_basis(name)
    assert basis.spec is spec and basis.name == name
    assert basis.stencil == spec.stencil and basis.kind == spec.stencil_kind
    n = 8
    nodes = {"bspline": n + spec.degree, "ghost": n + 3,   # ghost: one node past each wall
             "staggered": 2 * n + 3}                     # every half cell, and B's ghost past each wall
    assert basis.nodes(n) == nodes[spec.grid] and spec.nodes_per_cell == (2 if spec.grid == "staggered" else 1)
    assert basis.ghost == (0 if spec.grid == "bspline" else 1)


def test_what_the_built_in_bases_declare():
    assert registry.names() == ("linear", "gimp", "quadratic", "cubic", "cpdi", "ddmp", "ck")
    assert registry.swept() == ("linear", "gimp", "quadratic", "cubic")   # advise, the GUI switch, the CFL table
    assert registry.names(knots=True) == ("linear", "quadratic", "cubic")
    assert registry.names(map=True) == ("quadratic", "cubic")
    assert registry.names(particle_domains=True) == ("gimp", "cpdi")
    assert registry.names(fbar_linear_grid=True) == ("quadratic", "cubic", "ck")
    assert registry.names(crack=None) == ("linear", "gimp", "quadratic", "cubic", "cpdi", "ck")
    assert registry.names(coloured_scatter=True) == ("linear", "gimp", "quadratic", "cubic", "ddmp", "ck")
    assert registry.names(wall_layer=True) == ("linear", "quadratic", "cubic")
    assert registry.names(prepass_grid=True) == ("ddmp",)
    assert {registry.get(n).cfl_factor for n in registry.names()} == {1.0}
    assert registry.get(registry.DEFAULT).name == tm.load_config(make_cfg(2)).solver.basis == "quadratic"


def test_registration_rules():
    with pytest.raises(ValueError, match="registered already"):
        registry.register(registry.get("linear"))
    with pytest.raises(ValueError, match="built in"):
        registry.unregister("cubic")
    with pytest.raises(ValueError, match="grid must be one of"):
        registry.Spec("odd", "", "x:y", 1, 2, "hexagonal")
    with pytest.raises(ValueError, match="cfl_factor must be positive"):
        registry.Spec("odd", "", "x:y", 1, 2, "bspline", cfl_factor=0.0)


@pytest.mark.parametrize("change, key, message", [
    (dict(scatter="coloured", basis="cpdi"), "solver.scatter",
     "coloured needs a basis whose stencil is a bounded box of nodes, on a box grid (linear, gimp, quadratic, cubic, "
     "ddmp, ck): cpdi's particle "
     "domains and a mapped grid's stencil can reach any node, so they add atomically (scatter: auto)"),
    (dict(basis="linear", gimp_domain="deforming"), "solver.gimp_domain",
     "is read by solver.basis gimp only (the basis is linear): remove it or use basis gimp"),
    (dict(basis="gimp", cpdi=dict(variant="cpdi2")), "solver.cpdi",
     "is read by solver.basis cpdi only (the basis is gimp): remove it or use basis cpdi"),
    (dict(basis="cpdi", transfer="asflip", cpdi=dict(variant="cpdi2")), "solver.transfer",
     "asflip's position correction moves particles off their cpdi2 domain's centroid; use apic or flip with cpdi2, "
     "or cpdi1"),
])
def test_messages_read_from_the_declarations(change, key, message):
    cfg = make_cfg(2)
    cfg["solver"].update(change)
    with pytest.raises(tm.ConfigError) as e:
        tm.load_config(cfg)
    assert e.value.key == key and e.value.message == message


def test_crack_and_knot_refusals_name_the_supporting_bases():
    cfg = make_cfg(2, basis="ddmp")
    cfg["crack"] = {}
    with pytest.raises(tm.ConfigError, match=r"does not support basis ddmp: two interface blocks pulled apart kept "
                                             r"only 0.185 .*; use linear, gimp, quadratic, cubic, cpdi or ck with "
                                             r"a crack section"):
        tm.load_config(cfg)
    cfg = make_cfg(2, basis="gimp")
    cfg["domain"]["knots"] = dict(x=[0.0, 0.0, 0.5, 1.0, 1.0])
    with pytest.raises(tm.ConfigError, match=r"knot vectors need a B-spline basis \(linear, quadratic or cubic\), "
                                             r"not solver.basis gimp"):
        tm.load_config(cfg)


def test_config_validation_reads_the_registry_without_taichi():
    code = ("import sys, taichi_mpm.bases.registry, taichi_mpm.config; "
            "assert 'taichi' not in sys.modules, 'taichi imported'")
    subprocess.run([sys.executable, "-c", code], check=True)
