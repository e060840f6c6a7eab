"""Poling in any direction (scene.poling_axis): the material tensors rotated once, in
freefem/material.idp, with the Bond transformation, and the solutions it gives.

Known answers: the rotated tensors equal a full fourth-order tensor rotation done here in
numpy; the opposite poling with the opposite potentials gives the same displacement; a body
and its poling turned together give the turned solution; the default axis changes nothing."""

from __future__ import annotations

import importlib.util
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from harness.core import freefem
from harness.cli import main
from harness.core.contract import ExitCode, contract_path
from harness.core.errors import SceneError
from harness.measure.fields import read_state
from harness.core.layout import Layout
from harness.scene.materials import values as material_values
from harness.scene.poling import parse_poling
from physics_runs import CASES, DATA

LAYOUT = Layout()
PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))  # Voigt index -> tensor indices


def voigt_index() -> np.ndarray:
    index = np.zeros((3, 3), dtype=int)
    for k, (i, j) in enumerate(PAIRS):
        index[i, j] = index[j, i] = k
    return index


def rotate_by_tensors(values: dict, R: np.ndarray) -> dict[str, np.ndarray]:
    """The material's tensors in full index form, each index turned by R (column k = material
    axis k), back to Voigt: an independent check of the Bond matrices FreeFEM uses."""
    v = voigt_index()
    C = np.array(values["C"], float)[v[:, :, None, None], v[None, None, :, :]]
    e = np.array(values["e"], float)[:, v]
    m = np.array(values["m"], float)[v]
    C4 = np.einsum("ip,jq,kr,ls,pqrs->ijkl", R, R, R, R, C)
    e3 = np.einsum("ka,ib,jc,abc->kij", R, R, R, e)
    m2 = R @ m @ R.T
    rows, cols = zip(*PAIRS)
    return {"C": C4[rows, cols][:, rows, cols], "e": e3[:, rows, cols], "m": m2[rows, cols],
            "beta": R @ np.array(values["beta"], float) @ R.T, "k": R @ np.array(values["k"], float) @ R.T,
            "p": R @ np.array(values["p"], float)}


def freefem_rotated(material: str, axis: tuple[float, ...]) -> dict[str, np.ndarray]:
    """What material.idp makes of a material file for a scene poled along `axis`."""
    names = "XYZ"[:len(axis)]
    lines = [f"macro DIMENSION {len(axis)} //"]
    lines += [f"macro poling{c}() ({a!r}) //" for c, a in zip(names, axis)]
    lines += [f'include "{p}"' for p in (contract_path(), LAYOUT.material_file(material), LAYOUT.material_reduction_file())]
    lines.append("cout.precision(17);")
    for name in ("matR", "matC", "matE", "matBeta", "matK"):
        lines.append(f'for (int i = 0; i < {name}.n; ++i) for (int j = 0; j < {name}.m; ++j) '
                     f'cout << "{name} " << i << " " << j << " " << {name}(i, j) << endl;')
    for name in ("matM", "matP"):
        lines.append(f'for (int i = 0; i < {name}.n; ++i) cout << "{name} " << i << " 0 " << {name}[i] << endl;')
    with tempfile.TemporaryDirectory(prefix="ff-poling-") as tmp:
        script = Path(tmp) / "rotated.edp"
        script.write_text("\n".join(lines) + "\n")
        outcome = freefem.invoke(freefem.command(script, []), Path(tmp), timeout_s=60)
        text = (Path(tmp) / "stdout.txt").read_text()
    assert outcome.returncode == 0, text[-2000:]
    shapes = {"matR": (3, 3), "matC": (6, 6), "matE": (3, 6), "matBeta": (3, 3), "matK": (3, 3), "matM": (6, 1), "matP": (3, 1)}
    out = {name: np.full(shape, np.nan) for name, shape in shapes.items()}
    for line in text.splitlines():
        words = line.split()
        if len(words) == 4 and words[0] in out:
            out[words[0]][int(words[1]), int(words[2])] = float(words[3])
    return out


def as_material_frame(axis: tuple[float, ...]) -> np.ndarray:
    """The scene's axis in the 3D material frame: the 2D drawing's (x, y) are axes (1, 3)."""
    return np.array([axis[0], 0.0, axis[1]] if len(axis) == 2 else axis)


AXES = {
    "3D oblique": (0.48, -0.6, 0.64),
    "3D along x": (1.0, 0.0, 0.0),
    "3D opposite": (0.0, 0.0, -1.0),
    "3D near the opposite": (1e-9, 0.0, -math.sqrt(1 - 1e-18)),
    # Off the opposite by components whose squares are subnormal: summed as they are, n1^2 + n2^2
    # kept one bit of each, and R was not a rotation (R(0, 1) = -1, R(0, 0) = -1).
    "3D a subnormal way off the opposite": (3e-162, 1e-162, -1.0),
    "3D a subnormal way off the default": (3e-162, -1e-162, 1.0),
    "2D oblique": (0.6, 0.8),
    "2D along x": (1.0, 0.0),
    "2D opposite": (0.0, -1.0),
}


@pytest.mark.parametrize("name", list(AXES))
def test_the_bond_transformation_is_the_full_tensor_rotation(name):
    axis = AXES[name]
    got = freefem_rotated("PZT-5H", axis)
    R = got["matR"]
    # A proper rotation taking the poling axis 3 onto the scene's axis; in 2D about axis 2.
    assert R.T @ R == pytest.approx(np.eye(3), abs=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    assert R[:, 2] == pytest.approx(as_material_frame(axis), abs=1e-15)
    if len(axis) == 2:
        assert R[:, 1] == pytest.approx([0.0, 1.0, 0.0], abs=1e-15)
    want = rotate_by_tensors(material_values(LAYOUT.material_file("PZT-5H")), R)
    # Round-off of a sum of 4^4 products (einsum) against FreeFEM's Bond matrices: measured
    # <= 3e-16 of each tensor's largest entry.
    for key, ff in (("C", "matC"), ("e", "matE"), ("beta", "matBeta"), ("k", "matK")):
        scale = np.abs(want[key]).max()
        assert got[ff] == pytest.approx(want[key], abs=1e-14 * scale), key
    assert got["matM"][:, 0] == pytest.approx(want["m"], abs=1e-14 * np.abs(want["m"]).max())
    assert got["matP"][:, 0] == pytest.approx(want["p"], abs=1e-14 * np.abs(want["p"]).max())


def test_a_poling_axis_is_a_signed_name_or_a_vector():
    assert parse_poling("", 2).axis == (0.0, 1.0) and parse_poling("", 2).is_default
    assert parse_poling("-z", 3).axis == (0.0, 0.0, -1.0)
    assert parse_poling("+x", 2).axis == (1.0, 0.0)
    assert parse_poling([0.0, 2.0], 2).is_default and parse_poling([0, 0, 1], 3).is_default
    assert parse_poling([3.0, 4.0], 2).axis == pytest.approx((0.6, 0.8))
    assert parse_poling("-y", 2).macros() == {"polingX": "0.0", "polingY": "-1.0"}
    assert parse_poling("z", 3).macros() == {}


@pytest.mark.parametrize("given, same_as", [
    ([3e-162, 0.0], [1.0, 0.0]),           # its square keeps one bit: it was the axis (0.95, 0)
    ([1e200, 1e200], [1.0, 1.0]),          # its square is inf: it was the axis (0, 0)
    ([1e-320, -1e-320], [1.0, -1.0]),      # subnormal entries
    ([1e300, -2e300, 5e299], [1.0, -2.0, 0.5]),
    ([0.0, 0.0, 5e-324], [0.0, 0.0, 1.0]),  # the smallest double: the default axis
])
def test_a_poling_axis_of_any_finite_size_is_scaled_before_its_length_is_taken(given, same_as):
    """The axis is scaled by a power of two before its squares are summed, as hypot does; a
    vector whose squares are normal numbers gives the doubles it gave before (checked on every
    vector of the case files and tests, harness/scene/poling.py unit)."""
    axis, want = parse_poling(given, len(given)).axis, parse_poling(same_as, len(same_as)).axis
    assert axis == pytest.approx(want, abs=2.0 ** -52)  # one ulp of the rounded division
    assert math.fsum(x * x for x in axis) == pytest.approx(1.0, abs=4 * 2.0 ** -52)
    assert parse_poling([3e-162, 0.0], 2).axis == (1.0, 0.0) and parse_poling([0.0, 2.0], 2).is_default


def peer_rotation():  # noqa: ANN201 (a module)
    """peer_getfem/rotation.py, the GetFEM peer's own rotation (numpy only), imported by its path."""
    path = Path(__file__).parents[1] / "peer_getfem" / "rotation.py"
    spec = importlib.util.spec_from_file_location("peer_rotation", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("given, same_as", [
    ((1e200, 0.0, 1e200), (1.0, 0.0, 1.0)),
    ((3e-162, 0.0, 0.0), (1.0, 0.0, 0.0)),
    ((3e-162, 1e-162, -1.0), None),  # off the opposite by a subnormal amount: the axis (3, 1, 0) turns it
])
def test_the_peers_rotation_scales_the_axis_before_its_length_is_taken(given, same_as):
    rotation = peer_rotation().rotation
    R = rotation(np.array(given))
    assert R.T @ R == pytest.approx(np.eye(3), abs=1e-15) and np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    if same_as is None:
        assert R[:, 2] == pytest.approx(given, abs=1e-15)
        # The half turn about the unit vector along 3 x n = (-1, 3, 0)/sqrt(10): R = 2 a a^T - I.
        a = np.array([-1.0, 3.0, 0.0]) / math.sqrt(10.0)
        assert R == pytest.approx(2.0 * np.outer(a, a) - np.eye(3), abs=1e-15)
    else:
        assert np.array_equal(R, rotation(np.array(same_as)))


@pytest.mark.parametrize("given, same_as", [("[1e200, 1e200]", "[1.0, 1.0]"), ("[3e-162, 0.0]", '"x"')])
def test_a_huge_or_tiny_poling_axis_solves_as_its_direction(tmp_path, given, same_as):
    """The PZT-5H layer between electrodes (tests/data/layer.toml) poled along an axis of 1e200
    or 3e-162: the solution of its direction. Before, [1e200, 1e200] was refused as a material
    that is not positive definite (exit 2), and [3e-162, 0] poled along (0.95, 0) (exit 0)."""
    states = [solve(DATA / "layer.toml", 2, tmp_path / name, f"scene.poling_axis={axis}")
              for name, axis in (("given", given), ("direction", same_as))]
    for a, b in zip(*states):
        # The same axis to the last bit or to one ulp: the same solve (measured identical).
        assert a == pytest.approx(b, abs=1e-12 * max(np.abs(b).max(), 1e-300))
    assert np.abs(states[0][1]).max() > 1.0  # phi: the electrodes' 100 V


@pytest.mark.parametrize("value, message", [
    ([0.0, 0.0], "has zero length"),
    ([float("nan"), 1.0], "is not a finite number"),
    ("z", "names no axis of a 2D scene"),
    ([1.0, 0.0, 0.0], "is not a vector of 2 numbers"),
    ("w", "names no axis"),
])
def test_a_bad_poling_axis_is_named(value, message):
    with pytest.raises(SceneError, match=message):
        parse_poling(value, 2)


@pytest.mark.parametrize("value, message", [("[0, 0]", "has zero length"), ("[nan, 1.0]", "is not a finite number"),
                                            ('"z"', "names no axis of a 2D scene")])
def test_a_bad_poling_axis_ends_in_one_line_and_exit_2(tmp_path, capsys, value, message):
    code = main(["solve", str(DATA / "layer.toml"), "--n", "2", "--results", str(tmp_path),
                 "--set", f"scene.poling_axis={value}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.INPUT == 2
    assert len(err) == 1 and "scene.poling_axis" in err[0] and message in err[0], err
    assert not any(tmp_path.iterdir())


def state(results: Path, name: str, n: int) -> tuple[np.ndarray, ...]:
    return read_state(results / name / f"n{n}" / "state.txt")


def solve(case: Path, n: int, results: Path, *overrides: str) -> tuple[np.ndarray, ...]:
    argv = ["solve", str(case), "--n", str(n), "--results", str(results)]
    for item in overrides:
        argv += ["--set", item]
    assert main(argv) == 0, overrides
    return state(results, case.stem, n)


@pytest.mark.parametrize("case, n, axis", [(CASES / "paper.toml", 4, '"-y"'), (CASES / "paper3d.toml", 2, '"-z"')])
def test_the_opposite_poling_with_opposite_potentials_gives_the_same_displacement(tmp_path, case, n, axis):
    """Flipping the poling flips e and p (a half turn about axis 2); with phi -> -phi every
    equation holds again (the foundation's potential flipped too), so u and theta are the
    same and phi is opposite: the paper's scene, with contact, friction and both contact
    conductances active."""
    u, phi, theta = solve(case, n, tmp_path / "a")
    u2, phi2, theta2 = solve(case, n, tmp_path / "b", f"scene.poling_axis={axis}", "electric_contact.phi_f=44.0")
    # Round-off of two Newton solves (measured below 1e-12 relative on each field).
    assert u2 == pytest.approx(u, abs=1e-10 * np.abs(u).max())
    assert phi2 == pytest.approx(-phi, abs=1e-10 * np.abs(phi).max())
    assert theta2 == pytest.approx(theta, abs=1e-10 * np.abs(theta).max())
    assert np.abs(phi).max() > 1.0 and np.abs(u).max() > 0.0


def test_a_driven_layer_poled_the_other_way_moves_the_other_way(tmp_path):
    """No mechanical load: the flipped coupling flips u, with the same potential."""
    u, phi, theta = solve(DATA / "layer.toml", 4, tmp_path / "a")
    u2, phi2, theta2 = solve(DATA / "layer.toml", 4, tmp_path / "b", 'scene.poling_axis="-y"')
    assert np.abs(u).max() > 1e-9
    assert u2 == pytest.approx(-u, abs=1e-12 * np.abs(u).max())
    assert phi2 == pytest.approx(phi, abs=1e-12 * np.abs(phi).max())


# The turned scenes below: one scene and its loads, on a square (2D) or a cube (3D).
SCENE = """
[scene]
name = "{name}"
material = "PZT-5H"
effects = ["piezoelectric", "thermal", "pyroelectric"]
initial_guess = "zero"
poling_axis = "{poling}"
"""
LOADS = """
[loads]
electrode_potential = 100.0
heat_source = 1e4

[newton]
max_iterations = 40
rtol = 1e-9

[study]
levels = [2, 4]
slope_band = [0.5, 1.5]
"""
SQUARE = SCENE + """
[geometry]
kind = "rectangle"
width = 1.0
height = 1.0
bottom = [[0.0, 1.0, "{bottom}"]]
top = [[0.0, 1.0, "{top}"]]
left = "{left}"
right = "{right}"
diagonals = "SW-NE"
""" + LOADS
BOX = SCENE + """
[geometry]
kind = "box"
lx = 1.0
ly = 1.0
lz = 1.0
x0 = "{x0}"
x1 = "{x1}"
y0 = "{y0}"
y1 = "{y1}"
z0 = "{z0}"
z1 = "{z1}"
""" + LOADS


def nodes(points: np.ndarray, n: int) -> list[tuple[int, ...]]:
    """Each node as integer multiples of h (solution.vtu stores coordinates in single precision)."""
    return [tuple(int(round(c * n)) for c in p) for p in points]


def turned_pair(tmp_path: Path, text: str, first: dict, second: dict, n: int, turn: np.ndarray):
    """Both scenes solved at level n; the second scene is the first turned by `turn` (an
    orthogonal matrix mapping the unit square or cube onto itself, and its mesh onto its
    mesh). Returns each field of the first beside the second's at the turned nodes, turned
    back: u_first(p) = turn^T u_second(turn p)."""
    from physics_runs import solve as solved

    d = turn.shape[0]
    fields = []
    for name, values in (("first", first), ("second", second)):
        case = tmp_path / f"{name}.toml"
        case.write_text(text.format(name=name, **values))
        run = solved(case, n, tmp_path / "results")
        u, phi, theta = state(tmp_path / "results", name, n)
        fields.append((nodes(run.fields.points[:, :d], n), u.reshape(-1, d), phi, theta))
    (pa, ua, phia, thetaa), (pb, ub, phib, thetab) = fields
    where = {p: i for i, p in enumerate(pb)}
    index = [where[tuple(int(c) for c in turn @ np.array(p))] for p in pa]
    return (ua, ub[index] @ turn), (phia, phib[index]), (thetaa, thetab[index])


def assert_same(pairs) -> None:
    for first, second in pairs:
        scale = np.abs(first).max()
        assert scale > 0.0
        # Two solves of the same equations in another node order: round-off of the sparse
        # solver's pivoting (measured below 1e-13 of each field's largest value).
        assert second == pytest.approx(first, abs=1e-10 * scale)


def test_a_square_and_its_poling_mirrored_give_the_mirrored_solution(tmp_path):
    """x <-> y maps the square and its SW-NE diagonals onto themselves. It is a reflection,
    but a 6mm ceramic is symmetric under the mirror through its poling axis, so the poling
    along x (a quarter turn about axis 2) is the mirrored poling along y: clamped (and
    earthed) below and driven above becomes clamped left and driven right. The turned law
    has the in-plane couplings of the rotated tensors (e11, e13, e35)."""
    swap = np.array([[0.0, 1.0], [1.0, 0.0]])
    first = dict(poling="y", bottom="clamped", top="electrode", left="free", right="free")
    second = dict(poling="x", left="clamped", right="electrode", bottom="free", top="free")
    assert_same(turned_pair(tmp_path, SQUARE, first, second, 4, swap))


def test_a_cube_and_its_poling_turned_give_the_turned_solution(tmp_path):
    """The cyclic turn (x, y, z) -> (z, x, y) maps the cube and its Kuhn tetrahedra onto
    themselves and the poling z onto x. The turned frame and material.idp's (the quarter
    turn about y) differ by a turn about the poling axis, which leaves a transversely
    isotropic ceramic (PZT-5H: C66 = (C11 - C12)/2) unchanged."""
    turn = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    first = dict(poling="z", x0="free", x1="free", y0="free", y1="free", z0="clamped", z1="electrode")
    second = dict(poling="x", y0="free", y1="free", z0="free", z1="free", x0="clamped", x1="electrode")
    assert_same(turned_pair(tmp_path, BOX, first, second, 2, turn))


@pytest.mark.parametrize("case, axis", [("bulk", "[0.6, 0.8]"), ("bulk3d", "[0.48, -0.6, 0.64]")])
def test_linear_manufactured_fields_are_reproduced_with_an_oblique_poling(tmp_path, case, axis):
    """Linear exact fields are P1 functions: with every entry of the rotated tensors in the
    law (harness/scene/mms.py derives the data with its own Voigt sums, freefem/constitutive.idp
    assembles its `rotated` terms), the discrete solution is their interpolant to round-off.
    A wrong sign on any one rotated entry leaves an O(1) error."""
    from harness.core.layout import Layout as ResultsLayout
    from harness.scene.scene import load_scene
    from harness.study.verification import mms_errors

    linear = {"u1": "1e-8*(1.6 - 0.4*x + 0.3*y)", "u2": "1e-8*(0.6 - 0.4*x + 0.5*y)",
              "phi": "30 - 12*x + 20*y", "theta": "1e-3*(0.5 + 0.2*x - 0.6*y)"}
    if case == "bulk3d":
        linear = {k: v.replace("*y)", "*y - 0.2*z)").replace("20*y", "20*y + 15*z") for k, v in linear.items()}
        linear["u3"] = "1e-8*(0.3 + 0.2*x - 0.1*y + 0.4*z)"
    scene = load_scene(CASES / "mms" / f"{case}.toml", [f'manufactured.{k}="{v}"' for k, v in linear.items()]
                       + [f"scene.poling_axis={axis}", f'scene.name="{case}_poled"'])
    assert not scene.poling.is_default
    n = 4 if case == "bulk" else 2
    table = mms_errors(scene, (n,), ResultsLayout(results=tmp_path), jobs=1, progress=lambda line: None)
    # As tests/test_mms.py's P1 case: the LU's round-off (measured 1e-15 ... 1e-13).
    assert (table["relative_error"] < 1e-10).all(), table.to_string()
