"""The singular displacement of plane elasticity at a re-entrant corner: Williams' mode-I
eigenfunction of a wedge with traction-free faces, the displacement known answer of the adaptive
loop on the L-shaped domain (cases/mms/lshape_u.toml, docs/adaptivity.md).

The wedge has its vertex at the origin and its faces along the polar angles 0 and 2 omega (the
L-shape of cases/geo/lshape.geo: omega = 3 pi / 4). With theta = phi - omega, the angle from the
wedge's bisector, the symmetric (mode-I) field of an isotropic body in plane strain is

    u_xi  = A r^lam [(kappa - Q (lam + 1)) cos(lam theta) - lam cos((lam - 2) theta)]
    u_eta = A r^lam [(kappa + Q (lam + 1)) sin(lam theta) + lam sin((lam - 2) theta)]

in the frame (xi along the bisector, eta across it), with kappa = 3 - 4 nu and
Q = -cos((lam - 1) omega) / cos((lam + 1) omega). It has no body force, and the faces
theta = +-omega carry no traction exactly when lam is a root of Williams' characteristic equation

    sin(2 omega lam) + lam sin(2 omega) = 0

(M. L. Williams, "Stress singularities resulting from various boundary conditions in angular
corners of plates in extension", J. Appl. Mech. 19 (1952) 526-528). The field and the values
lam = 0.544483737, Q = 0.543075579 at omega = 3 pi / 4 are those of the L-shaped benchmark of
B. Szabo and I. Babuska, Finite Element Analysis, Wiley 1991. Its strain grows like r^(lam - 1),
so the energy norm of P1's error on uniform meshes falls as h^lam = N^(-lam/2) only.

The exponent is computed here, not copied; tests/test_adapt.py checks the field against the
equations it must solve (zero body force, free faces) symbolically.
"""

from __future__ import annotations

import math

import mpmath
import sympy

# Bracketing step of the root scan: the mode-I root of a re-entrant corner lies in (1/2, 1),
# and no two roots of the characteristic equation in (0, 1] are closer than this.
SCAN_STEP = 1e-3
# Relative departure from isotropy the eigenfunction tolerates: the material's round-off.
ISOTROPY_RTOL = 1e-12


def williams_exponent(omega: float) -> float:
    """The smallest positive root lam of sin(2 omega lam) + lam sin(2 omega) = 0 (the trivial
    lam = 0 left out): the mode-I exponent of a wedge of half-angle omega (in (0, pi])."""
    if not 0 < omega <= math.pi:
        raise ValueError(f"a wedge's half-angle is in (0, pi], not {omega}")

    def characteristic(lam: mpmath.mpf) -> mpmath.mpf:
        return mpmath.sin(2 * omega * lam) + lam * mpmath.sin(2 * omega)

    # Near 0 the function is lam (2 omega + sin 2 omega) > 0: scan up to its first sign change.
    with mpmath.workdps(30):
        for step in range(1, round(2 / SCAN_STEP)):
            low, high = mpmath.mpf(step) * SCAN_STEP, mpmath.mpf(step + 1) * SCAN_STEP
            if characteristic(low) * characteristic(high) <= 0:
                return float(mpmath.findroot(characteristic, (low, high), solver="anderson"))
    raise ValueError(f"no mode-I exponent in (0, 2) for the half-angle {omega}")


def plane_strain_poisson(f11: float, f13: float, f33: float, f44: float) -> float:
    """Poisson's ratio of a material that is isotropic in the plane of the 2D model (axes 1
    and 3), from its plane-strain constants; a ValueError for one that is not."""
    if abs(f33 - f11) > ISOTROPY_RTOL * f11 or abs(f11 - f13 - 2 * f44) > ISOTROPY_RTOL * f11:
        raise ValueError(f"the material is not isotropic in the plane (f11 {f11:g}, f33 {f33:g}, "
                         f"f13 {f13:g}, f44 {f44:g}: isotropy needs f11 = f33 = f13 + 2 f44)")
    return f13 / (2 * (f13 + f44))


def mode1_displacement(x: sympy.Symbol, y: sympy.Symbol, opening: sympy.Expr, nu: float,
                       amplitude: sympy.Expr) -> tuple[sympy.Expr, sympy.Expr]:
    """(u_x, u_y) of the mode-I field above for the wedge whose faces are the polar angles 0
    and `opening` = 2 omega, as expressions in x and y."""
    omega = sympy.nsimplify(opening) / 2
    lam = sympy.Float(williams_exponent(float(omega)), 17)
    kappa = 3 - 4 * sympy.Float(nu, 17)
    q = -sympy.cos((lam - 1) * omega) / sympy.cos((lam + 1) * omega)
    c, s = sympy.cos(omega), sympy.sin(omega)
    # atan2 of the coordinates turned onto the bisector: its cut lies outside the wedge.
    theta = sympy.atan2(-x * s + y * c, x * c + y * s)
    radial = amplitude * (x ** 2 + y ** 2) ** (lam / 2)
    u_xi = radial * ((kappa - q * (lam + 1)) * sympy.cos(lam * theta) - lam * sympy.cos((lam - 2) * theta))
    u_eta = radial * ((kappa + q * (lam + 1)) * sympy.sin(lam * theta) + lam * sympy.sin((lam - 2) * theta))
    return u_xi * c - u_eta * s, u_xi * s + u_eta * c
