"""Output files without a simulation: VTU round trip, PVD series (read by VTK, as ParaView does),
von Mises stress, diagnostics rows kept on resume, checkpoints, resume compatibility check."""
import numpy as np
import pytest

from taichi_mpm.io import files as io
from taichi_mpm.io.runner import config_changes


def state(dim, n=7, seed=1):
    rng = np.random.default_rng(seed)
    F = np.eye(dim) + 0.1 * rng.standard_normal((n, dim, dim))
    s = rng.standard_normal((n, dim, dim))
    s3 = rng.standard_normal((n, 3, 3))
    s3 = s3 + s3.transpose(0, 2, 1)
    s3[:, :dim, dim:] = s3[:, dim:, :dim] = 0  # plane strain / uniaxial strain: no out-of-plane shear
    p = dict(x=rng.random((n, dim)), v=rng.standard_normal((n, dim)), F=F, stress=s3[:, :dim, :dim].copy(), stress3=s3,
             mass=np.full(n, 0.5), volume=np.full(n, 0.1), body=np.arange(n) % 2, damage=rng.random(n))
    return io.derived_fields(p)


def test_von_mises_known_states():
    s = 3.0
    uniaxial = np.array([[[s, 0.0], [0.0, 0.0]]])
    shear = np.array([[[0.0, s], [s, 0.0]]])
    hydro = -2.0 * np.eye(3)[None]
    np.testing.assert_allclose(io.von_mises(uniaxial), [s], rtol=1e-14)
    np.testing.assert_allclose(io.von_mises(shear), [np.sqrt(3) * s], rtol=1e-14)
    np.testing.assert_allclose(io.von_mises(hydro), [0.0], atol=1e-14)
    np.testing.assert_allclose(io.von_mises(np.array([[[-4.0]]])), [4.0], rtol=1e-14)  # 1D: |sigma_xx|


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_vtu_round_trip(tmp_path, dim):
    p = state(dim)
    io.write_vtu(tmp_path / "particles_000000.vtu", p, fields=["F", "speed"])
    back = io.read_vtu(tmp_path / "particles_000000.vtu", dim)
    assert set(back) == {"x", "velocity", "stress", "stress3", "von_mises", "J", "body", "damage", "F", "speed"}
    np.testing.assert_allclose(back["x"], p["x"], rtol=1e-15)
    np.testing.assert_allclose(back["velocity"], p["v"], rtol=1e-15)
    np.testing.assert_allclose(back["stress"], p["stress"], rtol=1e-15)
    np.testing.assert_allclose(back["stress3"], p["stress3"], rtol=1e-15)  # the full tensor, sigma_zz included
    np.testing.assert_allclose(back["F"], p["F"], rtol=1e-15)
    np.testing.assert_allclose(back["J"], np.linalg.det(p["F"]), rtol=1e-14)
    np.testing.assert_array_equal(back["body"], p["body"])
    assert back["body"].dtype.kind == "i"


def test_pvd_series_is_read_by_vtk(tmp_path):
    pv = pytest.importorskip("pyvista")
    times = [0.0, 0.01, 0.02]
    entries = []
    for k, t in enumerate(times):
        p = state(2, seed=k)
        name = f"particles_{k:06d}.vtu"
        io.write_vtu(tmp_path / name, p)
        entries.append((t, name))
    io.write_pvd(tmp_path / "particles.pvd", entries)
    assert io.read_pvd(tmp_path / "particles.pvd") == entries
    assert [t for t, _ in io.series(tmp_path)] == times
    reader = pv.get_reader(str(tmp_path / "particles.pvd"))  # VTK's PVD reader, the one ParaView uses
    assert reader.time_values == times
    reader.set_active_time_value(0.02)
    block = reader.read()[0]
    assert block.n_points == 7 and "von_mises" in block.point_data
    np.testing.assert_allclose(block.points[:, :2], state(2, seed=2)["x"], rtol=1e-15)
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary files left


def test_checkpoint_round_trip(tmp_path):
    st = dict(x=np.random.rand(5, 2), v=np.random.rand(5, 2), F=np.random.rand(5, 2, 2), time=0.125, n_steps=17,
              dt=1e-3, vmax=2.5)
    io.save_checkpoint(tmp_path / "checkpoint.npz", st, {"next_output": 3, "config": {"a": [1, 2]}})
    back, meta = io.load_checkpoint(tmp_path / "checkpoint.npz")
    assert meta == {"next_output": 3, "config": {"a": [1, 2]}}
    assert back["time"] == 0.125 and back["n_steps"] == 17 and isinstance(back["n_steps"], int)
    np.testing.assert_array_equal(back["x"], st["x"])


def test_diagnostics_keeps_rows_on_resume(tmp_path):
    path = tmp_path / "diagnostics.csv"
    d = io.Diagnostics(path, 2)
    cols = io.diagnostics_columns(2)
    assert cols[:7] == ["time", "step", "dt", "kinetic", "strain", "gravity", "total"]
    assert "momentum_y" in cols and "cfl" in cols and "max_speed" in cols
    for k in range(4):
        d.append({c: float(k) for c in cols})
    io.Diagnostics(path, 2, keep=2)  # a resume from the checkpoint written after the second row
    rows = io.read_diagnostics(path)
    np.testing.assert_array_equal(rows["time"], [0.0, 1.0])


def test_resume_compatibility():
    old = {"name": "a", "solver": {"end_time": 1.0, "basis": "linear"}, "output": {"every": 0.1}, "dim": 2}
    assert config_changes(old, {**old, "solver": {"end_time": 2.0, "basis": "linear"}, "output": {"every": 1}}) == []
    assert config_changes(old, {**old, "solver": {"end_time": 1.0, "basis": "cubic"}}) == ["solver.basis"]
    assert config_changes(old, {**old, "dim": 3}) == ["dim"]


def test_npz_snapshot(tmp_path):
    p = state(3)
    io.write_npz(tmp_path / "particles_000000.npz", p, fields=["speed"])
    with np.load(tmp_path / "particles_000000.npz") as z:
        np.testing.assert_array_equal(z["x"], p["x"])
        np.testing.assert_array_equal(z["stress"], p["stress"])  # unpadded (N, 3, 3)
        np.testing.assert_allclose(z["speed"], np.linalg.norm(p["v"], axis=1))
        assert {"v", "F", "J", "von_mises", "body", "damage"} <= set(z.files)
