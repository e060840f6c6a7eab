// A PETSc preconditioner of this project, -pc_type ilu0lean: the incomplete LU factorisation
// without fill, ILU(0), of a sequential AIJ matrix, whose factor shares the matrix's own pattern
// (row starts and column indices) and stores its values in single precision
// (-pc_ilu0lean_values single, the default) or double (-pc_ilu0lean_values double).
//
// Why: the 3D geometric multigrid's smoother is ILU(0) of each level's operator (no smoother
// without a factor converges on the coupled u-phi-theta operator, docs/solvers.md), and PETSc's
// ILU(0) is a second matrix of the operator's size: values, column indices and row starts again,
// 12 bytes an entry. Sharing the pattern leaves 8 bytes an entry in double, 4 in single. A
// smoother needs no more than single precision: the factor is already an approximation of the
// operator, and the outer Krylov method works on the double-precision operator and residual
// (mixed-precision preconditioning: Carson and Khan, "Mixed precision iterative refinement
// with sparse approximate inverse preconditioning", SIAM J. Sci. Comput. 45, 2023; Goebel,
// Gruetzmacher, Ribizel and Anzt, "Mixed precision incomplete and factorized sparse approximate
// inverse preconditioning on GPUs", Euro-Par 2021).
//
// The factorisation is PETSc's for ILU(0) in the natural ordering (row by row, each row's lower
// part eliminated by the rows above in column order, fill outside the pattern dropped, the
// diagonal stored inverted), so that with double values it is the same preconditioner as
// -pc_type ilu to round-off (tests/test_petsc.py compares the two). The pattern must hold every
// diagonal entry, as PETSc's ILU(0) requires too.
#ifndef LEAN_ILU_HPP
#define LEAN_ILU_HPP

#include <petsc/private/pcimpl.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

namespace lean_ilu {

const char *const kType = "ilu0lean";

struct Data {
  bool single = true;
  PetscInt n = 0;
  std::vector<PetscInt> diagonal;   // each row's diagonal entry, as a position in the pattern
  std::vector<float> low;           // the factor's values in the operator's pattern: single ...
  std::vector<double> high;         // ... or double precision
};

// The factor's values v (L below the diagonal, unit diagonal implied; U on and above, the
// diagonal inverted) from the matrix's, row i of the work row w gathered from the pattern.
template <class Real>
PetscErrorCode factor(const PetscInt *ia, const PetscInt *ja, const PetscScalar *a, const PetscInt *diagonal,
                      PetscInt n, std::vector<Real> *values) {
  std::vector<Real> &v = *values;
  v.assign(ia[n], Real(0));
  // Entries a row's elimination writes outside its pattern are dropped: w is read only where
  // the next row's pattern has first overwritten it.
  std::vector<double> w(n, 0.0);
  for (PetscInt i = 0; i < n; ++i) {
    for (PetscInt p = ia[i]; p < ia[i + 1]; ++p) w[ja[p]] = a[p];
    for (PetscInt p = ia[i]; p < diagonal[i]; ++p) {
      PetscInt k = ja[p];
      double l = w[k] * (double)v[diagonal[k]];
      w[k] = l;
      if (l != 0.0)
        for (PetscInt q = diagonal[k] + 1; q < ia[k + 1]; ++q) w[ja[q]] -= l * (double)v[q];
    }
    double pivot = w[i];
    if (pivot == 0.0 || !std::isfinite(pivot))
      SETERRQ(PETSC_COMM_SELF, PETSC_ERR_MAT_LU_ZRPVT, "ILU(0) (-pc_type ilu0lean): pivot %g in row %" PetscInt_FMT,
              pivot, i);
    w[i] = 1.0 / pivot;
    // Single precision holds magnitudes up to 3.4e38: a larger entry (an unscaled system) would
    // become infinite and spoil every solve; say so rather than smooth with it.
    for (PetscInt p = ia[i]; p < ia[i + 1]; ++p) {
      v[p] = (Real)w[ja[p]];
      if (!std::isfinite((double)v[p]))
        SETERRQ(PETSC_COMM_SELF, PETSC_ERR_FP,
                "ILU(0) (-pc_type ilu0lean): row %" PetscInt_FMT " holds %g, beyond single precision's range "
                "(-pc_ilu0lean_values double keeps it)", i, w[ja[p]]);
    }
  }
  return 0;
}

// s minus the sum of v[p] y[ja[p]] over p in [begin, end), in four independent partial sums: a
// single sum is a chain of dependent additions whose latency bounds the sweep (measured at 2D
// h = 1/256: the Krylov solves 8.3 s with one sum, 7.85 s with four, PETSc's ILU 7.0 s, whose
// solve sweeps the rows of one pattern together, its "inodes"; grouping rows so here was slower).
template <class Real>
inline double minusDot(double s, const PetscInt *ja, const Real *v, const PetscScalar *y, PetscInt begin,
                       PetscInt end) {
  double s1 = 0, s2 = 0, s3 = 0;
  PetscInt p = begin;
  for (; p + 3 < end; p += 4) {
    s -= (double)v[p] * y[ja[p]];
    s1 -= (double)v[p + 1] * y[ja[p + 1]];
    s2 -= (double)v[p + 2] * y[ja[p + 2]];
    s3 -= (double)v[p + 3] * y[ja[p + 3]];
  }
  for (; p < end; ++p) s -= (double)v[p] * y[ja[p]];
  return (s + s1) + (s2 + s3);
}

// y = U^-1 L^-1 x with the factor's values v.
template <class Real>
void solve(const PetscInt *ia, const PetscInt *ja, const PetscInt *diagonal, PetscInt n, const std::vector<Real> &v,
           const PetscScalar *x, PetscScalar *y) {
  const Real *values = v.data();
  for (PetscInt i = 0; i < n; ++i) y[i] = minusDot(x[i], ja, values, y, ia[i], diagonal[i]);
  for (PetscInt i = n - 1; i >= 0; --i)
    y[i] = minusDot(y[i], ja, values, y, diagonal[i] + 1, ia[i + 1]) * (double)values[diagonal[i]];
}

// The preconditioning matrix's pattern, in place (a sequential AIJ matrix's own arrays).
PetscErrorCode pattern(PC pc, PetscInt *n, const PetscInt **ia, const PetscInt **ja) {
  PetscBool aij = PETSC_FALSE, done = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc->pmat, MATSEQAIJ, &aij));
  if (!aij) SETERRQ(PETSC_COMM_SELF, PETSC_ERR_SUP, "-pc_type ilu0lean needs a sequential AIJ matrix");
  PetscCall(MatGetRowIJ(pc->pmat, 0, PETSC_FALSE, PETSC_FALSE, n, ia, ja, &done));
  if (!done) SETERRQ(PETSC_COMM_SELF, PETSC_ERR_SUP, "-pc_type ilu0lean: the matrix has no row structure");
  return 0;
}
PetscErrorCode release(PC pc, PetscInt *n, const PetscInt **ia, const PetscInt **ja) {
  PetscBool done;
  return MatRestoreRowIJ(pc->pmat, 0, PETSC_FALSE, PETSC_FALSE, n, ia, ja, &done);
}

PetscErrorCode setUp(PC pc) {
  Data &d = *(Data *)pc->data;
  PetscInt n;
  const PetscInt *ia, *ja;
  const PetscScalar *a;
  PetscCall(pattern(pc, &n, &ia, &ja));
  d.n = n;
  d.diagonal.assign(n, -1);
  for (PetscInt i = 0; i < n; ++i) {
    const PetscInt *at = std::lower_bound(ja + ia[i], ja + ia[i + 1], i);
    if (at == ja + ia[i + 1] || *at != i)
      SETERRQ(PETSC_COMM_SELF, PETSC_ERR_MAT_LU_ZRPVT, "ILU(0) (-pc_type ilu0lean): row %" PetscInt_FMT
              " has no diagonal entry", i);
    d.diagonal[i] = (PetscInt)(at - ja);
  }
  PetscCall(MatSeqAIJGetArrayRead(pc->pmat, &a));
  if (d.single) {
    d.high.clear();
    d.high.shrink_to_fit();
    PetscCall(factor(ia, ja, a, d.diagonal.data(), n, &d.low));
  } else {
    d.low.clear();
    d.low.shrink_to_fit();
    PetscCall(factor(ia, ja, a, d.diagonal.data(), n, &d.high));
  }
  PetscCall(MatSeqAIJRestoreArrayRead(pc->pmat, &a));
  return release(pc, &n, &ia, &ja);
}

PetscErrorCode apply(PC pc, Vec x, Vec y) {
  Data &d = *(Data *)pc->data;
  PetscInt n;
  const PetscInt *ia, *ja;
  const PetscScalar *in;
  PetscScalar *out;
  PetscCall(pattern(pc, &n, &ia, &ja));
  PetscCall(VecGetArrayRead(x, &in));
  PetscCall(VecGetArrayWrite(y, &out));
  if (d.single) solve(ia, ja, d.diagonal.data(), n, d.low, in, out);
  else solve(ia, ja, d.diagonal.data(), n, d.high, in, out);
  PetscCall(VecRestoreArrayRead(x, &in));
  PetscCall(VecRestoreArrayWrite(y, &out));
  return release(pc, &n, &ia, &ja);
}

PetscErrorCode setFromOptions(PC pc, PetscOptionItems *) {
  Data &d = *(Data *)pc->data;
  const char *prefix = nullptr;
  char values[16] = "";
  PetscBool set = PETSC_FALSE;
  PetscCall(PCGetOptionsPrefix(pc, &prefix));
  PetscCall(PetscOptionsGetString(nullptr, prefix, "-pc_ilu0lean_values", values, sizeof values, &set));
  if (!set) return 0;
  if (std::strcmp(values, "single") && std::strcmp(values, "double"))
    SETERRQ(PETSC_COMM_SELF, PETSC_ERR_ARG_OUTOFRANGE, "-pc_ilu0lean_values is single or double, not %s", values);
  d.single = std::strcmp(values, "single") == 0;
  return 0;
}

PetscErrorCode view(PC pc, PetscViewer viewer) {
  const Data &d = *(const Data *)pc->data;
  return PetscViewerASCIIPrintf(viewer, "  ILU(0) in the matrix's pattern, %s-precision values\n",
                                d.single ? "single" : "double");
}

PetscErrorCode destroy(PC pc) {
  delete (Data *)pc->data;
  pc->data = nullptr;
  return 0;
}

PetscErrorCode create(PC pc) {
  pc->data = new Data;
  pc->ops->setup = setUp;
  pc->ops->apply = apply;
  pc->ops->setfromoptions = setFromOptions;
  pc->ops->view = view;
  pc->ops->destroy = destroy;
  return 0;
}

// The factor's MB (its values and diagonal positions; the pattern is the matrix's), or -1 when
// pc is not this type.
double megabytes(PC pc) {
  PetscBool mine = PETSC_FALSE;
  if (PetscObjectTypeCompare((PetscObject)pc, kType, &mine) || !mine || !pc->data) return -1;
  const Data &d = *(const Data *)pc->data;
  return (d.low.capacity() * sizeof(float) + d.high.capacity() * sizeof(double) +
          d.diagonal.capacity() * sizeof(PetscInt)) / 1048576.0;
}

PetscErrorCode registerType() { return PCRegister(kType, create); }

}  // namespace lean_ilu

#endif
