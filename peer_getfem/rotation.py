"""A material poled along another axis: its tensors turned into the scene's axes.

The material file gives C, e, beta, k, m, p in its own axes, axis 3 the poling (docs/model.md
section 9). Poled along the unit vector n of the scene, axis 3 is turned onto n by the
rotation about e3 x n (the opposite poling, n = -e3, by the half turn about axis 2). A
ceramic is transversely isotropic about its poling, so the axis alone fixes the turned
tensors.

Written from that definition, not from freefem/material.idp: instead of the 6x6 Bond matrix,
each Voigt array is unfolded into its full tensor (C_ijkl, e_ijk, m_ij, with the engineering
shear of Voigt strains), turned index by index, and folded back.
"""

from __future__ import annotations

import numpy as np

# Voigt index -> the pair of tensor indices (11, 22, 33, 23, 13, 12).
PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


def length(v: np.ndarray) -> float:
    """|v|, v first scaled by the power of two that brings its largest entry into [0.5, 1), as
    hypot scales (np.linalg.norm sums the squares as they are: [1e200, 0, 1e200] has length inf,
    [3e-162, 0, 0] one bit of it). Exact, so a vector whose squares are normal numbers has the
    length it had unscaled, to the bit."""
    v = np.asarray(v, float)
    largest = float(np.abs(v).max(initial=0.0))
    if largest == 0.0 or not np.isfinite(largest):
        return largest
    exponent = int(np.frexp(largest)[1])
    return float(np.ldexp(np.linalg.norm(np.ldexp(v, -exponent)), exponent))


def unit(v: np.ndarray) -> np.ndarray:
    """v / |v|, scaled first as length() is, so that neither overflows nor underflows."""
    v = np.asarray(v, float)
    exponent = int(np.frexp(float(np.abs(v).max()))[1])
    scaled = np.ldexp(v, -exponent)
    return scaled / np.linalg.norm(scaled)


def rotation(n: np.ndarray) -> np.ndarray:
    """R with R e3 = n: column k is material axis k in the scene's axes."""
    n = unit(n)
    axis = np.cross([0.0, 0.0, 1.0], n)
    sine, cosine = length(axis), float(n[2])
    if sine == 0.0:  # along e3: nothing to turn, or against it: the half turn about axis 2
        return np.diag([1.0, 1.0, 1.0]) if cosine > 0 else np.diag([-1.0, 1.0, -1.0])
    a = axis / sine
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return cosine * np.eye(3) + sine * cross + (1.0 - cosine) * np.outer(a, a)


def unfold_pairs(v: np.ndarray) -> np.ndarray:
    """A Voigt index's last axis (6) as two symmetric tensor indices (3, 3)."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    for voigt, (i, j) in enumerate(PAIRS):
        out[..., i, j] = out[..., j, i] = v[..., voigt]
    return out


def fold_pairs(t: np.ndarray) -> np.ndarray:
    return np.stack([t[..., i, j] for i, j in PAIRS], axis=-1)


def turned(material: dict, n: np.ndarray) -> dict:
    """The material's tensors in the scene's axes when it is poled along n (3 components).
    Stress-like Voigt indices (of C, e, m) map to tensor pairs one to one: C, e and m act on
    engineering strains, so their Voigt entries are the tensor entries themselves."""
    r = rotation(n)
    c = unfold_pairs(np.moveaxis(unfold_pairs(np.array(material["C"], float)), 0, -1))  # [k,l,i,j] = C_ijkl
    e = unfold_pairs(np.array(material["e"], float))
    m = unfold_pairs(np.array(material["m"], float))
    beta, k, p = (np.array(material[key], float) for key in ("beta", "k", "p"))
    c = np.einsum("ai,bj,ck,dl,ijkl->abcd", r, r, r, r, c)
    e = np.einsum("ai,bj,ck,ijk->abc", r, r, r, e)
    m = np.einsum("ai,bj,ij->ab", r, r, m)
    return {**material,
            "C": fold_pairs(np.moveaxis(fold_pairs(c), -1, 0)).T.tolist(),
            "e": fold_pairs(e).tolist(), "m": fold_pairs(m).tolist(),
            "beta": (r @ beta @ r.T).tolist(), "k": (r @ k @ r.T).tolist(), "p": (r @ p).tolist()}
