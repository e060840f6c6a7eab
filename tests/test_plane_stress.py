"""geometry.plane: a 2D scene in plane strain (the default, eps_zz = 0) or plane stress
(sigma_zz = 0, freefem/material.idp's condensation), against a bar in uniaxial tension, whose
state P1 holds exactly, and against the GetFEM peer, which condenses the material itself."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pandas as pd
import pytest

from harness import cli
from harness.core.contract import ExitCode
from harness.core.errors import SceneError
from harness.core.layout import Layout
from harness.scene.material_constants import material_constants
from harness.scene.scene import load_scene
from physics_runs import CASES, DATA, solve

T = 1e6  # bar.toml's traction [N/m^2]
L = 2.0  # its length [m]
# Brass (freefem/materials/Brass.idp): isotropic, C11 = lambda + 2 mu, C12 = lambda.
LAMBDA, MU = 69.75e9, (155.25e9 - 69.75e9) / 2
YOUNG, POISSON = MU * (3 * LAMBDA + 2 * MU) / (LAMBDA + MU), LAMBDA / (2 * (LAMBDA + MU))
# A uniform state solved to newton.rtol = 1e-9: round-off relative to the load (measured 8e-15).
ROUND_OFF = 1e-10


def bar(tmp_path: Path, plane: str, *overrides: str) -> tuple[dict[str, np.ndarray], np.ndarray]:
    solve(DATA / "bar.toml", 4, tmp_path, f'geometry.plane="{plane}"', *overrides)
    mesh = meshio.read(tmp_path / "bar" / "n4" / "solution.vtu")
    return ({k: np.asarray(v[0]).reshape(len(v[0]), -1)[:, 0] for k, v in mesh.cell_data.items()},
            np.asarray(mesh.point_data["u"]))


@pytest.mark.parametrize("plane, strain_xx, sigma_zz", [
    ("stress", T / YOUNG, 0.0),                           # sigma_xx = E eps_xx
    ("strain", T * (1 - POISSON**2) / YOUNG, POISSON * T),  # sigma_xx = E / (1 - nu^2) eps_xx
])
def test_a_bar_in_tension_stretches_by_the_plane_s_modulus(tmp_path, plane, strain_xx, sigma_zz):
    cells, u = bar(tmp_path, plane)
    assert np.allclose(cells["stress_xx"], T, rtol=0, atol=ROUND_OFF * T)
    assert np.allclose(cells["stress_yy"], 0, atol=ROUND_OFF * T)
    assert np.allclose(cells["stress_zz"], sigma_zz, rtol=0, atol=ROUND_OFF * T)
    assert u[:, 0].max() == pytest.approx(strain_xx * L, rel=1e-9)


def test_an_anisotropic_bar_in_plane_stress_is_in_uniaxial_stress(tmp_path):
    """BaTiO3 pulled along x: plane stress leaves sigma_xx alone, so eps_xx = s11 T with s the 3D
    compliance C^-1 (material axis 1 = x); plane strain holds eps_22 = 0: eps_xx = (s11 - s12^2/s22) T."""
    c = material_constants("BaTiO3", Layout(results=tmp_path))
    full = np.array([[c["f11"], c["fC12"], c["f13"]], [c["fC12"], c["fC22"], c["fC23"]], [c["f13"], c["fC23"], c["f33"]]])
    s = np.linalg.inv(full)  # the normal block: the shears decouple for class 6mm
    _, u = bar(tmp_path / "stress", "stress", 'scene.material="BaTiO3"')
    assert u[:, 0].max() == pytest.approx(s[0, 0] * T * L, rel=1e-9)
    _, u = bar(tmp_path / "strain", "strain", 'scene.material="BaTiO3"')
    assert u[:, 0].max() == pytest.approx((s[0, 0] - s[0, 1] ** 2 / s[1, 1]) * T * L, rel=1e-9)


def test_plane_stress_constants_are_the_condensed_ones(tmp_path):
    """sigma_22 = 0 condensed out (docs/model.md section 8): the out-of-plane row vanishes and the
    in-plane constants follow C*_ij = C_ij - C_i2 C_2j / C_22 and its piezoelectric, dielectric,
    thermal and pyroelectric companions, for every library material."""
    layout = Layout(results=tmp_path)
    for name in ("BaTiO3", "PZT-4", "PZT-5A", "PZT-5H", "Brass", "Alumina"):
        a, b = material_constants(name, layout), material_constants(name, layout, (), 2, "stress")
        c22 = a["fC22"]
        assert b["f11"] == pytest.approx(a["f11"] - a["fC12"] ** 2 / c22, rel=1e-14)
        assert b["f13"] == pytest.approx(a["f13"] - a["fC12"] * a["fC23"] / c22, rel=1e-14)
        assert b["f33"] == pytest.approx(a["f33"] - a["fC23"] ** 2 / c22, rel=1e-14)
        assert b["f44"] == a["f44"]
        assert b["e31"] == pytest.approx(a["e31"] - a["e32"] * a["fC12"] / c22, rel=1e-14, abs=1e-14)
        assert b["e33"] == pytest.approx(a["e33"] - a["e32"] * a["fC23"] / c22, rel=1e-14, abs=1e-14)
        assert b["b33"] == pytest.approx(a["b33"] + a["e32"] ** 2 / c22, rel=1e-14)
        assert b["m11"] == pytest.approx(a["m11"] - a["fC12"] * a["m22"] / c22, rel=1e-14)
        assert b["p3"] == pytest.approx(a["p3"] - a["e32"] * a["m22"] / c22, rel=1e-14, abs=1e-20)
        assert (b["fC12"], b["fC22"], b["fC23"], b["e32"], b["m22"]) == (0, 0, 0, 0, 0)
        assert (b["k11"], b["k33"], b["b11"]) == (a["k11"], a["k33"], a["b11"])


def test_plane_strain_is_the_default_and_leaves_the_table_as_it_was():
    scene = load_scene(CASES / "paper.toml")
    assert scene.plane == "strain" and scene.plane_macros() == {}
    assert "plane" not in scene.table["geometry"]  # summary.json and the cache keys unchanged
    explicit = load_scene(CASES / "paper.toml", ['geometry.plane="strain"'])
    assert explicit.table == scene.table
    assert load_scene(CASES / "paper.toml", ['geometry.plane="stress"']).plane_macros() == {"PLANESTRESS": "1"}


def test_a_bad_plane_or_a_3d_plane_is_refused_naming_the_case(tmp_path, capsys):
    with pytest.raises(SceneError, match="paper.toml.*plane"):
        load_scene(CASES / "paper.toml", ['geometry.plane="membrane"'])
    with pytest.raises(SceneError, match="no such key 'geometry.plane'"):
        load_scene(CASES / "paper3d.toml", ['geometry.plane="stress"'])
    code = cli.main(["solve", str(CASES / "disc_pad.toml"), "--n", "2", "--set", 'geometry.plane="stress"',
                     "--results", str(tmp_path)])
    assert code == ExitCode.INPUT
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "disc_pad.toml" in err and "3D" in err
    assert not (tmp_path / "disc_pad").exists()


def test_the_peer_condenses_plane_stress_alike(tmp_path):
    """Both codes in plane stress on the paper's scene (every effect) and the bimorph (three
    regions, two polings): FreeFEM's material.idp and the peer's numpy condensation agree as in
    plane strain (docs/crosscheck.md)."""
    for case, agree in (("paper.toml", 1e-9), ("bimorph.toml", 1e-8)):  # the thin bimorph's is 1e-8 (docs/crosscheck.md)
        out = tmp_path / case
        code = cli.main(["crosscheck", str(CASES / case), "--levels", "2,4", "--set", 'geometry.plane="stress"',
                         "--results", str(out / "results"), "--out", str(out / "out")])
        assert code == 0
        table = pd.read_csv(out / "out" / "crosscheck.csv")
        columns = [c for c in table.columns if c.startswith("rel_") and c.split("_")[1] in ("u", "phi", "theta")]
        assert (table[columns].to_numpy() <= agree).all()
        spec = (out / "results" / "crosscheck" / "runs").rglob("problem.json")
        assert all('"plane": "stress"' in p.read_text() for p in spec)
