// A FreeFEM plugin of this project: PETSc's Krylov solvers and preconditioners for a
// FreeFEM sparse matrix (run.linear_solver = "petsc", freefem/linear_solver.idp).
// Built on first use by harness/run/petsc_plugin.py against Debian's PETSc (3.18).
//
// Debian's FreeFEM has no PETSc interface of its own (its upstream one needs HPDDM), so
// this one is deliberately small. A script creates a solver context from an options
// string and the layout of its unknowns, then solves with it; PETSc's own options choose
// everything else (-ksp_type, -pc_type fieldsplit, hypre, gamg, mumps with BLR, ...):
//
//   int id = petscCreate(options, "u phi theta", sizes, blocks, coords);
//   int its = petscSolve(id, A, b, x, rtol, reuse);   // x = A^-1 b to rtol (true residual)
//   petscStats(id, stats);                             // iterations, residual, times
//   petscDestroy(id);
//
// The Newton method's bulk matrix K lives here, not in FreeFEM (freefem/bulk.idp):
//
//   int k = petscBulkCreate(n);
//   petscBulkAdd(k, Kuu, 0, 0); ...                      // each block varf, then freed by FreeFEM
//   petscBulkAssemble(k);
//   petscBulkMult(k, x, y);  petscBulkDiagonal(k, d);     // y = K x, d = diag(K)
//   petscBulkDirichlet(k, mask);                          // the Newton system's Dirichlet dofs
//   int its = petscSolveBulk(id, k, T, b, x, rtol, reuse);  // x = (K + T)^-1 b
//   petscBulkDestroy(k);
//
// or, for P1 fields, K in one pass by an element kernel whose blocks the script reads off the forms:
//
//   petscBulkKernelBlock(k, [rowOffset, rowComponents, colOffset, colComponents, dim], D); ...
//   petscBulkReserve(k, Ttu, rowOffset, colOffset); ... // room for the contact tangent's entries K lacks
//   petscBulkKernel(k, Th);                              // then petscBulkAssemble(k) as above
//
// and Gamma_3's contact residual and tangent at the Newton vector x, by a kernel whose
// integrands are the contact forms' own macros, compiled (contact_forms.hpp, generated):
//
//   petscContactResidual(Th, layout, law, x, r);  petscContactTangent(Th, layout, law, x, T);
//   petscContactIntegrals(Th, layout, law, x, values);   // the physical checks' integrals
//
// The unknowns are FreeFEM's Newton vector: the fields concatenated in order, a vector
// field's components interleaved per node. Each field becomes an index set named after
// it, so that "-pc_type fieldsplit -fieldsplit_u_pc_type gamg" addresses the displacement;
// a field's block size (the components per node) is the index set's, and the rigid-body
// modes built from `coords` (the displacement's nodal coordinates, interleaved as its
// dofs) are its near-null space, which smoothed aggregation needs for elasticity.
//
// Every PETSc error is caught by an error handler that keeps its message: the calls
// return a negative code and the message goes to stdout as one "error:" line, so the
// script can exit with a code of the project's contract (freefem/contract.idp).
#include <petscksp.h>
#include <petscsf.h>
#include <malloc.h>
#include <chrono>
#include <ctime>
#include <fstream>
#include <functional>
#include <cstdlib>
#include <algorithm>
#include <limits>
#include <cctype>
#include <cmath>
#include <cstring>
#include <sstream>
#include <string>
#include <vector>
#include "ff++.hpp"
#include "AFunction_ext.hpp"
#include "lgfem.hpp"
#include "contact_forms.hpp"
#include "lean_ilu.hpp"

namespace {

// Return codes of the calls (freefem/linear_solver.idp maps them to exit codes).
const long kNotConverged = -1;   // the Krylov method stopped before rtol (stats: reason)
const long kPetscError = -2;     // PETSc refused: a bad option, a failed set-up
const long kUnusedOption = -3;   // an option PETSc never read (misspelt, or for another solver)

std::string lastMessage;         // the first message of the last PETSc error

PetscErrorCode keepMessage(MPI_Comm, int, const char *, const char *, PetscErrorCode code,
                           PetscErrorType type, const char *message, void *) {
  if (type == PETSC_ERROR_INITIAL) lastMessage = message ? message : "";
  return code;
}

// PETSc and, without FreeFem++-mpi, MPI are started once, at the first context.
bool started = false;
PetscErrorCode start() {
  if (started) return 0;
  PetscErrorCode ierr = PetscInitializeNoArguments();
  if (ierr) return ierr;
  PetscPushErrorHandler(keepMessage, nullptr);
  ierr = lean_ilu::registerType();
  if (ierr) return ierr;
  started = true;
  return 0;
}

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
// CPU seconds of this process, FreeFEM's clock(): the run's profile (freefem/profile.idp)
// adds the plugin's pieces to the script's in one currency.
double cpu() { return (double)std::clock() / CLOCKS_PER_SEC; }
// The process's peak resident memory so far [MB]: VmHWM, as freefem/memory.idp reads it
// (getrusage's ru_maxrss would count the harness's forked Python before exec). -1 where
// there is no /proc.
double statusMb(const char *field) {
  std::ifstream status("/proc/self/status");
  std::string line;
  size_t len = std::strlen(field);
  while (std::getline(status, line))
    if (line.compare(0, len, field) == 0) return std::atof(line.c_str() + len) / 1024.0;
  return -1;
}
double peakMb() { return statusMb("VmHWM:"); }

struct Context {
  KSP ksp = nullptr;
  Mat op = nullptr;        // the operator of the last solve
  Mat pre = nullptr;       // the matrix the preconditioner was built from
  std::string prefix;      // of this context's options in PETSc's database
  std::vector<std::string> names;
  std::vector<IS> fields;
  std::vector<PetscInt> dirichlet;   // rows of the last operator made identity rows
  std::vector<PetscInt> seed;        // the dofs of the contact nodes (Gamma_3)
  IS zone = nullptr;                 // seed grown by -contact_zone_layers layers of the matrix graph
  std::vector<Mat> nodal;            // petscAddLevel: nodal (scalar P1) interpolations, finest first
  bool levelsAttached = false;
  bool oneLevel = false;             // a multigrid without coarser meshes: no smoother is read
  MatNullSpace rigid = nullptr;
  PetscInt size = 0;
  bool checkedOptions = false;
  // statistics
  PetscInt lastIts = 0, totalIts = 0, setups = 0, solves = 0;
  double lastResidual = 0, lastSetup = 0, lastSolve = 0, totalSetup = 0, totalSolve = 0;
  double cpuOperator = 0, cpuSetup = 0, cpuSolve = 0;   // CPU seconds of the last call's pieces
  double wallOperator = 0;   // wall seconds of the last call's K + T (on ranks: its exchange with the others)
  double peakOperator = 0, peakSetup = 0, peakSolve = 0;   // the peak [MB] after each of them
  int lastReason = 0;
};
std::vector<Context *> contexts;

// The object a script's integer handle names, or null (and the message) when it names none.
template <class T> T *handle(const std::vector<T *> &all, long id, const char *what) {
  if (id < 0 || id >= (long)all.size() || !all[id]) {
    lastMessage = std::string("no ") + what + " " + std::to_string(id);
    return nullptr;
  }
  return all[id];
}

Context *context(long id) { return handle(contexts, id, "PETSc solver context"); }

long fail(PetscErrorCode ierr, const std::string &where) {
  std::string text = lastMessage;
  if (text.empty()) {
    const char *generic = nullptr;
    PetscErrorMessage(ierr, &generic, nullptr);
    text = generic ? generic : "unknown error";
  }
  // One line: PETSc's messages may carry newlines.
  for (char &c : text) if (c == '\n') c = ' ';
  std::cout << "error: PETSc " << where << ": " << text << std::endl;
  lastMessage.clear();
  return kPetscError;
}

#define TRY(call, where) do { PetscErrorCode ierr_ = (call); if (ierr_) return fail(ierr_, where); } while (0)

// A copy of FreeFEM's matrix as a sequential AIJ matrix (rows sorted, as PETSc wants them).
PetscErrorCode toPetsc(Matrice_Creuse<double> *source, Mat *out) {
  MatriceMorse<double> *a = source->A ? dynamic_cast<MatriceMorse<double> *>(&*source->A) : nullptr;
  if (!a) { lastMessage = "the matrix is empty or not a sparse matrix"; return PETSC_ERR_ARG_WRONG; }
  if (a->half) { lastMessage = "a symmetric (half-stored) matrix is not supported"; return PETSC_ERR_SUP; }
  if (a->n != a->m) { lastMessage = "the matrix is not square"; return PETSC_ERR_ARG_SIZ; }
  a->CSR();
  std::vector<PetscInt> rows(a->p, a->p + a->n + 1), cols(a->j, a->j + a->nnz);
  PetscCall(MatCreate(PETSC_COMM_SELF, out));
  PetscCall(MatSetSizes(*out, a->n, a->n, a->n, a->n));
  PetscCall(MatSetType(*out, MATSEQAIJ));
  PetscCall(MatSeqAIJSetPreallocationCSR(*out, rows.data(), cols.data(), a->aij));
  return 0;
}

// FreeFEM's Dirichlet rows carry tgv (>= 1e25) on the diagonal, so the increment there is
// -(rest of the row)/tgv, zero to round-off. A preconditioner sees rows 1e30 times larger
// than the others (AMG's strength of connection and smoothers, a Schur complement's diagonal);
// such rows and their columns become identity ones instead, the increment there being zero
// either way (the Newton residual is zero on Dirichlet rows, and a zero increment moves no
// other row). The right-hand side is zeroed there to match.
const double kDirichletDiagonal = 1e25;
PetscErrorCode dirichletRows(Mat a, std::vector<PetscInt> *rows) {
  Vec d;
  PetscCall(MatCreateVecs(a, &d, nullptr));
  PetscCall(MatGetDiagonal(a, d));
  const PetscScalar *v;
  PetscInt n;
  PetscCall(VecGetLocalSize(d, &n));
  PetscCall(VecGetArrayRead(d, &v));
  rows->clear();
  for (PetscInt i = 0; i < n; ++i) if (std::abs(v[i]) >= kDirichletDiagonal) rows->push_back(i);
  PetscCall(VecRestoreArrayRead(d, &v));
  PetscCall(VecDestroy(&d));
  return 0;
}

// `attach` applied to pc, or to each preconditioner of a composite one (-pc_type composite).
PetscErrorCode eachLeaf(Context &c, PC pc, PetscErrorCode (*attach)(Context &, PC)) {
  PetscBool composite = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCCOMPOSITE, &composite));
  if (!composite) return attach(c, pc);
  PetscInt count;
  PetscCall(PCCompositeGetNumberPC(pc, &count));
  for (PetscInt i = 0; i < count; ++i) {
    PC sub;
    PetscCall(PCCompositeGetPC(pc, i, &sub));
    PetscCall(eachLeaf(c, sub, attach));
  }
  return 0;
}

// The fields as index sets on the preconditioner (fieldsplit only; other PCs ignore them).
// By default each field is a split of its own, in the Newton vector's order. The plugin's
// option -fieldsplit_groups gives the splits and their order instead: "theta,u+phi" is two
// splits, theta first, then u and phi together, named "uphi" (-fieldsplit_uphi_pc_type ...).
PetscErrorCode attachFields(Context &c, PC pc) {
  PetscBool split = PETSC_FALSE, given = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCFIELDSPLIT, &split));
  char spec[256] = "";
  PetscCall(PetscOptionsGetString(nullptr, c.prefix.c_str(), "-fieldsplit_groups", spec, sizeof(spec), &given));
  if (!split) return 0;
  if (!given) {
    for (size_t k = 0; k < c.fields.size(); ++k) PetscCall(PCFieldSplitSetIS(pc, c.names[k].c_str(), c.fields[k]));
    return 0;
  }
  std::string groups = spec;
  for (char &ch : groups) if (ch == ',') ch = ' ';
  std::istringstream words(groups);
  for (std::string group; words >> group;) {
    std::string name;
    IS is = nullptr;
    std::string members = group;
    for (char &ch : members) if (ch == '+') ch = ' ';
    std::istringstream fields(members);
    for (std::string field; fields >> field;) {
      size_t k = 0;
      while (k < c.names.size() && c.names[k] != field) ++k;
      if (k == c.names.size()) {
        lastMessage = "-fieldsplit_groups names a field \"" + field + "\" this scene does not solve for";
        if (is) ISDestroy(&is);
        return PETSC_ERR_ARG_WRONG;
      }
      name += field;
      if (!is) {
        PetscCall(PetscObjectReference((PetscObject)c.fields[k]));
        is = c.fields[k];
      } else {
        IS both;
        PetscCall(ISExpand(is, c.fields[k], &both));
        PetscCall(ISDestroy(&is));
        is = both;
      }
    }
    PetscCall(PCFieldSplitSetIS(pc, name.c_str(), is));
    PetscCall(ISDestroy(&is));
  }
  return 0;
}

// The contact zone: the contact nodes' dofs grown by `layers` layers of the matrix graph
// (every field of the nodes within `layers` elements of Gamma_3, once the coupling blocks
// are crossed). The contact conductances couple u_nu to phi and theta there with a gain of
// k/eps (1e5 in the benchmark's scaled units), which no split of the fields can see.
PetscErrorCode contactZone(Mat a, const std::vector<PetscInt> &seed, PetscInt layers, IS *zone) {
  PetscInt n;
  PetscCall(MatGetSize(a, &n, nullptr));
  std::vector<char> in(n, 0);
  std::vector<PetscInt> front(seed);
  for (PetscInt i : seed) in[i] = 1;
  for (PetscInt layer = 0; layer < layers; ++layer) {
    std::vector<PetscInt> next;
    for (PetscInt i : front) {
      PetscInt count;
      const PetscInt *cols;
      PetscCall(MatGetRow(a, i, &count, &cols, nullptr));
      for (PetscInt k = 0; k < count; ++k)
        if (!in[cols[k]]) { in[cols[k]] = 1; next.push_back(cols[k]); }
      PetscCall(MatRestoreRow(a, i, &count, &cols, nullptr));
    }
    front.swap(next);
  }
  std::vector<PetscInt> dofs;
  for (PetscInt i = 0; i < n; ++i) if (in[i]) dofs.push_back(i);
  PetscCall(ISCreateGeneral(PETSC_COMM_SELF, (PetscInt)dofs.size(), dofs.data(), PETSC_COPY_VALUES, zone));
  return 0;
}

// Additive Schwarz sub-preconditioners (-pc_type asm, or one of a composite's) get the contact
// zone as their one subdomain: a direct solve there corrects what a field split cannot.
PetscErrorCode attachZone(Context &c, PC pc) {
  PetscBool additive = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCASM, &additive));
  if (!additive) return 0;
  if (!c.zone) {
    PetscInt layers = 2;
    PetscCall(PetscOptionsGetInt(nullptr, c.prefix.c_str(), "-contact_zone_layers", &layers, nullptr));
    PetscCall(contactZone(c.op, c.seed, layers, &c.zone));
  }
  PetscCall(PCASMSetLocalSubdomains(pc, 1, &c.zone, &c.zone));
  return 0;
}

// Geometric multigrid (-pc_type mg). The script hands over the nodal interpolations of a
// family of nested meshes (petscAddLevel, finest first): P maps the nodal values of the
// next coarser mesh to this one's, the same for every field since all are P1. The
// Newton vector's interpolation is then block diagonal over the fields, each block P
// itself or, for the displacement, P acting on every component (its dofs interleaved per
// node). Coarse operators are Galerkin products R A P of the Newton tangent, so the
// coarse levels see the contact state and the conductances' coupling of the fine one.
// On the finest level the Dirichlet rows of P are zero: a coarse correction must not move
// a value the increment keeps at zero.
// The Newton vector's interpolation row by row, from the nodal one: for each field (its
// block size bs; its dofs (node, component) node-major, fields one after another) and each
// fine dof, the coarse columns and weights of its node's nodal row, zero weights left out.
// `row(dof, columns, weights)` sees the fine dofs in increasing order. Shared by one rank
// (fieldInterpolation) and the ranks (ranksInterpolation).
template <class Row>
PetscErrorCode forEachFieldRow(Mat nodal, const std::vector<PetscInt> &blocks, Row row) {
  PetscInt rows, cols;
  PetscCall(MatGetSize(nodal, &rows, &cols));
  std::vector<PetscInt> idx;
  std::vector<PetscScalar> val;
  PetscInt fineOffset = 0, coarseOffset = 0;
  for (PetscInt bs : blocks) {
    for (PetscInt i = 0; i < rows; ++i) {
      PetscInt count;
      const PetscInt *cj;
      const PetscScalar *cv;
      PetscCall(MatGetRow(nodal, i, &count, &cj, &cv));
      for (PetscInt comp = 0; comp < bs; ++comp) {
        idx.clear();
        val.clear();
        for (PetscInt k = 0; k < count; ++k)
          if (cv[k] != 0.0) { idx.push_back(coarseOffset + cj[k] * bs + comp); val.push_back(cv[k]); }
        PetscCall(row(fineOffset + i * bs + comp, idx, val));
      }
      PetscCall(MatRestoreRow(nodal, i, &count, &cj, &cv));
    }
    fineOffset += bs * rows;
    coarseOffset += bs * cols;
  }
  return 0;
}
PetscErrorCode fieldInterpolation(const Context &c, Mat nodal, PetscInt fineNodes, bool finest, Mat *out) {
  PetscInt rows, cols;
  PetscCall(MatGetSize(nodal, &rows, &cols));
  std::vector<PetscInt> blocks;
  PetscInt fineSize = 0, coarseSize = 0;
  for (IS is : c.fields) {
    PetscInt bs;
    PetscCall(ISGetBlockSize(is, &bs));
    blocks.push_back(bs);
    fineSize += bs * rows;
    coarseSize += bs * cols;
  }
  if (rows != fineNodes) {
    lastMessage = "petscAddLevel: an interpolation onto " + std::to_string(rows) + " nodes where the level has " +
                  std::to_string(fineNodes) + " (multigrid needs every field P1 on nested meshes)";
    return PETSC_ERR_ARG_SIZ;
  }
  std::vector<char> fixed(fineSize, 0);
  if (finest) for (PetscInt i : c.dirichlet) fixed[i] = 1;
  std::vector<PetscInt> ptr(1, 0), idx;
  std::vector<PetscScalar> val;
  PetscCall(forEachFieldRow(nodal, blocks, [&](PetscInt dof, const std::vector<PetscInt> &cj,
                                               const std::vector<PetscScalar> &cv) -> PetscErrorCode {
    if (!fixed[dof]) { idx.insert(idx.end(), cj.begin(), cj.end()); val.insert(val.end(), cv.begin(), cv.end()); }
    ptr.push_back((PetscInt)idx.size());
    return 0;
  }));
  PetscCall(MatCreate(PETSC_COMM_SELF, out));
  PetscCall(MatSetSizes(*out, fineSize, coarseSize, fineSize, coarseSize));
  PetscCall(MatSetType(*out, MATSEQAIJ));
  PetscCall(MatSeqAIJSetPreallocationCSR(*out, ptr.data(), idx.data(), val.data()));
  return 0;
}

// The multigrid's options, its levels set (one rank and the ranks alike). One level (no coarser
// mesh): PCMG names its only solver mg_levels_0_; it is the coarse solve, so it takes
// -mg_coarse_ options, as it would below a finer level.
PetscErrorCode multigridOptions(Context &c, PC pc, PetscInt levels) {
  PetscCall(PCSetFromOptions(pc));
  c.oneLevel = levels == 1;
  if (levels > 1) return 0;
  KSP coarse;
  const char *prefix = nullptr;
  PetscCall(PCMGGetCoarseSolve(pc, &coarse));
  PetscCall(PCGetOptionsPrefix(pc, &prefix));
  PetscCall(KSPSetOptionsPrefix(coarse, (std::string(prefix ? prefix : "") + "mg_coarse_").c_str()));
  return KSPSetFromOptions(coarse);
}

// The levels on a PCMG (-pc_type mg, or one of a composite's), from the nodal interpolations.
PetscErrorCode attachLevels(Context &c, PC pc) {
  PetscBool mg = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCMG, &mg));
  if (!mg) return 0;
  // No coarser mesh (the coarsest level of a study): one level, the coarse solver on this one.
  PetscInt levels = (PetscInt)c.nodal.size() + 1;
  PetscCall(PCMGSetLevels(pc, levels, nullptr));
  PetscInt nodes = 0;
  for (IS is : c.fields) {   // the finest level's nodes: any field's size over its block size
    PetscInt n, bs;
    PetscCall(ISGetSize(is, &n));
    PetscCall(ISGetBlockSize(is, &bs));
    nodes = n / bs;
    break;
  }
  for (size_t k = 0; k < c.nodal.size(); ++k) {
    Mat p;
    PetscCall(fieldInterpolation(c, c.nodal[k], nodes, k == 0, &p));
    PetscCall(PCMGSetInterpolation(pc, levels - 1 - (PetscInt)k, p));
    PetscCall(MatDestroy(&p));
    PetscCall(MatGetSize(c.nodal[k], nullptr, &nodes));
  }
  PetscCall(PCMGSetGalerkin(pc, PC_MG_GALERKIN_BOTH));
  std::cout << "multigrid: " << levels << " levels" << std::endl;
  return multigridOptions(c, pc, levels);
}

// The MB of a sequential sparse matrix's arrays (values, column indices, row starts and
// PETSc's per-row counts), from its stored entries: what -memory_breakdown prints.
double matrixMb(Mat m) {
  MatInfo info;
  PetscInt rows, bs = 1;
  MatType type;
  if (MatGetInfo(m, MAT_LOCAL, &info) || MatGetLocalSize(m, &rows, nullptr) || MatGetType(m, &type)) return -1;
  PetscBool blocked = PETSC_FALSE;
  PetscObjectTypeCompareAny((PetscObject)m, &blocked, MATSEQBAIJ, MATBAIJ, "");
  if (blocked) MatGetBlockSize(m, &bs);
  double indices = info.nz_allocated / (double)(bs * bs) + 4.0 * rows / bs;
  return (info.nz_allocated * sizeof(PetscScalar) + indices * sizeof(PetscInt)) / 1048576.0;
}

// -memory_breakdown (a plugin option): after a preconditioner's set-up, one line per matrix
// it holds, each multigrid level's operator, interpolation and smoother's factor (MUMPS's: its
// INFOG(22), the MB its factorisation used), beside the process's resident memory: where the
// set-up's peak goes (docs/solvers.md, "Memory at the peak").
PetscErrorCode memoryBreakdown(Context &c, const char *when) {
  PetscBool on = PETSC_FALSE;
  PetscCall(PetscOptionsGetBool(nullptr, c.prefix.c_str(), "-memory_breakdown", &on, nullptr));
  if (!on) return 0;
  PetscMPIInt rank = 0, size = 1;
  MPI_Comm_rank(PETSC_COMM_WORLD, &rank);
  MPI_Comm_size(PETSC_COMM_WORLD, &size);
  const std::string who = size > 1 ? "rank " + std::to_string(rank) + " " : "";
  std::cout << who << "memory " << when << ": resident " << statusMb("VmRSS:") << " MB, peak " << peakMb() << " MB"
            << std::endl;
  // On ranks the level smoothers' block-Jacobi factors are made at the first solve: read them then.
  if (std::strcmp(when, size > 1 ? "after solve" : "after set-up") != 0) return 0;
  PC pc;
  PetscBool mg = PETSC_FALSE;
  PetscCall(KSPGetPC(c.ksp, &pc));
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCMG, &mg));
  if (!mg) {
    std::cout << "memory: operator " << matrixMb(c.op) << " MB" << std::endl;
    return 0;
  }
  PetscInt levels;
  PetscCall(PCMGGetLevels(pc, &levels));
  for (PetscInt l = levels - 1; l >= 0; --l) {
    KSP smoother;
    PC spc;
    Mat a, p, f;
    PetscInt rows;
    MatInfo info;
    PetscCall(PCMGGetSmoother(pc, l, &smoother));
    PetscCall(KSPGetOperators(smoother, &a, nullptr));
    PetscCall(MatGetSize(a, &rows, nullptr));
    PetscCall(MatGetInfo(a, MAT_LOCAL, &info));
    std::cout << who << "memory: level " << l << " (" << rows << " rows, " << (long)info.nz_used << " entries): operator "
              << matrixMb(a) << " MB";
    if (l > 0) {
      PetscCall(PCMGGetInterpolation(pc, l, &p));
      std::cout << ", interpolation " << matrixMb(p) << " MB";
    }
    PetscCall(KSPGetPC(smoother, &spc));
    PetscBool blocks = PETSC_FALSE;
    PetscCall(PetscObjectTypeCompare((PetscObject)spc, PCBJACOBI, &blocks));
    if (blocks) {  // block Jacobi on ranks: this rank's block's smoother
      KSP *sub;
      PetscInt count;
      PetscCall(PCBJacobiGetSubKSP(spc, &count, nullptr, &sub));
      PetscCall(KSPGetPC(sub[0], &spc));
    }
    PetscBool factor = PETSC_FALSE;
    PetscCall(PetscObjectTypeCompareAny((PetscObject)spc, &factor, PCILU, PCLU, PCICC, PCCHOLESKY, ""));
    double lean = lean_ilu::megabytes(spc);
    if (lean >= 0) std::cout << ", factor (ilu0lean) " << lean << " MB";
    if (factor) {
      MatSolverType solver;
      PetscCall(PCFactorGetMatrix(spc, &f));
      PetscCall(MatFactorGetSolverType(f, &solver));
      if (std::strcmp(solver, MATSOLVERMUMPS) == 0) {
        PetscInt used;
        PetscCall(MatMumpsGetInfog(f, 22, &used));
        std::cout << ", MUMPS factorisation " << used << " MB";
      } else {
        std::cout << ", factor " << matrixMb(f) << " MB";
      }
    }
    std::cout << std::endl;
  }
  return 0;
}

// "-pc_type gamg -mat_mumps_icntl_14 -50" with prefix p_: "-p_pc_type gamg -p_mat_mumps_icntl_14 -50"
// (an option is a word starting with '-' and a letter; a negative number is a value).
std::string prefixed(const std::string &options, const std::string &prefix) {
  std::istringstream words(options);
  std::string out;
  for (std::string w; words >> w;) {
    if (w.size() > 1 && w[0] == '-' && std::isalpha((unsigned char)w[1])) w = "-" + prefix + w.substr(1);
    out += w + " ";
  }
  return out;
}

// One step of a function that returns PETSc's code and names, in *step, the step that failed.
#define STEP(call, name) do { *step = (name); ierr = (call); if (ierr) return ierr; } while (0)

// Context c's Krylov solver on `comm`, with the defaults an inexact Newton needs: GMRES on the
// true (unpreconditioned) residual, which right preconditioning gives, so that rtol means
// ||b - A x|| <= rtol ||b||; then the user's options, and the fields on every leaf of its PC.
// On failure PETSc's code, *step naming the step that failed (one rank and the ranks alike).
PetscErrorCode newKrylov(Context *c, MPI_Comm comm, const std::string &options, std::string *step) {
  PetscErrorCode ierr;
  PC pc;
  STEP(KSPCreate(comm, &c->ksp), "KSP");
  STEP(KSPSetOptionsPrefix(c->ksp, c->prefix.c_str()), "options");
  STEP(KSPSetType(c->ksp, KSPGMRES), "KSP type");
  STEP(KSPSetPCSide(c->ksp, PC_RIGHT), "PC side");
  STEP(KSPGMRESSetRestart(c->ksp, 100), "GMRES restart");
  STEP(KSPSetTolerances(c->ksp, 1e-8, 0.0, 1e50, 1000), "tolerances");
  STEP(KSPSetFromOptions(c->ksp), "options \"" + options + "\"");
  STEP(KSPGetPC(c->ksp, &pc), "fields");
  STEP(eachLeaf(*c, pc, attachFields), "fields");
  return 0;
}

// The operator into c's solver, for a solve to rtol: the preconditioner's matrix is the
// operator itself when `rebuild` (with the rigid-body modes where the displacement is the only
// field), else the last one, kept; the contact zone (`zone`, one rank) and the multigrid's levels
// (`levels`) attached to the PC's leaves at the first solve. On failure PETSc's code, *step
// naming the step (one rank and the ranks alike).
PetscErrorCode useOperator(Context *c, bool rebuild, double rtol, bool zone, PetscErrorCode (*levels)(Context &, PC),
                           std::string *step) {
  PetscErrorCode ierr;
  PC pc;
  if (rebuild) {
    STEP(MatDestroy(&c->pre), "matrix");
    STEP(PetscObjectReference((PetscObject)c->op), "matrix");
    c->pre = c->op;
    if (c->rigid && c->fields.size() == 1) STEP(MatSetNearNullSpace(c->pre, c->rigid), "near-null space");
  }
  STEP(KSPSetOperators(c->ksp, c->op, c->pre), "operators");
  if (zone && !c->zone) {
    STEP(KSPGetPC(c->ksp, &pc), "contact zone");
    STEP(eachLeaf(*c, pc, attachZone), "contact zone");
  }
  if (!c->levelsAttached) {
    STEP(KSPGetPC(c->ksp, &pc), "multigrid levels");
    STEP(eachLeaf(*c, pc, levels), "multigrid levels");
    c->levelsAttached = true;
  }
  STEP(KSPSetReusePreconditioner(c->ksp, rebuild ? PETSC_FALSE : PETSC_TRUE), "reuse");
  STEP(KSPSetTolerances(c->ksp, rtol, 0.0, PETSC_DEFAULT, PETSC_DEFAULT), "tolerances");
  return 0;
}

// The rigid-body modes of the displacement (the first vector field, bs > 1), in its own
// numbering, as field `is`'s near-null space: from the coordinates of its n local dofs, the
// `mine` of them this process owns (own[i]; null: all, one rank). A standard vector is
// sequential on one process and distributed on the ranks. On failure *step names the step.
PetscErrorCode rigidModes(Context *c, IS is, MPI_Comm comm, PetscInt bs, PetscInt n, PetscInt mine,
                          const KN<double> &coords, const char *own, std::string *step) {
  PetscErrorCode ierr;
  Vec xyz;
  PetscScalar *v;
  STEP(VecCreate(comm, &xyz), "coordinates");
  STEP(VecSetSizes(xyz, mine, PETSC_DECIDE), "coordinates");
  STEP(VecSetBlockSize(xyz, bs), "coordinates");
  STEP(VecSetType(xyz, VECSTANDARD), "coordinates");
  STEP(VecGetArray(xyz, &v), "coordinates");
  for (PetscInt i = 0, q = 0; i < n; ++i) if (!own || own[i]) v[q++] = coords[i];
  STEP(VecRestoreArray(xyz, &v), "coordinates");
  STEP(MatNullSpaceCreateRigidBody(xyz, &c->rigid), "rigid-body modes");
  STEP(VecDestroy(&xyz), "coordinates");
  STEP(PetscObjectCompose((PetscObject)is, "nearnullspace", (PetscObject)c->rigid), "near-null space");
  return 0;
}

long create(string *const &options, string *const &names, KN<long> *const &sizes, KN<long> *const &blocks,
            KN<double> *const &coords, KN<double> *const &contact) {
  TRY(start(), "start");
  Context *c = new Context;
  std::istringstream words(*names);
  for (std::string w; words >> w;) c->names.push_back(w);
  if (c->names.size() != (size_t)sizes->N() || sizes->N() != blocks->N()) {
    std::cout << "error: PETSc solver: " << c->names.size() << " field names for " << sizes->N() << " sizes and "
              << blocks->N() << " block sizes" << std::endl;
    delete c;
    return kPetscError;
  }
  // The options go into PETSc's database under a prefix of this context's own: objects
  // PETSc creates on its own (the factor matrix of -pc_type lu, a fieldsplit's sub-solvers)
  // read that database, with the prefix handed down.
  c->prefix = "s" + std::to_string(contexts.size()) + "_";
  TRY(PetscOptionsInsertString(nullptr, prefixed(*options, c->prefix).c_str()), "options \"" + *options + "\"");
  PetscInt offset = 0;
  for (long k = 0; k < sizes->N(); ++k) {
    PetscInt n = (*sizes)[k], bs = (*blocks)[k];
    IS is;
    TRY(ISCreateStride(PETSC_COMM_SELF, n, offset, 1, &is), "index set");
    TRY(ISSetBlockSize(is, bs), "block size of field " + c->names[k]);
    if (bs > 1 && !c->rigid && coords->N() == n) {
      std::string step;
      TRY(rigidModes(c, is, PETSC_COMM_SELF, bs, n, n, *coords, nullptr, &step), step);
    }
    c->fields.push_back(is);
    offset += n;
  }
  c->size = offset;
  for (long i = 0; i < contact->N() && i < offset; ++i) if ((*contact)[i] != 0) c->seed.push_back(i);
  std::string step;
  TRY(newKrylov(c, PETSC_COMM_SELF, *options, &step), step);
  contexts.push_back(c);
  return (long)contexts.size() - 1;
}

// The options of context c that PETSc never read, "-a, -b" (none: empty).
PetscErrorCode unusedOptions(const Context &c, std::string *unused) {
  PetscInt left;
  char **names, **values;
  PetscCall(PetscOptionsLeftGet(nullptr, &left, &names, &values));
  for (PetscInt i = 0; i < left; ++i) {
    std::string name = names[i];
    if (name.compare(0, c.prefix.size(), c.prefix) != 0) continue;
    if (c.oneLevel && name.compare(c.prefix.size(), 10, "mg_levels_") == 0) continue;   // no level to smooth
    *unused += std::string(unused->empty() ? "" : ", ") + "-" + name.substr(c.prefix.size());
  }
  PetscCall(PetscOptionsLeftRestore(nullptr, &left, &names, &values));
  return 0;
}

// The Newton method's bulk matrix K, held by the plugin alone (petscBulk* below): FreeFEM
// assembles one block varf at a time and hands it over, then frees it, so FreeFEM never holds
// K, nor two blocks at once. FreeFEM's sparse matrix costs about 40 bytes an entry (indices
// and a hash beside each value); a block waits here as CSR rows, 12 bytes an entry, until all
// are in, and K is then one PETSc matrix J of 12 bytes an entry.
//
// J is also the Newton operator K + T (T the contact tangent, on Gamma_3's rows) with the
// Dirichlet rows and columns made identity ones: no second copy of K is kept beside it. Where
// J differs from K (the rows of T and the Dirichlet rows, whole; the Dirichlet columns of the
// other rows, which hold zeros in J) K's values are kept aside, a few per cent of K, and
// serve to put K back into J before the next T, and to correct J x into K x.
struct Bulk {
  struct Chunk {            // one block, its rows (of K's numbering) as CSR, columns sorted
    PetscInt row0 = 0, col0 = 0;
    std::vector<PetscInt> ptr, col;
    std::vector<PetscScalar> val;
  };
  PetscInt n = 0;
  std::vector<Chunk> chunks;
  Mat J = nullptr;                   // K once assembled; K + T with identity Dirichlet rows when !clean
  bool clean = true;                 // J holds K
  std::vector<PetscInt> dirichlet;   // the rows (and columns) the Newton system makes identity ones
  // K where J differs from it: whole rows (sRows, CSR over J's pattern) and single entries of
  // the other rows (dPos into J's values, their row, column and K's value).
  std::vector<char> whole;
  std::vector<PetscInt> sRows, sPtr, sCols, dPos, dRow, dCol;
  std::vector<PetscScalar> sVals, dVals;
  bool captured = false;
  // Entries of T that K lacks, (row, column) pairs, made room for in J's pattern when K is
  // built (petscBulkReserve): otherwise the first K + T copies J into a wider pattern.
  // Given, they may include K's entries; once K is built, exactly J's entries outside K, sorted.
  std::vector<std::pair<PetscInt, PetscInt>> reserved;
  // On MPI ranks, once K is in the distributed matrix (petscRanksHoldOnce): J is gone and K x is
  // that matrix's product, corrected where it is not K (releasedMult, "Distributed solves").
  std::function<PetscErrorCode(const KN<double> &, KN<double> &)> releasedMult;
  bool held() const { return J || releasedMult; }
};
std::vector<Bulk *> bulks;

Bulk *bulkOf(long id) { return handle(bulks, id, "bulk matrix"); }

long bulkCreate(long const &n) {
  TRY(start(), "start");
  Bulk *b = new Bulk;
  b->n = (PetscInt)n;
  bulks.push_back(b);
  return (long)bulks.size() - 1;
}

// The block A (FreeFEM's, of rows rowOffset.. and columns colOffset.. of K) as a chunk: its
// entries bucketed by row (FreeFEM keeps them in the order assembly made them), each row's
// columns sorted. FreeFEM's own sort (CSR()) is not used: it is a heap sort of the whole.
// A's FreeFEM matrix if it is a full (not half) sparse matrix that fits in K at (rowOffset,
// colOffset) and K is not assembled yet; else none, the reason in lastMessage.
MatriceMorse<double> *blockInside(const Bulk &b, Matrice_Creuse<double> *A, long rowOffset, long colOffset) {
  MatriceMorse<double> *m = A->A ? dynamic_cast<MatriceMorse<double> *>(&*A->A) : nullptr;
  if (!m || m->half || b.J || rowOffset < 0 || colOffset < 0 || rowOffset + m->n > b.n || colOffset + m->m > b.n) {
    lastMessage = "a bulk block must be a full sparse matrix inside K, given before K is assembled";
    return nullptr;
  }
  return m;
}

long bulkAdd(long const &id, Matrice_Creuse<double> *const &A, long const &rowOffset, long const &colOffset) {
  Bulk *b = bulkOf(id);
  if (!b) return fail(PETSC_ERR_ARG_OUTOFRANGE, "bulk block");
  MatriceMorse<double> *m = blockInside(*b, A, rowOffset, colOffset);
  if (!m) return fail(PETSC_ERR_ARG_WRONG, "bulk block");
  Bulk::Chunk c;
  c.row0 = (PetscInt)rowOffset;
  c.col0 = (PetscInt)colOffset;
  size_t nnz = m->nnz;
  c.ptr.assign(m->n + 1, 0);
  for (size_t k = 0; k < nnz; ++k) ++c.ptr[m->i[k] + 1];
  for (long r = 0; r < m->n; ++r) c.ptr[r + 1] += c.ptr[r];
  std::vector<PetscInt> fill(c.ptr.begin(), c.ptr.end() - 1);
  c.col.resize(nnz);
  c.val.resize(nnz);
  for (size_t k = 0; k < nnz; ++k) {
    PetscInt q = fill[m->i[k]]++;
    c.col[q] = m->j[k] + c.col0;
    c.val[q] = m->aij[k];
  }
  std::vector<std::pair<PetscInt, PetscScalar>> row;
  for (long r = 0; r < m->n; ++r) {
    row.clear();
    for (PetscInt q = c.ptr[r]; q < c.ptr[r + 1]; ++q) row.emplace_back(c.col[q], c.val[q]);
    std::sort(row.begin(), row.end(), [](const std::pair<PetscInt, PetscScalar> &x,
                                         const std::pair<PetscInt, PetscScalar> &y) { return x.first < y.first; });
    for (size_t k = 0; k < row.size(); ++k) {
      c.col[c.ptr[r] + k] = row[k].first;
      c.val[c.ptr[r] + k] = row[k].second;
    }
  }
  b->chunks.push_back(std::move(c));
  return 0;
}

// Room in K's pattern for the entries of A (FreeFEM's, of rows rowOffset.. and columns
// colOffset.. of K), zeros in K: the element kernel makes it (kernelAssemble); K from blocks
// ignores it and widens its pattern at the first K + T instead.
long bulkReserve(long const &id, Matrice_Creuse<double> *const &A, long const &rowOffset, long const &colOffset) {
  Bulk *b = bulkOf(id);
  if (!b) return fail(PETSC_ERR_ARG_OUTOFRANGE, "bulk reserve");
  MatriceMorse<double> *m = blockInside(*b, A, rowOffset, colOffset);
  if (!m) return fail(PETSC_ERR_ARG_WRONG, "bulk reserve");
  for (size_t k = 0; k < (size_t)m->nnz; ++k)
    b->reserved.emplace_back((PetscInt)(m->i[k] + rowOffset), (PetscInt)(m->j[k] + colOffset));
  return 0;
}

// K from its chunks into an exactly preallocated PETSc matrix, each chunk freed once in: row by
// row the chunks in the order of their columns, so each row is filled from left to right.
PetscErrorCode assembleChunks(Bulk &b) {
  std::vector<std::pair<PetscInt, PetscInt>>().swap(b.reserved);
  std::stable_sort(b.chunks.begin(), b.chunks.end(),
                   [](const Bulk::Chunk &x, const Bulk::Chunk &y) { return x.col0 < y.col0; });
  std::vector<PetscInt> counts(b.n, 0);
  PetscInt total = 0;
  for (const Bulk::Chunk &c : b.chunks)
    for (size_t r = 0; r + 1 < c.ptr.size(); ++r) counts[c.row0 + r] += c.ptr[r + 1] - c.ptr[r];
  for (PetscInt r = 0; r < b.n; ++r) total += counts[r];
  PetscCall(MatCreate(PETSC_COMM_SELF, &b.J));
  PetscCall(MatSetSizes(b.J, b.n, b.n, b.n, b.n));
  PetscCall(MatSetType(b.J, MATSEQAIJ));
  PetscCall(MatSeqAIJSetPreallocation(b.J, 0, counts.data()));
  PetscCall(MatSetOption(b.J, MAT_NEW_NONZERO_ALLOCATION_ERR, PETSC_TRUE));
  for (Bulk::Chunk &c : b.chunks) {
    for (size_t r = 0; r + 1 < c.ptr.size(); ++r) {
      PetscInt row = c.row0 + (PetscInt)r, count = c.ptr[r + 1] - c.ptr[r];
      if (count)
        PetscCall(MatSetValues(b.J, 1, &row, count, c.col.data() + c.ptr[r], c.val.data() + c.ptr[r], INSERT_VALUES));
    }
    std::vector<PetscInt>().swap(c.ptr);
    std::vector<PetscInt>().swap(c.col);
    std::vector<PetscScalar>().swap(c.val);
  }
  b.chunks.clear();
  PetscCall(MatAssemblyBegin(b.J, MAT_FINAL_ASSEMBLY));
  PetscCall(MatAssemblyEnd(b.J, MAT_FINAL_ASSEMBLY));
  MatInfo info;
  PetscCall(MatGetInfo(b.J, MAT_LOCAL, &info));
  if ((PetscInt)info.nz_used != total) {
    lastMessage = "two bulk blocks overlap (" + std::to_string((long)info.nz_used) + " entries where the blocks have " +
                  std::to_string(total) + ")";
    return PETSC_ERR_ARG_WRONG;
  }
  return 0;
}

long bulkAssemble(long const &id) {
  Bulk *b = bulkOf(id);
  if (!b) return fail(PETSC_ERR_ARG_OUTOFRANGE, "bulk matrix");
  if (!b->J) TRY(assembleChunks(*b), "bulk matrix");
  return 0;
}

// Row i of the sequential AIJ matrix m: its columns and values, in place.
struct Rows {
  PetscInt n = 0;
  const PetscInt *ia = nullptr, *ja = nullptr;
  PetscScalar *a = nullptr;
  Mat m = nullptr;
};
PetscErrorCode openRows(Mat m, Rows *r) {
  PetscBool done;
  r->m = m;
  PetscCall(MatGetRowIJ(m, 0, PETSC_FALSE, PETSC_FALSE, &r->n, &r->ia, &r->ja, &done));
  if (!done) {
    lastMessage = "the matrix has no row structure to read";
    return PETSC_ERR_SUP;
  }
  return MatSeqAIJGetArray(m, &r->a);
}
PetscErrorCode closeRows(Rows *r) {
  PetscBool done;
  PetscCall(MatSeqAIJRestoreArray(r->m, &r->a));
  return MatRestoreRowIJ(r->m, 0, PETSC_FALSE, PETSC_FALSE, &r->n, &r->ia, &r->ja, &done);
}

// J := K again, from the values kept aside.
PetscErrorCode restoreK(Bulk &b) {
  if (b.clean) return 0;
  Rows r;
  PetscCall(openRows(b.J, &r));
  for (size_t s = 0; s < b.sRows.size(); ++s)
    for (PetscInt p = r.ia[b.sRows[s]], q = b.sPtr[s]; q < b.sPtr[s + 1]; ++p, ++q) r.a[p] = b.sVals[q];
  for (size_t d = 0; d < b.dPos.size(); ++d) r.a[b.dPos[d]] = b.dVals[d];
  PetscCall(closeRows(&r));
  b.clean = true;
  return 0;
}

// Keeps aside K's values (J clean) where J will differ from it: the rows marked in b.whole,
// and the Dirichlet columns of every other row.
PetscErrorCode captureK(Bulk &b) {
  std::vector<char> dirichletColumn(b.n, 0);
  for (PetscInt i : b.dirichlet) dirichletColumn[i] = 1;
  b.sRows.clear(); b.sPtr.assign(1, 0); b.sCols.clear(); b.sVals.clear();
  b.dPos.clear(); b.dRow.clear(); b.dCol.clear(); b.dVals.clear();
  Rows r;
  PetscCall(openRows(b.J, &r));
  for (PetscInt i = 0; i < b.n; ++i) {
    if (b.whole[i]) {
      b.sRows.push_back(i);
      for (PetscInt p = r.ia[i]; p < r.ia[i + 1]; ++p) { b.sCols.push_back(r.ja[p]); b.sVals.push_back(r.a[p]); }
      b.sPtr.push_back((PetscInt)b.sCols.size());
      continue;
    }
    for (PetscInt p = r.ia[i]; p < r.ia[i + 1]; ++p)
      if (dirichletColumn[r.ja[p]]) {
        b.dPos.push_back(p); b.dRow.push_back(i); b.dCol.push_back(r.ja[p]); b.dVals.push_back(r.a[p]);
      }
  }
  std::cout << "bulk: K kept aside where K + T differs: " << b.sCols.size() << " entries in " << b.sRows.size()
            << " whole rows, " << b.dPos.size() << " in Dirichlet columns, of " << r.ia[b.n] << std::endl;
  PetscCall(closeRows(&r));
  b.captured = true;
  return 0;
}

// J (clean) with its pattern extended by t's, values K's (zero where only t has an entry).
PetscErrorCode extendPattern(Bulk &b, Mat t) {
  std::vector<PetscInt> counts(b.n), cols;
  std::vector<PetscScalar> vals;
  auto rowUnion = [&](PetscInt i) -> PetscErrorCode {
    PetscInt nk, nt;
    const PetscInt *ck, *ct;
    const PetscScalar *vk;
    cols.clear(); vals.clear();
    PetscCall(MatGetRow(b.J, i, &nk, &ck, &vk));
    PetscCall(MatGetRow(t, i, &nt, &ct, nullptr));
    PetscInt a = 0, c = 0;
    while (a < nk || c < nt) {
      if (c >= nt || (a < nk && ck[a] < ct[c])) { cols.push_back(ck[a]); vals.push_back(vk[a]); ++a; }
      else if (a >= nk || ct[c] < ck[a]) { cols.push_back(ct[c]); vals.push_back(0.0); ++c; }
      else { cols.push_back(ck[a]); vals.push_back(vk[a]); ++a; ++c; }
    }
    PetscCall(MatRestoreRow(t, i, &nt, &ct, nullptr));
    return MatRestoreRow(b.J, i, &nk, &ck, &vk);
  };
  for (PetscInt i = 0; i < b.n; ++i) {
    PetscCall(rowUnion(i));
    counts[i] = (PetscInt)cols.size();
  }
  Mat wider;
  PetscCall(MatCreate(PETSC_COMM_SELF, &wider));
  PetscCall(MatSetSizes(wider, b.n, b.n, b.n, b.n));
  PetscCall(MatSetType(wider, MATSEQAIJ));
  PetscCall(MatSeqAIJSetPreallocation(wider, 0, counts.data()));
  for (PetscInt i = 0; i < b.n; ++i) {
    PetscCall(rowUnion(i));
    PetscCall(MatSetValues(wider, 1, &i, (PetscInt)cols.size(), cols.data(), vals.data(), INSERT_VALUES));
  }
  PetscCall(MatAssemblyBegin(wider, MAT_FINAL_ASSEMBLY));
  PetscCall(MatAssemblyEnd(wider, MAT_FINAL_ASSEMBLY));
  PetscCall(MatDestroy(&b.J));
  b.J = wider;
  b.captured = false;
  return 0;
}

// Whether (row, col) is one of J's reserved entries, outside K's own pattern.
bool isReserved(const Bulk &b, PetscInt row, PetscInt col) {
  return std::binary_search(b.reserved.begin(), b.reserved.end(), std::make_pair(row, col));
}

// Whether every entry of t has a place in a's pattern.
PetscErrorCode within(Mat t, Mat a, bool *inside) {
  PetscInt n;
  PetscCall(MatGetSize(t, &n, nullptr));
  *inside = true;
  for (PetscInt i = 0; i < n && *inside; ++i) {
    PetscInt nt, na;
    const PetscInt *ct, *ca;
    PetscCall(MatGetRow(t, i, &nt, &ct, nullptr));
    if (nt) {
      PetscCall(MatGetRow(a, i, &na, &ca, nullptr));
      for (PetscInt k = 0; k < nt && *inside; ++k) *inside = std::binary_search(ca, ca + na, ct[k]);
      PetscCall(MatRestoreRow(a, i, &na, &ca, nullptr));
    }
    PetscCall(MatRestoreRow(t, i, &nt, &ct, nullptr));
  }
  return 0;
}

// J := K + T with the Dirichlet rows and columns identity ones. *widened: J's pattern had
// to grow for T (a new matrix: no preconditioner of the old one may be reused).
PetscErrorCode sumOperator(Bulk &b, Matrice_Creuse<double> *T, bool *widened) {
  Mat t;
  PetscCall(toPetsc(T, &t));
  PetscInt n;
  PetscCall(MatGetSize(t, &n, nullptr));
  if (n != b.n) {
    MatDestroy(&t);
    lastMessage = "the contact tangent has " + std::to_string(n) + " rows where K has " + std::to_string(b.n);
    return PETSC_ERR_ARG_SIZ;
  }
  PetscCall(restoreK(b));
  bool inside = false;
  PetscCall(within(t, b.J, &inside));
  *widened = !inside;
  if (!inside) {
    std::cout << "bulk: K's pattern widened for the contact tangent (a copy of the operator)" << std::endl;
    PetscCall(extendPattern(b, t));
  }
  if (b.whole.size() != (size_t)b.n) b.whole.assign(b.n, 0);
  for (PetscInt i : b.dirichlet)
    if (!b.whole[i]) { b.whole[i] = 1; b.captured = false; }
  for (PetscInt i = 0; i < n; ++i) {
    PetscInt nt;
    PetscCall(MatGetRow(t, i, &nt, nullptr, nullptr));
    if (nt && !b.whole[i]) { b.whole[i] = 1; b.captured = false; }
    PetscCall(MatRestoreRow(t, i, &nt, nullptr, nullptr));
  }
  if (!b.captured) PetscCall(captureK(b));
  PetscCall(MatAXPY(b.J, 1.0, t, SUBSET_NONZERO_PATTERN));
  PetscCall(MatDestroy(&t));
  PetscCall(MatZeroRowsColumns(b.J, (PetscInt)b.dirichlet.size(), b.dirichlet.data(), 1.0, nullptr, nullptr));
  b.clean = false;
  return 0;
}

PetscErrorCode vectorOf(KN<double> *v, PetscInt n, Vec *out) {
  if (v->N() != n) {
    lastMessage = "a vector of size " + std::to_string(v->N()) + " where K has " + std::to_string(n) + " rows";
    return PETSC_ERR_ARG_SIZ;
  }
  return VecCreateSeqWithArray(PETSC_COMM_SELF, 1, n, (PetscScalar *)(double *)*v, out);
}

// y = K x in every row (the Dirichlet rows are K's own): J x, corrected where J is not K.
PetscErrorCode multiplyK(Bulk &b, KN<double> *x, KN<double> *y) {
  if (!b.J) return b.releasedMult(*x, *y);
  Vec vx, vy;
  PetscCall(vectorOf(x, b.n, &vx));
  PetscCall(vectorOf(y, b.n, &vy));
  PetscCall(MatMult(b.J, vx, vy));
  PetscCall(VecDestroy(&vx));
  PetscCall(VecDestroy(&vy));
  if (b.clean) return 0;
  for (size_t s = 0; s < b.sRows.size(); ++s) {
    double sum = 0;
    for (PetscInt q = b.sPtr[s]; q < b.sPtr[s + 1]; ++q) sum += b.sVals[q] * (*x)[b.sCols[q]];
    (*y)[b.sRows[s]] = sum;
  }
  for (size_t d = 0; d < b.dPos.size(); ++d) (*y)[b.dRow[d]] += b.dVals[d] * (*x)[b.dCol[d]];
  return 0;
}

long bulkMult(long const &id, KN<double> *const &x, KN<double> *const &y) {
  Bulk *b = bulkOf(id);
  if (!b || !b->held()) return fail(PETSC_ERR_ARG_WRONGSTATE, "K x");
  if (y->N() != b->n) y->resize(b->n);
  TRY(multiplyK(*b, x, y), "K x");
  return 0;
}

long bulkDiagonal(long const &id, KN<double> *const &d) {
  Bulk *b = bulkOf(id);
  if (!b || !b->J) return fail(PETSC_ERR_ARG_WRONGSTATE, "K's diagonal");
  if (d->N() != b->n) d->resize(b->n);
  TRY(restoreK(*b), "K's diagonal");
  Vec vd;
  TRY(vectorOf(d, b->n, &vd), "K's diagonal");
  TRY(MatGetDiagonal(b->J, vd), "K's diagonal");
  VecDestroy(&vd);
  return 0;
}

// The Newton system's Dirichlet dofs (mask != 0): identity rows and columns in K + T.
long bulkDirichlet(long const &id, KN<double> *const &mask) {
  Bulk *b = bulkOf(id);
  if (!b || !b->J || mask->N() != b->n) return fail(PETSC_ERR_ARG_SIZ, "Dirichlet dofs");
  TRY(restoreK(*b), "Dirichlet dofs");
  b->dirichlet.clear();
  for (PetscInt i = 0; i < b->n; ++i) if ((*mask)[i] != 0) b->dirichlet.push_back(i);
  b->captured = false;
  return 0;
}

// K's entries, one "i j value" line each (0-based, rows sorted), under the header FreeFEM
// writes for its own sparse matrices ("n m nnz half fortran state"), for a test that compares
// K with FreeFEM's.
PetscErrorCode writeK(Bulk &b, const std::string &file) {
  PetscCall(restoreK(b));
  std::ofstream out(file.c_str());
  out.precision(20);
  Rows r;
  PetscCall(openRows(b.J, &r));
  out << "#  the bulk matrix K held by PETSc, as FreeFEM writes a sparse matrix\n"
      << "#    n       m        nnz     half     fortran   state\n"
      << b.n << " " << b.n << " " << r.ia[b.n] - (PetscInt)b.reserved.size() << " 0 0 2\n";
  for (PetscInt i = 0; i < b.n; ++i)
    for (PetscInt p = r.ia[i]; p < r.ia[i + 1]; ++p)
      if (!isReserved(b, i, r.ja[p])) out << i << " " << r.ja[p] << " " << r.a[p] << "\n";
  PetscCall(closeRows(&r));
  if (!out) {
    lastMessage = "cannot write " + file;
    return PETSC_ERR_FILE_WRITE;
  }
  return 0;
}

long bulkWrite(long const &id, string *const &file) {
  Bulk *b = bulkOf(id);
  if (!b || !b->J) return fail(PETSC_ERR_ARG_WRONGSTATE, "writing K");
  TRY(writeK(*b, *file), "writing K");
  return 0;
}

long bulkDestroy(long const &id) {
  Bulk *b = id >= 0 && id < (long)bulks.size() ? bulks[id] : nullptr;
  if (!b) return 0;
  MatDestroy(&b->J);   // a solver context still using it keeps its own reference
  delete b;
  bulks[id] = nullptr;
  return 0;
}

// ---- K by element kernel (petscBulkKernel*): P1 fields, one-point rule, one pass ----
// K's blocks are bilinear forms (freefem/forms.idp) whose integrands, for P1 fields and
// the centroid rule that integrates them exactly (forms.idp's bulkQF), read only each
// field component's value and gradient at the element's centroid. Such a block is one
// constant matrix D over those channels (value, d/dx_1 .. d/dx_d of each component): the
// element matrix is |T| Phi_i^T D Phi_j, Phi_i = (1/(d+1), grad lambda_i) for vertex i.
// The script reads D off the forms themselves, by assembling each block varf on a single
// element and probing it with linear functions (freefem/bulk_kernel.idp), so the physics
// stays in the forms; this kernel only does the element loop FreeFEM would interpret.
// tests/test_lean_bulk.py: the K built here equals the block-assembled one entry by entry.
struct KernelBlock {
  PetscInt rowOffset = 0, colOffset = 0;   // the fields' first rows and columns in K
  int rowComponents = 1, colComponents = 1, dim = 0;
  std::vector<double> d;                   // (rowComponents (dim+1)) x (colComponents (dim+1)), row-major
};
std::vector<std::vector<KernelBlock>> kernelBlocks;   // by bulk matrix id

long bulkKernelBlock(long const &id, KN<long> *const &layout, KN<double> *const &d) {
  Bulk *b = bulkOf(id);
  if (!b || b->J || layout->N() != 5) {
    if (b) lastMessage = "a kernel block needs [row offset, row components, column offset, column components, dimension]";
    return fail(PETSC_ERR_ARG_WRONG, "bulk kernel block");
  }
  KernelBlock k;
  k.rowOffset = (*layout)[0]; k.rowComponents = (int)(*layout)[1];
  k.colOffset = (*layout)[2]; k.colComponents = (int)(*layout)[3];
  k.dim = (int)(*layout)[4];
  long channels = k.dim + 1;
  if (d->N() != k.rowComponents * channels * k.colComponents * channels || k.rowOffset < 0 || k.colOffset < 0) {
    lastMessage = "a kernel block's matrix does not match its components";
    return fail(PETSC_ERR_ARG_SIZ, "bulk kernel block");
  }
  k.d.assign(&(*d)[0], &(*d)[0] + d->N());
  if ((long)kernelBlocks.size() <= id) kernelBlocks.resize(id + 1);
  kernelBlocks[id].push_back(std::move(k));
  return 0;
}

// The vertex neighbours of each vertex (itself included), sorted: the nodal pattern a P1
// varf assembles (every pair of vertices sharing an element, zeros too).
template <class M>
void vertexNeighbours(const M &th, std::vector<PetscInt> *ptr, std::vector<PetscInt> *adj) {
  const int nve = M::Rd::d + 1;   // simplices
  std::vector<std::vector<PetscInt>> rows(th.nv);
  for (int k = 0; k < th.nt; ++k)
    for (int i = 0; i < nve; ++i)
      for (int j = 0; j < nve; ++j) rows[th(k, i)].push_back(th(k, j));
  ptr->assign(th.nv + 1, 0);
  for (int v = 0; v < th.nv; ++v) {
    std::sort(rows[v].begin(), rows[v].end());
    rows[v].erase(std::unique(rows[v].begin(), rows[v].end()), rows[v].end());
    (*ptr)[v + 1] = (*ptr)[v] + (PetscInt)rows[v].size();
  }
  adj->resize((*ptr)[th.nv]);
  for (int v = 0; v < th.nv; ++v) {
    std::copy(rows[v].begin(), rows[v].end(), adj->begin() + (*ptr)[v]);
    std::vector<PetscInt>().swap(rows[v]);
  }
}

// Gradients of the barycentric coordinates of element k (row i: grad lambda_i) and its measure.
template <class M>
double elementGradients(const M &th, int k, double grad[4][3]) {
  const int dim = M::Rd::d;
  const double *p0 = &th(th(k, 0)).x;
  double jac[3][3], inv[3][3];
  for (int c = 0; c < dim; ++c)
    for (int r = 0; r < dim; ++r) jac[r][c] = (&th(th(k, c + 1)).x)[r] - p0[r];
  double det;
  if (dim == 2) {
    det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
    inv[0][0] = jac[1][1] / det; inv[0][1] = -jac[0][1] / det;
    inv[1][0] = -jac[1][0] / det; inv[1][1] = jac[0][0] / det;
  } else {
    det = jac[0][0] * (jac[1][1] * jac[2][2] - jac[1][2] * jac[2][1])
        - jac[0][1] * (jac[1][0] * jac[2][2] - jac[1][2] * jac[2][0])
        + jac[0][2] * (jac[1][0] * jac[2][1] - jac[1][1] * jac[2][0]);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        // the cofactor of (c, r) over det: the inverse's (r, c)
        int r1 = (c + 1) % 3, r2 = (c + 2) % 3, c1 = (r + 1) % 3, c2 = (r + 2) % 3;
        inv[r][c] = (jac[r1][c1] * jac[r2][c2] - jac[r1][c2] * jac[r2][c1]) / det;
      }
  }
  // lambda_{i+1} = row i of inv times (x - p0); lambda_0 = 1 - the others.
  for (int c = 0; c < dim; ++c) {
    grad[0][c] = 0;
    for (int i = 0; i < dim; ++i) { grad[i + 1][c] = inv[i][c]; grad[0][c] -= inv[i][c]; }
  }
  return std::abs(det) / (dim == 2 ? 2.0 : 6.0);
}

// The reserved entries (petscBulkReserve) that K's pattern lacks, sorted, each counted in its
// row and the row marked irregular: its K columns no longer sit block after block.
PetscErrorCode reserveOutsideK(Bulk &b, const std::vector<const KernelBlock *> &order, const std::vector<PetscInt> &ptr,
                               const std::vector<PetscInt> &adj, PetscInt nv, std::vector<PetscInt> *counts,
                               std::vector<char> *irregular) {
  auto inK = [&](const std::pair<PetscInt, PetscInt> &e) {
    for (const KernelBlock *k : order) {
      if (e.first < k->rowOffset || e.first >= k->rowOffset + nv * k->rowComponents ||
          e.second < k->colOffset || e.second >= k->colOffset + nv * k->colComponents) continue;
      PetscInt v = (e.first - k->rowOffset) / k->rowComponents, w = (e.second - k->colOffset) / k->colComponents;
      return std::binary_search(adj.begin() + ptr[v], adj.begin() + ptr[v + 1], w);
    }
    return false;
  };
  std::sort(b.reserved.begin(), b.reserved.end());
  b.reserved.erase(std::unique(b.reserved.begin(), b.reserved.end()), b.reserved.end());
  b.reserved.erase(std::remove_if(b.reserved.begin(), b.reserved.end(), inK), b.reserved.end());
  b.reserved.shrink_to_fit();
  irregular->assign(b.n, 0);
  for (const std::pair<PetscInt, PetscInt> &e : b.reserved) {
    ++(*counts)[e.first];
    (*irregular)[e.first] = 1;
  }
  if (!b.reserved.empty())
    std::cout << "bulk: room made in K for " << b.reserved.size() << " entries of the contact tangent" << std::endl;
  return 0;
}

// J = K from the registered blocks over the mesh: the pattern first (exactly the block
// varfs'), then each element's matrices added in place into J's values.
template <class M>
PetscErrorCode kernelAssemble(Bulk &b, const std::vector<KernelBlock> &blocks, const M &th) {
  const int dim = M::Rd::d, nve = dim + 1, ch = dim + 1;
  std::vector<PetscInt> ptr, adj;
  vertexNeighbours(th, &ptr, &adj);
  // Per row field (its offset), the blocks of that row in column order.
  std::vector<const KernelBlock *> order;
  for (const KernelBlock &k : blocks) order.push_back(&k);
  std::stable_sort(order.begin(), order.end(), [](const KernelBlock *x, const KernelBlock *y) {
    return x->rowOffset != y->rowOffset ? x->rowOffset < y->rowOffset : x->colOffset < y->colOffset; });
  for (const KernelBlock *k : order)
    if (k->dim != dim) {
      lastMessage = "a kernel block was read off a mesh of another dimension";
      return PETSC_ERR_ARG_WRONG;
    }
  for (const KernelBlock *k : order)
    if (k->rowOffset + (PetscInt)th.nv * k->rowComponents > b.n || k->colOffset + (PetscInt)th.nv * k->colComponents > b.n) {
      lastMessage = "a kernel block reaches past K: the mesh is not the fields' mesh";
      return PETSC_ERR_ARG_SIZ;
    }
  std::vector<PetscInt> counts(b.n, 0);
  for (const KernelBlock *k : order)
    for (int v = 0; v < th.nv; ++v)
      for (int c = 0; c < k->rowComponents; ++c)
        counts[k->rowOffset + (PetscInt)v * k->rowComponents + c] += (ptr[v + 1] - ptr[v]) * k->colComponents;
  std::vector<char> irregular;
  PetscCall(reserveOutsideK(b, order, ptr, adj, th.nv, &counts, &irregular));
  PetscCall(MatCreate(PETSC_COMM_SELF, &b.J));
  PetscCall(MatSetSizes(b.J, b.n, b.n, b.n, b.n));
  PetscCall(MatSetType(b.J, MATSEQAIJ));
  PetscCall(MatSeqAIJSetPreallocation(b.J, 0, counts.data()));
  PetscCall(MatSetOption(b.J, MAT_NEW_NONZERO_ALLOCATION_ERR, PETSC_TRUE));
  {
    const PetscScalar zero = 0;
    for (const std::pair<PetscInt, PetscInt> &e : b.reserved)
      PetscCall(MatSetValues(b.J, 1, &e.first, 1, &e.second, &zero, INSERT_VALUES));
    std::vector<PetscInt> cols;
    std::vector<PetscScalar> zeros;
    for (size_t first = 0; first < order.size();) {   // the blocks of one row field
      size_t last = first;
      while (last < order.size() && order[last]->rowOffset == order[first]->rowOffset) ++last;
      for (int v = 0; v < th.nv; ++v) {
        cols.clear();
        for (size_t q = first; q < last; ++q)
          for (PetscInt p = ptr[v]; p < ptr[v + 1]; ++p)
            for (int c = 0; c < order[q]->colComponents; ++c)
              cols.push_back(order[q]->colOffset + adj[p] * order[q]->colComponents + c);
        zeros.assign(cols.size(), 0.0);
        for (int c = 0; c < order[first]->rowComponents; ++c) {
          PetscInt row = order[first]->rowOffset + (PetscInt)v * order[first]->rowComponents + c;
          PetscCall(MatSetValues(b.J, 1, &row, (PetscInt)cols.size(), cols.data(), zeros.data(), INSERT_VALUES));
        }
      }
      first = last;
    }
  }
  PetscCall(MatAssemblyBegin(b.J, MAT_FINAL_ASSEMBLY));
  PetscCall(MatAssemblyEnd(b.J, MAT_FINAL_ASSEMBLY));
  // Where block q starts in a row of vertex v: the row's start plus the earlier blocks of its field.
  std::vector<PetscInt> before(order.size(), 0);   // columns per neighbour of the earlier blocks
  for (size_t q = 1; q < order.size(); ++q)
    before[q] = order[q]->rowOffset == order[q - 1]->rowOffset ? before[q - 1] + order[q - 1]->colComponents : 0;
  Rows r;
  PetscCall(openRows(b.J, &r));
  double grad[4][3], phi[4][4], left[3 * 4];
  PetscInt rank[4][4];
  for (int k = 0; k < th.nt; ++k) {
    double measure = elementGradients(th, k, grad);
    int vert[4];
    for (int i = 0; i < nve; ++i) {
      vert[i] = th(k, i);
      phi[i][0] = 1.0 / nve;
      for (int c = 0; c < dim; ++c) phi[i][c + 1] = grad[i][c];
    }
    for (int i = 0; i < nve; ++i)
      for (int j = 0; j < nve; ++j)
        rank[i][j] = std::lower_bound(adj.begin() + ptr[vert[i]], adj.begin() + ptr[vert[i] + 1], (PetscInt)vert[j]) -
                     (adj.begin() + ptr[vert[i]]);
    for (size_t q = 0; q < order.size(); ++q) {
      const KernelBlock &kb = *order[q];
      const int nc = kb.colComponents, width = nc * ch;
      for (int i = 0; i < nve; ++i) {
        const PetscInt neighbours = ptr[vert[i] + 1] - ptr[vert[i]];
        for (int cr = 0; cr < kb.rowComponents; ++cr) {
          // left = |T| Phi_i^T D, the row of component cr of vertex i, over the column channels
          for (int cb = 0; cb < width; ++cb) {
            double sum = 0;
            for (int a = 0; a < ch; ++a) sum += phi[i][a] * kb.d[(size_t)(cr * ch + a) * width + cb];
            left[cb] = measure * sum;
          }
          PetscInt row = kb.rowOffset + (PetscInt)vert[i] * kb.rowComponents + cr;
          PetscScalar *values = r.a + r.ia[row] + before[q] * neighbours;
          for (int j = 0; j < nve; ++j)
            for (int cc = 0; cc < nc; ++cc) {
              double sum = 0;
              for (int a = 0; a < ch; ++a) sum += left[cc * ch + a] * phi[j][a];
              if (irregular[row]) {   // reserved entries shift K's columns: look the column up
                PetscInt col = kb.colOffset + (PetscInt)vert[j] * nc + cc;
                r.a[std::lower_bound(r.ja + r.ia[row], r.ja + r.ia[row + 1], col) - r.ja] += sum;
              } else {
                values[rank[i][j] * nc + cc] += sum;
              }
            }
        }
      }
    }
  }
  PetscCall(closeRows(&r));
  return 0;
}

template <class M>
long bulkKernel(long const &id, const M *const &th) {
  Bulk *b = bulkOf(id);
  if (!b || b->J || !b->chunks.empty() || id >= (long)kernelBlocks.size() || kernelBlocks[id].empty() || !th) {
    if (b) lastMessage = "the kernel needs its blocks, and a bulk matrix that has no block yet";
    return fail(PETSC_ERR_ARG_WRONGSTATE, "bulk kernel");
  }
  PetscErrorCode ierr = kernelAssemble(*b, kernelBlocks[id], *th);
  std::vector<KernelBlock>().swap(kernelBlocks[id]);
  if (ierr) return fail(ierr, "bulk kernel");
  return 0;
}

// ---- The contact kernel: Gamma_3's residual and tangent in one pass over its faces ----
// The integrands are freefem/contact_forms.idp's macros, as FreeFEM expands them, compiled here
// through contact_forms.hpp (harness/run/contact_forms.py): this code does only the loop over
// Gamma_3's faces and quadrature points that FreeFEM's boundary varfs interpret (about 90 us a
// point). Each form is linear in the test function (residual) and bilinear in the increment and
// the test function (tangent), so a point's vector or block is the form evaluated with unit ones,
// as the bulk kernel's D is read off a form with unit probes. The rule is FreeFEM's own contactQF
// (dimension.idp): 2-point Gauss-Legendre on an edge, the 7-point degree-5 rule on a triangle.
// tests/test_lean_bulk.py: both equal the varfs' entry by entry.
struct ContactSetup {
  long label = 0;
  int dim = 0;
  long offset[3] = {-1, -1, -1};   // u, phi, theta in the Newton vector (-1: not in it)
  bool friction = false, electric = false, thermal = false;
  contact_forms::Law law;
};

bool contactSetup(KN<long> *layout, KN<double> *law, long n, ContactSetup *s) {
  const long laws = sizeof(contact_forms::Law) / sizeof(double);
  if (layout->N() != 8 || law->N() != laws) {
    lastMessage = "the contact kernel needs [label, dimension, u, phi and theta offsets, friction, electric, thermal] "
                  "and " + std::to_string(laws) + " law constants";
    return false;
  }
  s->label = (*layout)[0];
  s->dim = (int)(*layout)[1];
  for (int f = 0; f < 3; ++f) s->offset[f] = (*layout)[2 + f];
  s->friction = (*layout)[5] != 0;
  s->electric = (*layout)[6] != 0 && s->offset[1] >= 0;
  s->thermal = (*layout)[7] != 0 && s->offset[2] >= 0;
  double *to = &s->law.cnu;
  for (long i = 0; i < laws; ++i) to[i] = (*law)[i];
  if (s->offset[0] < 0 || s->offset[0] >= n || s->offset[1] >= n || s->offset[2] >= n) {
    lastMessage = "the contact kernel's field offsets lie outside the Newton vector";
    return false;
  }
  return true;
}

long boundaryCount(const Mesh &th) { return th.neb; }
long boundaryCount(const Mesh3 &th) { return th.nbe; }

// Each quadrature point of each face labelled s.label: visit(vertices, lambda, weight, point)
// with the face's vertices, their P1 basis values and the point's state and outward normal.
template <class M, class Visit>
bool contactPoints(const M &th, const ContactSetup &s, const KN<double> &x, Visit visit) {
  const int dim = M::Rd::d;
  if (dim != s.dim) {
    lastMessage = "the contact kernel's mesh is not of the scene's dimension";
    return false;
  }
  std::vector<std::vector<double>> bary;   // the rule's points, barycentric on the face
  std::vector<double> weights;
  if (dim == 2) {
    const QuadratureFormular1d &qf = QF_GaussLegendre2;
    for (int q = 0; q < qf.n; ++q) { bary.push_back({1 - qf[q].x, qf[q].x}); weights.push_back(qf[q].a); }
  } else {
    const GQuadratureFormular<R2> &qf = QuadratureFormular_T_5;
    for (int q = 0; q < qf.n; ++q) { bary.push_back({1 - qf[q].x - qf[q].y, qf[q].x, qf[q].y}); weights.push_back(qf[q].a); }
  }
  for (long ibe = 0; ibe < boundaryCount(th); ++ibe) {
    if (th.be(ibe).lab != s.label) continue;
    int ie;
    const int k = th.BoundaryElement(ibe, ie);
    int vert[3];
    double p[3][3] = {{0}}, opposite[3] = {0};
    for (int i = 0, f = 0; i <= dim; ++i) {
      const double *c = &th(th(k, i)).x;
      if (i == ie) { for (int r = 0; r < dim; ++r) opposite[r] = c[r]; continue; }
      vert[f] = th(k, i);
      for (int r = 0; r < dim; ++r) p[f][r] = c[r];
      ++f;
    }
    // The face's normal, its measure, and the normal turned away from the element's other vertex.
    double normal[3] = {0, 0, 0}, measure;
    if (dim == 2) {
      normal[0] = p[1][1] - p[0][1]; normal[1] = p[0][0] - p[1][0];
      measure = std::sqrt(normal[0] * normal[0] + normal[1] * normal[1]);
    } else {
      double e1[3], e2[3];
      for (int r = 0; r < 3; ++r) { e1[r] = p[1][r] - p[0][r]; e2[r] = p[2][r] - p[0][r]; }
      normal[0] = e1[1] * e2[2] - e1[2] * e2[1];
      normal[1] = e1[2] * e2[0] - e1[0] * e2[2];
      normal[2] = e1[0] * e2[1] - e1[1] * e2[0];
      measure = 0.5 * std::sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]);
    }
    double length = std::sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]), side = 0;
    for (int r = 0; r < dim; ++r) side += normal[r] * (p[0][r] - opposite[r]);
    if (side < 0) length = -length;
    contact_forms::Point point = {};
    point.N = {normal[0] / length, normal[1] / length, normal[2] / length};
    for (size_t q = 0; q < weights.size(); ++q) {
      const std::vector<double> &lambda = bary[q];
      double u[3] = {0, 0, 0}, ph = 0, tt = 0;
      for (int j = 0; j < dim; ++j) {
        for (int c = 0; c < dim; ++c) u[c] += lambda[j] * x[s.offset[0] + (long)vert[j] * dim + c];
        if (s.offset[1] >= 0) ph += lambda[j] * x[s.offset[1] + vert[j]];
        if (s.offset[2] >= 0) tt += lambda[j] * x[s.offset[2] + vert[j]];
      }
      point.u1 = u[0]; point.u2 = u[1]; point.u3 = u[2]; point.ph = ph; point.th = tt;
      visit(vert, lambda.data(), weights[q] * measure, point);
    }
  }
  return true;
}

// r = the contact residual at the Newton vector x (contactR of every field, in its place).
template <class M>
long contactResidual(const M *const &th, KN<long> *const &layout, KN<double> *const &law, KN<double> *const &x,
                     KN<double> *const &r) {
  ContactSetup s;
  if (!th || r->N() != x->N() || !contactSetup(layout, law, x->N(), &s)) {
    if (th && r->N() != x->N()) lastMessage = "the contact residual's vector is not the Newton vector's size";
    return fail(PETSC_ERR_ARG_WRONG, "contact residual");
  }
  const contact_forms::Forms &forms = contact_forms::kForms[s.dim - 2][s.friction];
  const int dim = s.dim;
  *r = 0.;
  bool ok = contactPoints(*th, s, *x, [&](const int *vert, const double *lambda, double w, contact_forms::Point &pt) {
    double *v[3] = {&pt.v1, &pt.v2, &pt.v3};
    for (int c = 0; c < dim; ++c) {
      *v[c] = 1;
      const double value = w * forms.Ru(s.law, pt);
      *v[c] = 0;
      for (int j = 0; j < dim; ++j) (*r)[s.offset[0] + (long)vert[j] * dim + c] += lambda[j] * value;
    }
    if (s.electric) {
      pt.vp = 1;
      const double value = w * forms.Rp(s.law, pt);
      pt.vp = 0;
      for (int j = 0; j < dim; ++j) (*r)[s.offset[1] + vert[j]] += lambda[j] * value;
    }
    if (s.thermal) {
      pt.vt = 1;
      const double value = w * forms.Rt(s.law, pt);
      pt.vt = 0;
      for (int j = 0; j < dim; ++j) (*r)[s.offset[2] + vert[j]] += lambda[j] * value;
    }
  });
  if (!ok) return fail(PETSC_ERR_ARG_WRONG, "contact residual");
  return 0;
}

// T = the contact tangent at the Newton vector x, a FreeFEM matrix of the Newton system's size.
template <class M>
long contactTangent(const M *const &th, KN<long> *const &layout, KN<double> *const &law, KN<double> *const &x,
                    Matrice_Creuse<double> *const &T) {
  ContactSetup s;
  if (!th || !contactSetup(layout, law, x->N(), &s)) return fail(PETSC_ERR_ARG_WRONG, "contact tangent");
  const contact_forms::Forms &forms = contact_forms::kForms[s.dim - 2][s.friction];
  const int dim = s.dim;
  const int n = (int)x->N();
  HashMatrix<int, double> *t = new HashMatrix<int, double>(n, n, 0, 0);
  auto add = [&](long row, long col, double value) { (*t)((int)row, (int)col) += value; };
  bool ok = contactPoints(*th, s, *x, [&](const int *vert, const double *lambda, double w, contact_forms::Point &pt) {
    double *a[3] = {&pt.a1, &pt.a2, &pt.a3}, *v[3] = {&pt.v1, &pt.v2, &pt.v3};
    double block[3][3], fromU[2][3], diagonal[2] = {0, 0};
    for (int cj = 0; cj < dim; ++cj) {
      *a[cj] = 1;
      for (int ci = 0; ci < dim; ++ci) { *v[ci] = 1; block[ci][cj] = w * forms.Tuu(s.law, pt); *v[ci] = 0; }
      if (s.electric) { pt.vp = 1; fromU[0][cj] = w * forms.Tpu(s.law, pt); pt.vp = 0; }
      if (s.thermal) { pt.vt = 1; fromU[1][cj] = w * forms.Ttu(s.law, pt); pt.vt = 0; }
      *a[cj] = 0;
    }
    if (s.electric) { pt.ap = 1; pt.vp = 1; diagonal[0] = w * forms.Tpp(s.law, pt); pt.ap = 0; pt.vp = 0; }
    if (s.thermal) { pt.at = 1; pt.vt = 1; diagonal[1] = w * forms.Ttt(s.law, pt); pt.at = 0; pt.vt = 0; }
    for (int i = 0; i < dim; ++i)
      for (int j = 0; j < dim; ++j) {
        const double ll = lambda[i] * lambda[j];
        const long rowU = s.offset[0] + (long)vert[i] * dim, colU = s.offset[0] + (long)vert[j] * dim;
        for (int ci = 0; ci < dim; ++ci)
          for (int cj = 0; cj < dim; ++cj) add(rowU + ci, colU + cj, ll * block[ci][cj]);
        for (int f = 0; f < 2; ++f) {
          if (!(f == 0 ? s.electric : s.thermal)) continue;
          const long row = s.offset[1 + f] + vert[i];
          for (int cj = 0; cj < dim; ++cj) add(row, colU + cj, ll * fromU[f][cj]);
          add(row, s.offset[1 + f] + vert[j], ll * diagonal[f]);
        }
      }
  });
  if (!ok) {
    delete t;
    return fail(PETSC_ERR_ARG_WRONG, "contact tangent");
  }
  T->A.master(t);
  return 0;
}

// 1 when the compiled integrands are the script's own expansions of contact_forms.idp (texts: each
// form's and check's Stringification, in kFormTexts' order, separated by "@@"), 0 otherwise, with
// a note naming the first that differs: a law changed since contact_forms.hpp was written, or a
// copy of the scripts with another law, then goes to FreeFEM's varfs instead.
long contactCurrent(KN<long> *const &layout, string *const &texts) {
  if (layout->N() != 8 || (*layout)[1] < 2 || (*layout)[1] > 3) {
    lastMessage = "the contact kernel's layout has no dimension";
    return fail(PETSC_ERR_ARG_WRONG, "contact kernel");
  }
  auto folded = [](const std::string &text) {
    std::istringstream words(text);
    std::string word, out;
    while (words >> word) out += (out.empty() ? "" : " ") + word;
    return out;
  };
  const char *const *compiled = contact_forms::kFormTexts[(*layout)[1] - 2][(*layout)[5] != 0];
  std::string all = *texts;
  for (int i = 0; i < contact_forms::kTexts; ++i) {
    size_t end = all.find("@@");
    std::string mine = folded(all.substr(0, end));
    all = end == std::string::npos ? std::string() : all.substr(end + 2);
    if (*compiled[i] && mine != compiled[i]) {
      std::cout << "note: the contact kernel's integrand " << i << " is not this script's contact_forms.idp "
                << "(`python -m harness.run.contact_forms` writes it again): FreeFEM's varfs assemble the contact terms"
                << std::endl;
      return 0;
    }
  }
  return 1;
}

// The weight of each vertex in the checks' integrals below, interpolated at each point: on MPI ranks
// the rank's partition of unity, so that the ranks' integrals sum to the whole Gamma_3's
// (freefem/parallel_output.idp); none (every weight 1) on one rank.
std::vector<double> contactShares;
long contactWeights(KN<double> *const &w) {
  contactShares.assign(w->N(), 0.0);
  for (long i = 0; i < w->N(); ++i) contactShares[i] = (*w)[i];
  return 0;
}

// values = the physical checks' integrals over Gamma_3 at x (contact_forms.hpp's kCheckForms),
// each point weighted by contactShares where they are given.
template <class M>
long contactIntegrals(const M *const &th, KN<long> *const &layout, KN<double> *const &law, KN<double> *const &x,
                      KN<double> *const &values) {
  ContactSetup s;
  const bool shared = !contactShares.empty();
  if (!th || values->N() != contact_forms::kChecks || !contactSetup(layout, law, x->N(), &s) ||
      (shared && (long)contactShares.size() != th->nv)) {
    if (th && values->N() != contact_forms::kChecks)
      lastMessage = "the contact integrals need a vector of " + std::to_string(contact_forms::kChecks);
    else if (th && shared && (long)contactShares.size() != th->nv)
      lastMessage = "the contact integrals' weights are not one a vertex of the mesh";
    return fail(PETSC_ERR_ARG_WRONG, "contact integrals");
  }
  const contact_forms::Form *checks = contact_forms::kCheckForms[s.dim - 2][s.friction];
  const int dim = s.dim;
  *values = 0.;
  bool ok = contactPoints(*th, s, *x, [&](const int *vert, const double *lambda, double w, contact_forms::Point &pt) {
    if (shared) {
      double share = 0;
      for (int j = 0; j < dim; ++j) share += lambda[j] * contactShares[vert[j]];
      w *= share;
    }
    for (int q = 0; q < contact_forms::kChecks; ++q) (*values)[q] += w * checks[q](s.law, pt);
  });
  if (!ok) return fail(PETSC_ERR_ARG_WRONG, "contact integrals");
  return 0;
}

long krylov(Context *c, KN<double> *b, KN<double> *x, double rtol, long reuse);

// x = A^-1 b to ||b - A x|| <= rtol ||b||, from x = 0.
// reuse: 0 a new operator A and a preconditioner built from it; 1 the operator A with the
// preconditioner of an earlier matrix (a Newton tangent a few contact nodes away);
// 2 the last operator and preconditioner again (A is not read: no copy).
long solve(long const &id, Matrice_Creuse<double> *const &A, KN<double> *const &b, KN<double> *const &x,
           double const &rtol, long const &reuse) {
  Context *c = context(id);
  if (!c) return fail(PETSC_ERR_ARG_OUTOFRANGE, "solve");
  double c0 = cpu();
  if (reuse < 2 || !c->op) {
    Mat next;
    TRY(toPetsc(A, &next), "matrix");
    TRY(dirichletRows(next, &c->dirichlet), "Dirichlet rows");
    TRY(MatZeroRowsColumns(next, (PetscInt)c->dirichlet.size(), c->dirichlet.data(), 1.0, nullptr, nullptr),
        "Dirichlet rows");
    TRY(MatDestroy(&c->op), "matrix");
    c->op = next;
  }
  c->cpuOperator = cpu() - c0;
  c->peakOperator = peakMb();
  return krylov(c, b, x, rtol, reuse);
}

// The same with the operator K + T: K the bulk matrix `bulk` (petscBulk*), T its low-rank
// change (the contact tangent, on Gamma_3's rows), the Dirichlet dofs K's.
long solveBulk(long const &id, long const &bulk, Matrice_Creuse<double> *const &T, KN<double> *const &b,
               KN<double> *const &x, double const &rtol, long const &reuse) {
  Context *c = context(id);
  if (!c) return fail(PETSC_ERR_ARG_OUTOFRANGE, "solve");
  Bulk *k = bulkOf(bulk);
  if (!k || !k->J) return fail(PETSC_ERR_ARG_WRONGSTATE, "solve");
  double c0 = cpu();
  long use = reuse;
  // A clean J holds K alone (put back for K's diagonal, say): the operator is summed again.
  if (reuse < 2 || !c->op || k->clean) {
    bool widened = false;
    TRY(sumOperator(*k, T, &widened), "matrix K + T");
    if (c->op != k->J) {
      TRY(MatDestroy(&c->op), "matrix K + T");
      TRY(PetscObjectReference((PetscObject)k->J), "matrix K + T");
      c->op = k->J;
    }
    c->dirichlet = k->dirichlet;
    if (widened) use = 0;
  }
  c->cpuOperator = cpu() - c0;
  c->peakOperator = peakMb();
  return krylov(c, b, x, rtol, use);
}

// After a KSPSolve of c on vb, vx (started at t1, CPU c1): the options PETSc never read
// (checked once, after the first solve: by then PETSc has read every option it will), the times,
// the converged reason, the iterations and the true relative residual, whatever norm the Krylov
// method monitored. *result: the iterations, kNotConverged or kUnusedOption.
PetscErrorCode afterSolve(Context *c, Vec vb, Vec vx, double t1, double c1, long *result) {
  if (!c->checkedOptions) {
    c->checkedOptions = true;
    std::string unused;
    PetscCall(unusedOptions(*c, &unused));
    if (!unused.empty()) {
      std::cout << "error: PETSc option(s) " << unused
                << " never used (misspelt, or for another solver or preconditioner)" << std::endl;
      *result = kUnusedOption;
      return 0;
    }
  }
  c->lastSolve = now() - t1;
  c->cpuSolve = cpu() - c1;
  c->peakSolve = peakMb();
  c->totalSolve += c->lastSolve;
  KSPConvergedReason reason;
  PetscCall(KSPGetConvergedReason(c->ksp, &reason));
  PetscCall(KSPGetIterationNumber(c->ksp, &c->lastIts));
  Vec r;
  PetscReal rn, bn;
  PetscCall(VecDuplicate(vb, &r));
  PetscCall(MatMult(c->op, vx, r));
  PetscCall(VecAYPX(r, -1.0, vb));
  PetscCall(VecNorm(r, NORM_2, &rn));
  PetscCall(VecNorm(vb, NORM_2, &bn));
  PetscCall(VecDestroy(&r));
  c->lastResidual = bn > 0 ? rn / bn : rn;
  c->lastReason = (int)reason;
  c->totalIts += c->lastIts;
  ++c->solves;
  *result = reason > 0 ? (long)c->lastIts : kNotConverged;
  return 0;
}

long krylov(Context *c, KN<double> *b, KN<double> *x, double rtol, long reuse) {
  bool rebuild = !reuse || !c->pre;
  PetscInt n;
  TRY(MatGetSize(c->op, &n, nullptr), "matrix");
  if (n != c->size || b->N() != n || x->N() != n) {
    std::cout << "error: PETSc solve: sizes differ (matrix " << n << ", fields " << c->size << ", b " << b->N()
              << ", x " << x->N() << ")" << std::endl;
    return kPetscError;
  }
  std::string step;
  TRY(useOperator(c, rebuild, rtol, true, attachLevels, &step), step);
  double t0 = now(), c0 = cpu();
  if (rebuild) {
    TRY(memoryBreakdown(*c, "before set-up"), "memory breakdown");
    TRY(KSPSetUp(c->ksp), "set-up");
    PC pc;
    TRY(KSPGetPC(c->ksp, &pc), "set-up");
    TRY(PCSetUp(pc), "preconditioner set-up");
    TRY(memoryBreakdown(*c, "after set-up"), "memory breakdown");
    c->lastSetup = now() - t0;
    c->cpuSetup = cpu() - c0;
    c->peakSetup = peakMb();
    c->totalSetup += c->lastSetup;
    ++c->setups;
  } else {
    c->lastSetup = 0;
    c->cpuSetup = 0;
    c->peakSetup = peakMb();
  }
  Vec vb, vx;
  TRY(VecCreateSeqWithArray(PETSC_COMM_SELF, 1, n, (PetscScalar *)(double *)*b, &vb), "vector");
  TRY(VecCreateSeqWithArray(PETSC_COMM_SELF, 1, n, (PetscScalar *)(double *)*x, &vx), "vector");
  for (PetscInt i : c->dirichlet) (*b)[i] = 0;
  double t1 = now(), c1 = cpu();
  TRY(KSPSolve(c->ksp, vb, vx), "solve");
  TRY(memoryBreakdown(*c, "after solve"), "memory breakdown");
  long result;
  TRY(afterSolve(c, vb, vx, t1, c1, &result), "solve");
  TRY(VecDestroy(&vb), "vector");
  TRY(VecDestroy(&vx), "vector");
  return result;
}

// stats = [iterations, true relative residual, converged reason, set-up s, solve s,
//          total iterations, total set-up s, total solve s, set-ups, solves,
//          the last call's CPU s of forming its operator, set-up, solve, and the peak resident
//          memory in MB after each of these three] (resized to 16 entries)
long stats(long const &id, KN<double> *const &out) {
  Context *c = context(id);
  if (!c) return fail(PETSC_ERR_ARG_OUTOFRANGE, "stats");
  double values[] = {(double)c->lastIts, c->lastResidual, (double)c->lastReason, c->lastSetup, c->lastSolve,
                     (double)c->totalIts, c->totalSetup, c->totalSolve, (double)c->setups, (double)c->solves,
                     c->cpuOperator, c->cpuSetup, c->cpuSolve, c->peakOperator, c->peakSetup, c->peakSolve,
                     c->wallOperator};
  long count = sizeof(values) / sizeof(values[0]);
  if (out->N() < count) out->resize(count);
  for (long k = 0; k < count; ++k) (*out)[k] = values[k];
  return 0;
}

// One more coarse level for -pc_type mg: the nodal interpolation from the next coarser
// mesh of a nested family onto the last level given (the Newton mesh first).
long addLevel(long const &id, Matrice_Creuse<double> *const &P) {
  Context *c = context(id);
  if (!c) return fail(PETSC_ERR_ARG_OUTOFRANGE, "level");
  MatriceMorse<double> *a = P->A ? dynamic_cast<MatriceMorse<double> *>(&*P->A) : nullptr;
  if (!a) {
    lastMessage = "the interpolation is not a sparse matrix";
    return fail(PETSC_ERR_ARG_WRONG, "level");
  }
  a->CSR();
  std::vector<PetscInt> rows(a->p, a->p + a->n + 1), cols(a->j, a->j + a->nnz);
  Mat m;
  TRY(MatCreate(PETSC_COMM_SELF, &m), "level");
  TRY(MatSetSizes(m, a->n, a->m, a->n, a->m), "level");
  TRY(MatSetType(m, MATSEQAIJ), "level");
  TRY(MatSeqAIJSetPreallocationCSR(m, rows.data(), cols.data(), a->aij), "level");
  c->nodal.push_back(m);
  return (long)c->nodal.size();
}

// The Krylov solver and its preconditioner let go once Newton is done, the operator kept for K x:
// the checks and the estimator then take their memory instead of raising the peak (3D h = 1/32 on
// 2 ranks: the checks raised each rank's peak by 25-45 MiB before).
long releasePreconditioner(long const &id) {
  Context *c = context(id);
  if (c) KSPDestroy(&c->ksp);
  malloc_trim(0);   // handed back: under FreeFem++-mpi it would stay in the heap (releaseK)
  return 0;
}

long destroy(long const &id) {
  Context *c = context(id);
  if (!c) return 0;
  KSPDestroy(&c->ksp);
  MatDestroy(&c->op);
  MatDestroy(&c->pre);
  for (IS &is : c->fields) ISDestroy(&is);
  MatNullSpaceDestroy(&c->rigid);
  ISDestroy(&c->zone);
  for (Mat &m : c->nodal) MatDestroy(&m);
  delete c;
  contexts[id] = nullptr;
  return 0;
}

// ---- Distributed solves: run.ranks > 1 (freefem/petsc_ranks.idp) ----
//
// On N ranks each rank holds its overlapping subdomain (freefem/ranks.idp): its Newton vector's
// dofs, the partition of unity D on them, and for each its index in the natural numbering of
// the whole mesh's Newton vector (fields concatenated, a vector field's components per node),
// which the script reads off the whole mesh once (freefem/ranks.idp). From these:
//
//   int part = petscRanksPart(natural, D, dirichlet);      // who owns which dof, PETSc's numbering
//   int id = petscRanksCreate(part, options, names, sizes, blocks, coords);
//   petscAddLevel(id, interpolation);                      // multigrid levels, as on one rank
//   int its = petscRanksSolve(id, bulk, T, b, x, rtol, reuse);   // this rank's K (petscBulk*), T
//
// Each dof is owned by the lowest rank whose D is non-zero there; a rank's owned dofs are
// consecutive in PETSc's numbering, in the order of its Newton vector, so each field's owned
// dofs are one stride and the displacement's components stay together (block size d).
// The distributed matrix is sum_i R_i^T D_i A_i R_i (where D_i != 0 a local row is the
// global row, ranks.idp), each rank adding its rows with D_i != 0; the Dirichlet rows and
// columns (of a mask consistent over the ranks) become identity ones, as on one rank
// (dirichletRows). A vector goes in by its owners' entries and comes back to every local dof
// by one scatter, so the increment is the same on every rank to the bit.
struct RanksPart {
  PetscInt local = 0, owned = 0, first = 0, size = 0;
  std::vector<PetscInt> index;       // PETSc's global index of each local dof
  std::vector<char> own, dirichlet;  // owned here; a Dirichlet dof (consistent mask)
  std::vector<double> weight;        // D
  VecScatter toLocal = nullptr;      // PETSc's vector -> every local dof
  Vec spread = nullptr, seq = nullptr;   // a vector of PETSc's layout; the local dofs' one
  std::vector<PetscInt> sizes, blocks;   // each field's local dofs and components per node
  // K held once (petscRanksHoldOnce): after the first operator the subdomain's K lives only in the
  // distributed matrix. Kept aside are what that matrix does not hold as K: the rows K + T changes
  // (refill: the contact rows, the script's mask) and the Dirichlet rows, whole, and the Dirichlet
  // columns' entries of the other rows, each of this rank's rows with D != 0 (complete rows), in
  // the local numbering.
  bool holdOnce = false;
  std::vector<char> refill;
  std::vector<PetscInt> keptRows, keptPtr, keptCols, dRow, dCol;
  std::vector<PetscScalar> keptVals, dVals;
};
std::vector<RanksPart *> parts;
std::vector<long> partOfContext;   // contexts[id]'s part, -1: a one-rank context

int mpiRank() {
  int r = 0;
  MPI_Comm_rank(PETSC_COMM_WORLD, &r);
  return r;
}

// An error on one rank or on all: each rank that meets it says it, with its rank (the harness
// reports the first line), and the script ends every rank with petscRanksAbort.
long failRanks(PetscErrorCode ierr, const std::string &where) {
  return fail(ierr, where + " (rank " + std::to_string(mpiRank()) + ")");
}

// Ends every rank with `code`: the ranks still waiting in a collective call for the one that
// failed would otherwise wait for ever (MPI_Abort; the launcher returns its code).
long ranksAbort(long const &code) {
  std::cout.flush();
  MPI_Abort(PETSC_COMM_WORLD, (int)code);
  return code;
}
#define TRYRANKS(call, where) do { PetscErrorCode ierr_ = (call); if (ierr_) return failRanks(ierr_, where); } while (0)
// An error inside the Krylov solve or its preconditioner's set-up (a failed factorisation,
// -ksp_error_if_not_converged, ...): the solve failed, not the options (freefem/petsc_ranks.idp).
const long kKrylovError = -4;
// A broken invariant of the plugin itself (PETSC_ERR_PLIB from our own code), not the user's options
// or the solve (exit INTERNAL).
const long kInternalError = -5;
#define TRYKRYLOV(call, where) do { PetscErrorCode ierr_ = (call); if (ierr_) { failRanks(ierr_, where); return kKrylovError; } } while (0)

RanksPart *partOf(long id) {
  if (id < 0 || id >= (long)partOfContext.size() || partOfContext[id] < 0) return nullptr;
  return parts[partOfContext[id]];
}

// Owners and PETSc's numbering: the natural numbering's dofs split evenly over the ranks as
// roots of a star forest whose leaves are the ranks' local dofs; a reduction finds each dof's
// lowest rank with D != 0, the owners number theirs, a second reduction hands the numbers out.
PetscErrorCode numberDofs(RanksPart &p, const std::vector<PetscInt> &natural) {
  MPI_Comm comm = PETSC_COMM_WORLD;
  int rank = mpiRank();
  PetscInt largest = -1;
  for (PetscInt k : natural) largest = std::max(largest, k);
  PetscCallMPI(MPI_Allreduce(&largest, &p.size, 1, MPIU_INT, MPI_MAX, comm));
  ++p.size;
  PetscLayout layout;
  PetscCall(PetscLayoutCreate(comm, &layout));
  PetscCall(PetscLayoutSetSize(layout, p.size));
  PetscCall(PetscLayoutSetUp(layout));
  PetscSF sf;
  PetscCall(PetscSFCreate(comm, &sf));
  PetscCall(PetscSFSetGraphLayout(sf, layout, p.local, nullptr, PETSC_COPY_VALUES, natural.data()));
  PetscInt roots;
  PetscCall(PetscLayoutGetLocalSize(layout, &roots));
  PetscCall(PetscLayoutDestroy(&layout));
  const PetscInt none = std::numeric_limits<PetscInt>::max();
  std::vector<PetscInt> rootData(roots, none), leafData(p.local);
  for (PetscInt i = 0; i < p.local; ++i) leafData[i] = p.weight[i] > 0 ? rank : none;
  PetscCall(PetscSFReduceBegin(sf, MPIU_INT, leafData.data(), rootData.data(), MPI_MIN));
  PetscCall(PetscSFReduceEnd(sf, MPIU_INT, leafData.data(), rootData.data(), MPI_MIN));
  PetscCall(PetscSFBcastBegin(sf, MPIU_INT, rootData.data(), leafData.data(), MPI_REPLACE));
  PetscCall(PetscSFBcastEnd(sf, MPIU_INT, rootData.data(), leafData.data(), MPI_REPLACE));
  p.own.assign(p.local, 0);
  p.owned = 0;
  bool uncovered = false;
  for (PetscInt i = 0; i < p.local; ++i) {
    uncovered = uncovered || leafData[i] == none;
    if (leafData[i] == rank) { p.own[i] = 1; ++p.owned; }
  }
  if (uncovered) {
    PetscSFDestroy(&sf);
    lastMessage = "a dof that no rank's partition of unity covers";
    return PETSC_ERR_ARG_WRONG;
  }
  PetscCallMPI(MPI_Scan(&p.owned, &p.first, 1, MPIU_INT, MPI_SUM, comm));
  p.first -= p.owned;
  std::fill(rootData.begin(), rootData.end(), -1);
  for (PetscInt i = 0, k = p.first; i < p.local; ++i) leafData[i] = p.own[i] ? k++ : -1;
  PetscCall(PetscSFReduceBegin(sf, MPIU_INT, leafData.data(), rootData.data(), MPI_MAX));
  PetscCall(PetscSFReduceEnd(sf, MPIU_INT, leafData.data(), rootData.data(), MPI_MAX));
  PetscCall(PetscSFBcastBegin(sf, MPIU_INT, rootData.data(), leafData.data(), MPI_REPLACE));
  PetscCall(PetscSFBcastEnd(sf, MPIU_INT, rootData.data(), leafData.data(), MPI_REPLACE));
  PetscCall(PetscSFDestroy(&sf));
  p.index = leafData;
  PetscCall(VecCreateMPI(comm, p.owned, p.size, &p.spread));
  PetscCall(VecCreateSeq(PETSC_COMM_SELF, p.local, &p.seq));
  IS from, to;
  PetscCall(ISCreateGeneral(PETSC_COMM_SELF, p.local, p.index.data(), PETSC_COPY_VALUES, &from));
  PetscCall(ISCreateStride(PETSC_COMM_SELF, p.local, 0, 1, &to));
  PetscCall(VecScatterCreate(p.spread, from, p.seq, to, &p.toLocal));
  PetscCall(ISDestroy(&from));
  return ISDestroy(&to);
}

long ranksPart(KN<double> *const &natural, KN<double> *const &weight, KN<double> *const &dirichlet) {
  TRYRANKS(start(), "start");
  RanksPart *p = new RanksPart;
  p->local = natural->N();
  if (weight->N() != p->local || dirichlet->N() != p->local) {
    delete p;
    lastMessage = "the natural numbering, the partition of unity and the Dirichlet mask differ in size";
    return failRanks(PETSC_ERR_ARG_SIZ, "decomposition");
  }
  std::vector<PetscInt> nat(p->local);
  p->weight.resize(p->local);
  p->dirichlet.resize(p->local);
  for (PetscInt i = 0; i < p->local; ++i) {
    nat[i] = (PetscInt)std::lround((*natural)[i]);
    p->weight[i] = (*weight)[i];
    p->dirichlet[i] = (*dirichlet)[i] != 0;
  }
  parts.push_back(p);
  TRYRANKS(numberDofs(*p, nat), "decomposition");
  return (long)parts.size() - 1;
}

// A solver context on every rank: the options as on one rank, the fields as strides of the
// owned dofs, the rigid-body modes from the owned displacement dofs' coordinates.
long ranksCreate(long const &part, string *const &options, string *const &names, KN<long> *const &sizes,
                 KN<long> *const &blocks, KN<double> *const &coords) {
  if (part < 0 || part >= (long)parts.size() || !parts[part]) {
    lastMessage = "no decomposition " + std::to_string(part);
    return failRanks(PETSC_ERR_ARG_OUTOFRANGE, "context");
  }
  RanksPart &p = *parts[part];
  MPI_Comm comm = PETSC_COMM_WORLD;
  Context *c = new Context;
  std::istringstream words(*names);
  for (std::string w; words >> w;) c->names.push_back(w);
  contexts.push_back(c);
  long id = (long)contexts.size() - 1;
  partOfContext.resize(contexts.size(), -1);
  partOfContext[id] = part;
  PetscInt total = 0;
  for (long k = 0; k < sizes->N(); ++k) total += (*sizes)[k];
  if (c->names.size() != (size_t)sizes->N() || sizes->N() != blocks->N() || total != p.local) {
    lastMessage = "the fields' names, sizes and blocks do not describe the " + std::to_string(p.local) + " local dofs";
    return failRanks(PETSC_ERR_ARG_SIZ, "context");
  }
  c->prefix = "s" + std::to_string(id) + "_";
  TRYRANKS(PetscOptionsInsertString(nullptr, prefixed(*options, c->prefix).c_str()), "options \"" + *options + "\"");
  {
    // The multigrid's Galerkin products read -matptap_via without a prefix (the product matrices
    // PCMG makes have none): the context's own is handed on, and so counts as read.
    char via[64];
    PetscBool given = PETSC_FALSE;
    TRYRANKS(PetscOptionsGetString(nullptr, c->prefix.c_str(), "-matptap_via", via, sizeof(via), &given), "options");
    if (given) TRYRANKS(PetscOptionsSetValue(nullptr, "-matptap_via", via), "options");
  }
  PetscInt offset = 0, ownedOffset = p.first;
  for (long k = 0; k < sizes->N(); ++k) {
    PetscInt n = (*sizes)[k], bs = (*blocks)[k], mine = 0;
    p.sizes.push_back(n);
    p.blocks.push_back(bs);
    for (PetscInt i = offset; i < offset + n; ++i) mine += p.own[i];
    IS is;
    TRYRANKS(ISCreateStride(comm, mine, ownedOffset, 1, &is), "index set");
    TRYRANKS(ISSetBlockSize(is, bs), "block size of field " + c->names[k]);
    if (bs > 1 && !c->rigid && coords->N() == n) {
      std::string step;
      TRYRANKS(rigidModes(c, is, comm, bs, n, mine, *coords, p.own.data() + offset, &step), step);
    }
    c->fields.push_back(is);
    offset += n;
    ownedOffset += mine;
  }
  c->size = p.size;
  std::string step;
  TRYRANKS(newKrylov(c, comm, *options, &step), step);
  return id;
}

template <class Index, class Offset>
PetscErrorCode addWeightedRow(const RanksPart &p, Mat m, PetscInt i, Offset from, Offset to, const Index *ja,
                              const PetscScalar *a);
PetscErrorCode releaseK(RanksPart &p, Bulk &bulk, const Rows &k, Mat *out);
PetscErrorCode refillOperator(const RanksPart &p, Matrice_Creuse<double> *T, MatriceMorse<double> *t, Mat op);

// The distributed operator from this rank's K and T: K its subdomain's bulk matrix, held by the
// plugin as on one rank (Bulk: 12 bytes an entry, FreeFEM's own matrix about 40) and never
// changed on ranks, T its contact tangent; both are added here (FreeFEM's K + T took 22 of a 3D
// n = 8 run's 32 s on 2 ranks). *out: the last operator, refilled in place (its pattern kept; T
// may still add entries), or null: a new one, preallocated exactly from the owned rows. With K
// held once (p.holdOnce) the first operator takes K over (releaseK) and later ones refill only
// the contact rows (refillOperator).
PetscErrorCode ranksOperator(RanksPart &p, Bulk &bulk, Matrice_Creuse<double> *T, Mat *out) {
  MatriceMorse<double> *t = T->A ? dynamic_cast<MatriceMorse<double> *>(&*T->A) : nullptr;
  if (T->A && (!t || t->half || t->n != p.local || t->m != p.local)) {
    lastMessage = "the contact tangent is not a full sparse matrix of the subdomain's " + std::to_string(p.local) + " dofs";
    return PETSC_ERR_ARG_SIZ;
  }
  if (bulk.n != p.local) {
    lastMessage = "the bulk matrix has " + std::to_string(bulk.n) + " rows where the subdomain has " + std::to_string(p.local) +
                  " dofs";
    return PETSC_ERR_ARG_SIZ;
  }
  if (t) t->CSR();
  if (!bulk.J) return refillOperator(p, T, t, *out);
  PetscCall(restoreK(bulk));
  Rows k;
  PetscCall(openRows(bulk.J, &k));
  auto add = [&](Mat m) -> PetscErrorCode {
    for (PetscInt i = 0; i < p.local; ++i) {
      if (p.dirichlet[i]) {
        if (p.own[i]) PetscCall(MatSetValue(m, p.index[i], p.index[i], 1.0, ADD_VALUES));
        continue;
      }
      if (p.weight[i] == 0) continue;
      PetscCall(addWeightedRow(p, m, i, k.ia[i], k.ia[i + 1], k.ja, k.a));
      if (t) PetscCall(addWeightedRow(p, m, i, t->p[i], t->p[i + 1], t->j, t->aij));
    }
    PetscCall(MatAssemblyBegin(m, MAT_FINAL_ASSEMBLY));
    return MatAssemblyEnd(m, MAT_FINAL_ASSEMBLY);
  };
  if (*out) {
    PetscCall(MatZeroEntries(*out));
  } else {
    // An owned row is whole on its owner (D != 0 there): its columns there are the global row's,
    // each in the diagonal block when this rank owns its dof too. T's are counted as if apart
    // from K's (a few Gamma_3 rows slightly over-allocated).
    std::vector<PetscInt> inside(p.owned, 0), outside(p.owned, 0);
    for (PetscInt i = 0; i < p.local; ++i) {
      if (!p.own[i]) continue;
      PetscInt row = p.index[i] - p.first;
      if (p.dirichlet[i]) { inside[row] = 1; continue; }
      for (PetscInt q = k.ia[i]; q < k.ia[i + 1]; ++q) ++(p.own[k.ja[q]] ? inside[row] : outside[row]);
      if (t) for (auto q = t->p[i]; q < t->p[i + 1]; ++q) ++(p.own[t->j[q]] ? inside[row] : outside[row]);
    }
    PetscCall(MatCreate(PETSC_COMM_WORLD, out));
    PetscCall(MatSetType(*out, MATAIJ));
    PetscCall(MatSetSizes(*out, p.owned, p.owned, p.size, p.size));
    PetscCall(MatSeqAIJSetPreallocation(*out, 0, inside.data()));
    PetscCall(MatMPIAIJSetPreallocation(*out, 0, inside.data(), 0, outside.data()));
    PetscCall(MatSetOption(*out, MAT_NEW_NONZERO_ALLOCATION_ERR, PETSC_FALSE));
  }
  PetscCall(add(*out));
  if (p.holdOnce) return releaseK(p, bulk, k, out);
  return closeRows(&k);
}

// Row i of a CSR matrix of the subdomain (its local columns from..to of ja, values of a) weighted
// by D_i, without the Dirichlet columns, added into m at its global row and columns.
template <class Index, class Offset>
PetscErrorCode addWeightedRow(const RanksPart &p, Mat m, PetscInt i, Offset from, Offset to, const Index *ja,
                              const PetscScalar *a) {
  thread_local std::vector<PetscInt> cols;   // scratch reused row after row (a row is ~80 entries, K has 700k rows at 3D 1/32)
  thread_local std::vector<PetscScalar> vals;
  cols.clear();
  vals.clear();
  for (Offset q = from; q < to; ++q) {
    if (p.dirichlet[ja[q]]) continue;
    cols.push_back(p.index[ja[q]]);
    vals.push_back(p.weight[i] * a[q]);
  }
  return MatSetValues(m, 1, &p.index[i], (PetscInt)cols.size(), cols.data(), vals.data(), ADD_VALUES);
}

// The first operator holds K now: what it does not hold as K is kept aside (RanksPart), the
// subdomain's own K is freed, and K x becomes the distributed matrix's product, corrected there.
PetscErrorCode releaseK(RanksPart &p, Bulk &bulk, const Rows &k, Mat *out) {
  p.keptRows.clear(); p.keptPtr.assign(1, 0); p.keptCols.clear(); p.keptVals.clear();
  p.dRow.clear(); p.dCol.clear(); p.dVals.clear();
  for (PetscInt i = 0; i < p.local; ++i) {
    if (p.weight[i] == 0) continue;
    if (p.dirichlet[i] || p.refill[i]) {
      p.keptRows.push_back(i);
      for (PetscInt q = k.ia[i]; q < k.ia[i + 1]; ++q) { p.keptCols.push_back(k.ja[q]); p.keptVals.push_back(k.a[q]); }
      p.keptPtr.push_back((PetscInt)p.keptCols.size());
      continue;
    }
    for (PetscInt q = k.ia[i]; q < k.ia[i + 1]; ++q)
      if (p.dirichlet[k.ja[q]]) { p.dRow.push_back(i); p.dCol.push_back(k.ja[q]); p.dVals.push_back(k.a[q]); }
  }
  Rows open = k;
  PetscCall(closeRows(&open));
  PetscCall(MatDestroy(&bulk.J));
  // Under FreeFem++-mpi freed memory stays in the process's heap (MPI's memory hooks change
  // malloc's settings: a 257 MB K freed here left VmRSS where it was, 3D h = 1/32 on 2 ranks),
  // and the preconditioner's set-up then raised the peak on top of it; handed back, K's place
  // is taken by the set-up instead (per-rank peak 1,110 -> 940 MiB with the Galerkin products below).
  malloc_trim(0);
  // y = K x on every row with D != 0 (the others are never read: the residual and the checks
  // weigh each row by D): the operator's product brought back to the local dofs, each kept row
  // computed whole, the Dirichlet columns added.
  bulk.releasedMult = [&p, out](const KN<double> &x, KN<double> &y) -> PetscErrorCode {
    if (!*out) {
      lastMessage = "K x after the distributed matrix that held K was destroyed";
      return PETSC_ERR_ARG_WRONGSTATE;
    }
    Vec vx, vy;
    PetscCall(VecDuplicate(p.spread, &vx));
    PetscCall(VecDuplicate(p.spread, &vy));
    PetscScalar *in;
    PetscCall(VecGetArray(vx, &in));
    for (PetscInt i = 0; i < p.local; ++i)
      if (p.own[i]) in[p.index[i] - p.first] = x[i];
    PetscCall(VecRestoreArray(vx, &in));
    PetscCall(MatMult(*out, vx, vy));
    PetscCall(VecScatterBegin(p.toLocal, vy, p.seq, INSERT_VALUES, SCATTER_FORWARD));
    PetscCall(VecScatterEnd(p.toLocal, vy, p.seq, INSERT_VALUES, SCATTER_FORWARD));
    const PetscScalar *back;
    PetscCall(VecGetArrayRead(p.seq, &back));
    for (PetscInt i = 0; i < p.local; ++i) y[i] = back[i];
    PetscCall(VecRestoreArrayRead(p.seq, &back));
    PetscCall(VecDestroy(&vx));
    PetscCall(VecDestroy(&vy));
    for (size_t r = 0; r < p.keptRows.size(); ++r) {
      double sum = 0;
      for (PetscInt q = p.keptPtr[r]; q < p.keptPtr[r + 1]; ++q) sum += p.keptVals[q] * x[p.keptCols[q]];
      y[p.keptRows[r]] = sum;
    }
    for (size_t d = 0; d < p.dRow.size(); ++d) y[p.dRow[d]] += p.dVals[d] * x[p.dCol[d]];
    return 0;
  };
  if (mpiRank() == 0)
    std::cout << "ranks: K held once, in the distributed matrix (kept aside on rank 0: " << p.keptCols.size()
              << " entries of " << p.keptRows.size() << " whole rows, " << p.dRow.size() << " in Dirichlet columns)"
              << std::endl;
  return 0;
}

// K + T again once K is released: the contact rows' values zeroed in place (pattern kept) and
// added again from the kept rows of K and the new T; every other row is K's, as the first operator left it.
PetscErrorCode refillOperator(const RanksPart &p, Matrice_Creuse<double> *T, MatriceMorse<double> *t, Mat op) {
  if (!op) {
    lastMessage = "the contact rows of an operator that does not exist";
    return PETSC_ERR_ARG_WRONGSTATE;
  }
  std::vector<PetscInt> zero;
  for (PetscInt i = 0; i < p.local; ++i)
    if (p.own[i] && p.refill[i]) zero.push_back(p.index[i]);
  PetscCall(MatSetOption(op, MAT_KEEP_NONZERO_PATTERN, PETSC_TRUE));
  PetscCall(MatZeroRows(op, (PetscInt)zero.size(), zero.data(), 0.0, nullptr, nullptr));
  for (size_t r = 0; r < p.keptRows.size(); ++r) {
    PetscInt i = p.keptRows[r];
    if (!p.refill[i]) continue;
    PetscCall(addWeightedRow(p, op, i, p.keptPtr[r], p.keptPtr[r + 1], p.keptCols.data(), p.keptVals.data()));
    if (t) PetscCall(addWeightedRow(p, op, i, t->p[i], t->p[i + 1], t->j, t->aij));
  }
  // A value of T outside the contact rows would have gone nowhere: refused, not solved wrong.
  // (FreeFEM's boundary varfs store zeros in the rows of a contact element's other vertices.)
  if (t)
    for (PetscInt i = 0; i < p.local; ++i) {
      if (p.weight[i] == 0 || p.refill[i] || p.dirichlet[i]) continue;
      for (auto q = t->p[i]; q < t->p[i + 1]; ++q)
        if (t->aij[q] != 0) {
          lastMessage = "the contact tangent has a value outside the contact rows kept aside (an internal error)";
          return PETSC_ERR_PLIB;
        }
    }
  PetscCall(MatAssemblyBegin(op, MAT_FINAL_ASSEMBLY));
  return MatAssemblyEnd(op, MAT_FINAL_ASSEMBLY);
}

// K held once by the decomposition `part` from its first operator on (ranksOperator): mask (the
// Newton vector's size) marks the contact rows, the rows K + T changes at every Newton step.
long ranksHoldOnce(long const &part, KN<double> *const &mask) {
  RanksPart *p = part >= 0 && part < (long)parts.size() ? parts[part] : nullptr;
  if (!p) return failRanks(PETSC_ERR_ARG_OUTOFRANGE, "K held once");
  if (mask->N() != p->local) {
    lastMessage = "the contact rows' mask has " + std::to_string(mask->N()) + " entries where the subdomain has " +
                  std::to_string(p->local) + " dofs";
    return failRanks(PETSC_ERR_ARG_SIZ, "K held once");
  }
  p->refill.assign(p->local, 0);
  for (PetscInt i = 0; i < p->local; ++i) p->refill[i] = (*mask)[i] != 0 && !p->dirichlet[i];
  p->holdOnce = true;
  return 0;
}

// The distributed interpolation of the Newton vector from multigrid level k + 1 onto level k
// (0 the Newton mesh) from the nodal one: on level 0 its rows are this rank's local nodes
// (the script interpolates the whole coarse mesh onto the subdomain) and it sets the rows of
// the dofs it owns, Dirichlet ones zero (attachLevels) but kept in the pattern: a coarse dof
// whose hat reaches only Dirichlet dofs then still has its diagonal in the Galerkin product,
// where PCMG sets one (across ranks MatGalerkin's MatDiagonalSet may not add an entry: "new
// nonzero caused a malloc", 2D n = 16 on 4 ranks); below, every rank has the whole nodal
// interpolation between two coarse meshes and sets the rows of PETSc's even split, the layout
// of the coarse levels (their natural numbering).
// The range [lo, hi) of this rank's rows of a distributed size, as PETSc lays it out (local: its
// own count, or PETSC_DECIDE).
PetscErrorCode layoutRange(PetscInt local, PetscInt size, PetscInt *lo, PetscInt *hi) {
  PetscLayout layout;
  PetscCall(PetscLayoutCreate(PETSC_COMM_WORLD, &layout));
  PetscCall(PetscLayoutSetLocalSize(layout, local));
  PetscCall(PetscLayoutSetSize(layout, size));
  PetscCall(PetscLayoutSetUp(layout));
  PetscCall(PetscLayoutGetRange(layout, lo, hi));
  return PetscLayoutDestroy(&layout);
}

PetscErrorCode ranksInterpolation(const RanksPart &p, Mat nodal, size_t level, Mat *out) {
  PetscInt rows, cols;
  PetscCall(MatGetSize(nodal, &rows, &cols));
  PetscInt fineSize = 0, coarseSize = 0;
  for (PetscInt bs : p.blocks) { fineSize += bs * rows; coarseSize += bs * cols; }
  PetscInt localRows = PETSC_DECIDE;
  if (level == 0) {
    if (fineSize != p.local) {
      lastMessage = "petscAddLevel: an interpolation onto " + std::to_string(rows) + " nodes where the subdomain has " +
                    std::to_string(p.sizes[0] / p.blocks[0]) + " (multigrid needs every field P1 on nested meshes)";
      return PETSC_ERR_ARG_SIZ;
    }
    fineSize = p.size;
    localRows = p.owned;
  }
  // Preallocated exactly, from a first pass over the rows (4 + 4 entries a row, as before, left
  // three quarters of the finest interpolation's memory unused: 38 of 3D h = 1/32's MB a rank).
  PetscInt lo, hi, clo, chi;
  PetscCall(layoutRange(localRows, fineSize, &lo, &hi));
  PetscCall(layoutRange(PETSC_DECIDE, coarseSize, &clo, &chi));
  std::vector<PetscInt> inside(hi - lo, 0), outside(hi - lo, 0);
  auto mine = [&](PetscInt dof) { return level == 0 ? p.own[dof] != 0 : (dof >= lo && dof < hi); };
  auto rowOf = [&](PetscInt dof) { return level == 0 ? p.index[dof] : dof; };
  PetscCall(forEachFieldRow(nodal, p.blocks, [&](PetscInt dof, const std::vector<PetscInt> &cj,
                                                 const std::vector<PetscScalar> &) -> PetscErrorCode {
    if (!mine(dof)) return 0;
    for (PetscInt j : cj) ++(j >= clo && j < chi ? inside : outside)[rowOf(dof) - lo];
    return 0;
  }));
  PetscCall(MatCreate(PETSC_COMM_WORLD, out));
  PetscCall(MatSetType(*out, MATAIJ));
  PetscCall(MatSetSizes(*out, localRows, PETSC_DECIDE, fineSize, coarseSize));
  PetscCall(MatSeqAIJSetPreallocation(*out, 0, inside.data()));
  PetscCall(MatMPIAIJSetPreallocation(*out, 0, inside.data(), 0, outside.data()));
  std::vector<PetscScalar> zeros;
  PetscCall(forEachFieldRow(nodal, p.blocks, [&](PetscInt dof, const std::vector<PetscInt> &cj,
                                                 const std::vector<PetscScalar> &cv) -> PetscErrorCode {
    if (!mine(dof) || cj.empty()) return 0;
    PetscInt row = rowOf(dof);
    const PetscScalar *values = cv.data();
    if (level == 0 && p.dirichlet[dof]) { zeros.assign(cv.size(), 0.0); values = zeros.data(); }
    return MatSetValues(*out, 1, &row, (PetscInt)cj.size(), cj.data(), values, INSERT_VALUES);
  }));
  PetscCall(MatAssemblyBegin(*out, MAT_FINAL_ASSEMBLY));
  return MatAssemblyEnd(*out, MAT_FINAL_ASSEMBLY);
}

// The levels on a PCMG of a distributed context (attachLevels' twin).
PetscErrorCode attachRanksLevels(Context &c, PC pc) {
  PetscBool mg = PETSC_FALSE;
  PetscCall(PetscObjectTypeCompare((PetscObject)pc, PCMG, &mg));
  if (!mg) return 0;
  long id = std::find(contexts.begin(), contexts.end(), &c) - contexts.begin();
  const RanksPart &p = *partOf(id);
  PetscInt levels = (PetscInt)c.nodal.size() + 1;
  PetscCall(PCMGSetLevels(pc, levels, nullptr));
  for (size_t k = 0; k < c.nodal.size(); ++k) {
    Mat interpolation;
    PetscCall(ranksInterpolation(p, c.nodal[k], k, &interpolation));
    PetscCall(PCMGSetInterpolation(pc, levels - 1 - (PetscInt)k, interpolation));
    PetscCall(MatDestroy(&interpolation));
  }
  PetscCall(PCMGSetGalerkin(pc, PC_MG_GALERKIN_BOTH));
  if (mpiRank() == 0) std::cout << "multigrid: " << levels << " levels on " << p.size << " dofs" << std::endl;
  return multigridOptions(c, pc, levels);
}

// x = (K + T)^-1 b over the ranks, to ||b - (K + T) x|| <= rtol ||b||, from x = 0; K and T
// this rank's, b consistent; x comes back consistent. reuse as in solve() (one rank).
long ranksSolve(long const &id, long const &bulk, Matrice_Creuse<double> *const &T, KN<double> *const &b,
                KN<double> *const &x, double const &rtol, long const &reuse) {
  Context *c = context(id);
  RanksPart *p = partOf(id);
  Bulk *k = bulkOf(bulk);
  if (!c || !p || !k || !k->held()) return failRanks(PETSC_ERR_ARG_OUTOFRANGE, "solve");
  if (b->N() != p->local || x->N() != p->local) {
    lastMessage = "vectors of " + std::to_string(b->N()) + " and " + std::to_string(x->N()) + " entries where the subdomain has " +
                  std::to_string(p->local) + " dofs";
    return failRanks(PETSC_ERR_ARG_SIZ, "solve");
  }
  double c0 = cpu(), w0 = now();
  // One distributed matrix, the operator and the preconditioner's, refilled in place: a second
  // would cost a copy of K on every rank. A reused multigrid keeps its Galerkin coarse operators
  // (PCMG's set-up is skipped); the inner solvers built on this matrix itself (the finest
  // smoother's block-Jacobi ILU, a one-level multigrid's LU) see it change and set up again at
  // their next solve (3D n = 8 on 2 ranks: 1 Krylov iteration a step where the stale LU of a
  // second matrix took 10-13).
  if (reuse < 2 || !c->op) {
    PetscErrorCode ierr = ranksOperator(*p, *k, T, &c->op);
    if (ierr) {
      long code = failRanks(ierr, "matrix K + T");
      return ierr == PETSC_ERR_PLIB ? kInternalError : code;
    }
  }
  c->cpuOperator = cpu() - c0;
  c->wallOperator = now() - w0;
  c->peakOperator = peakMb();
  bool rebuild = !reuse || !c->pre;
  std::string step;
  TRYRANKS(useOperator(c, rebuild, rtol, false, attachRanksLevels, &step), step);
  double t0 = now(), s0 = cpu();
  c->lastSetup = 0;
  c->cpuSetup = 0;
  if (rebuild) {
    PC pc;
    TRYRANKS(memoryBreakdown(*c, "before set-up"), "memory breakdown");
    TRYKRYLOV(KSPSetUp(c->ksp), "set-up");
    TRYRANKS(KSPGetPC(c->ksp, &pc), "set-up");
    TRYKRYLOV(PCSetUp(pc), "preconditioner set-up");
    TRYRANKS(memoryBreakdown(*c, "after set-up"), "memory breakdown");
    c->lastSetup = now() - t0;
    c->cpuSetup = cpu() - s0;
    c->totalSetup += c->lastSetup;
    ++c->setups;
  }
  c->peakSetup = peakMb();
  Vec vb, vx;
  TRYRANKS(VecDuplicate(p->spread, &vb), "vector");
  TRYRANKS(VecDuplicate(p->spread, &vx), "vector");
  PetscScalar *in;
  TRYRANKS(VecGetArray(vb, &in), "vector");
  for (PetscInt i = 0; i < p->local; ++i)
    if (p->own[i]) in[p->index[i] - p->first] = p->dirichlet[i] ? 0.0 : (*b)[i];
  TRYRANKS(VecRestoreArray(vb, &in), "vector");
  double t1 = now(), s1 = cpu();
  TRYKRYLOV(KSPSolve(c->ksp, vb, vx), "solve");
  TRYRANKS(memoryBreakdown(*c, "after solve"), "memory breakdown");
  long result;
  TRYRANKS(afterSolve(c, vb, vx, t1, s1, &result), "solve");
  if (result == kUnusedOption) return result;
  TRYRANKS(VecScatterBegin(p->toLocal, vx, p->seq, INSERT_VALUES, SCATTER_FORWARD), "increment");
  TRYRANKS(VecScatterEnd(p->toLocal, vx, p->seq, INSERT_VALUES, SCATTER_FORWARD), "increment");
  const PetscScalar *out;
  TRYRANKS(VecGetArrayRead(p->seq, &out), "increment");
  for (PetscInt i = 0; i < p->local; ++i) (*x)[i] = out[i];
  TRYRANKS(VecRestoreArrayRead(p->seq, &out), "increment");
  TRYRANKS(VecDestroy(&vb), "vector");
  TRYRANKS(VecDestroy(&vx), "vector");
  return result;
}

void destroyParts() {
  for (RanksPart *&p : parts) {
    if (!p) continue;
    VecScatterDestroy(&p->toLocal);
    VecDestroy(&p->spread);
    VecDestroy(&p->seq);
    delete p;
    p = nullptr;
  }
}

// PETSc finalised before FreeFEM ends (and before FreeFem++-mpi's MPI_Finalize).
void finish() {
  for (long id = 0; id < (long)contexts.size(); ++id) destroy(id);
  for (long id = 0; id < (long)bulks.size(); ++id) bulkDestroy(id);
  destroyParts();
  if (started) PetscFinalize();
  started = false;
}

}  // namespace

static void init() {
  Global.Add("petscCreate", "(",
             new OneOperator6_<long, string *, string *, KN<long> *, KN<long> *, KN<double> *, KN<double> *>(create));
  Global.Add("petscSolve", "(",
             new OneOperator6_<long, long, Matrice_Creuse<double> *, KN<double> *, KN<double> *, double, long>(solve));
  Global.Add("petscSolveBulk", "(",
             new OneOperator7_<long, long, long, Matrice_Creuse<double> *, KN<double> *, KN<double> *, double,
                                long>(solveBulk));
  Global.Add("petscBulkCreate", "(", new OneOperator1_<long, long>(bulkCreate));
  Global.Add("petscBulkAdd", "(", new OneOperator4_<long, long, Matrice_Creuse<double> *, long, long>(bulkAdd));
  Global.Add("petscBulkAssemble", "(", new OneOperator1_<long, long>(bulkAssemble));
  Global.Add("petscBulkMult", "(", new OneOperator3_<long, long, KN<double> *, KN<double> *>(bulkMult));
  Global.Add("petscBulkDiagonal", "(", new OneOperator2_<long, long, KN<double> *>(bulkDiagonal));
  Global.Add("petscBulkDirichlet", "(", new OneOperator2_<long, long, KN<double> *>(bulkDirichlet));
  Global.Add("petscBulkWrite", "(", new OneOperator2_<long, long, string *>(bulkWrite));
  Global.Add("petscBulkDestroy", "(", new OneOperator1_<long, long>(bulkDestroy));
  Global.Add("petscBulkKernelBlock", "(", new OneOperator3_<long, long, KN<long> *, KN<double> *>(bulkKernelBlock));
  Global.Add("petscBulkReserve", "(", new OneOperator4_<long, long, Matrice_Creuse<double> *, long, long>(bulkReserve));
  Global.Add("petscBulkKernel", "(", new OneOperator2_<long, long, pmesh>(bulkKernel<Mesh>));
  Global.Add("petscBulkKernel", "(", new OneOperator2_<long, long, pmesh3>(bulkKernel<Mesh3>));
  Global.Add("petscContactResidual", "(",
             new OneOperator5_<long, pmesh, KN<long> *, KN<double> *, KN<double> *, KN<double> *>(contactResidual<Mesh>));
  Global.Add("petscContactResidual", "(",
             new OneOperator5_<long, pmesh3, KN<long> *, KN<double> *, KN<double> *, KN<double> *>(contactResidual<Mesh3>));
  Global.Add("petscContactTangent", "(",
             new OneOperator5_<long, pmesh, KN<long> *, KN<double> *, KN<double> *, Matrice_Creuse<double> *>(
                 contactTangent<Mesh>));
  Global.Add("petscContactCurrent", "(", new OneOperator2_<long, KN<long> *, string *>(contactCurrent));
  Global.Add("petscContactWeights", "(", new OneOperator1_<long, KN<double> *>(contactWeights));
  Global.Add("petscContactIntegrals", "(",
             new OneOperator5_<long, pmesh, KN<long> *, KN<double> *, KN<double> *, KN<double> *>(contactIntegrals<Mesh>));
  Global.Add("petscContactIntegrals", "(",
             new OneOperator5_<long, pmesh3, KN<long> *, KN<double> *, KN<double> *, KN<double> *>(
                 contactIntegrals<Mesh3>));
  Global.Add("petscContactTangent", "(",
             new OneOperator5_<long, pmesh3, KN<long> *, KN<double> *, KN<double> *, Matrice_Creuse<double> *>(
                 contactTangent<Mesh3>));
  Global.Add("petscStats", "(", new OneOperator2_<long, long, KN<double> *>(stats));
  Global.Add("petscAddLevel", "(", new OneOperator2_<long, long, Matrice_Creuse<double> *>(addLevel));
  Global.Add("petscDestroy", "(", new OneOperator1_<long, long>(destroy));
  Global.Add("petscReleasePreconditioner", "(", new OneOperator1_<long, long>(releasePreconditioner));
  Global.Add("petscRanksPart", "(", new OneOperator3_<long, KN<double> *, KN<double> *, KN<double> *>(ranksPart));
  Global.Add("petscRanksCreate", "(",
             new OneOperator6_<long, long, string *, string *, KN<long> *, KN<long> *, KN<double> *>(ranksCreate));
  Global.Add("petscRanksAbort", "(", new OneOperator1_<long, long>(ranksAbort));
  Global.Add("petscRanksHoldOnce", "(", new OneOperator2_<long, long, KN<double> *>(ranksHoldOnce));
  Global.Add("petscRanksSolve", "(",
             new OneOperator7_<long, long, long, Matrice_Creuse<double> *, KN<double> *, KN<double> *, double,
                                long>(ranksSolve));
  ff_atend(finish);
}

LOADFUNC(init)
