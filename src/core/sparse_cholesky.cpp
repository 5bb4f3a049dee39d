#include "sparse_cholesky.h"

#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <limits>
#include <string>

#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <stdexcept>

#ifdef TORO_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

namespace toro {

bool cholmodAvailable() {
#ifdef TORO_HAVE_CHOLMOD
  return true;
#else
  return false;
#endif
}

namespace {

using IntSetter = void (*)(int);

// The runtimes' setters, looked up once.  dlsym instead of linking: the BLAS behind CHOLMOD is
// chosen by the system (Debian's alternatives), and OpenMP is CHOLMOD's own dependency.
struct ThreadSetters {
  IntSetter openblas_threads = nullptr;
  IntSetter omp_threads = nullptr;
  IntSetter omp_dynamic = nullptr;
  IntSetter omp_max_active_levels = nullptr;
};

const ThreadSetters& threadSetters() {
  static const ThreadSetters setters = [] {
    ThreadSetters s;
    s.openblas_threads = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    s.omp_threads = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "omp_set_num_threads"));
    s.omp_dynamic = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "omp_set_dynamic"));
    s.omp_max_active_levels = reinterpret_cast<IntSetter>(dlsym(RTLD_DEFAULT, "omp_set_max_active_levels"));
    return s;
  }();
  return setters;
}

// Process-wide, as the libraries' own counts are; read by every finish, in whatever thread it runs.
std::atomic<int> solver_threads{0};

// OpenMP's thread count and dynamic adjustment belong to the calling thread (its data environment),
// so this runs in the thread that is about to factorise.  Dynamic teams: without them libgomp gives
// CHOLMOD's num_threads(4) clauses four threads whatever the thread count says.  Dynamic teams alone
// do not make one thread one: libgomp bounds a team by the CPUs left after the 15-minute load
// average, so on a quiet 2-core machine CHOLMOD's loops still ran in teams of 2, and every region
// read the load and the affinity mask (sysinfo, sched_getaffinity: 228,000 calls) and woke the
// other thread (4.2 million futex calls over the sphere2500 replay; GOMP_parallel 14 % of its
// profile).  With one thread no region may be active (max-active-levels 0): each runs inline.
bool applyOpenMp(int threads) {
  const ThreadSetters& s = threadSetters();
  if (threads <= 0 || !s.omp_threads || !s.omp_dynamic) return false;
  s.omp_threads(threads);
  s.omp_dynamic(1);
  // INT_MAX: the runtime's own limit (it clamps to the levels it supports).
  if (s.omp_max_active_levels) s.omp_max_active_levels(threads == 1 ? 0 : std::numeric_limits<int>::max());
  return true;
}

}  // namespace

std::string validateSolverThreads(int threads) {
  if (threads < 0 || threads > kMaxSolverThreads)
    return "solver threads must be in [0, " + std::to_string(kMaxSolverThreads) + "] (0: the libraries' own), got " +
           std::to_string(threads);
  return "";
}

SolverThreadSettings setSolverThreads(int threads) {
  const std::string invalid = validateSolverThreads(threads);
  if (!invalid.empty()) throw std::invalid_argument(invalid);
  SolverThreadSettings out;
  if (threads > 0) {
    solver_threads.store(threads);
    if (const IntSetter set = threadSetters().openblas_threads) {
      set(threads);
      out.openblas_set = true;
    }
    out.openmp_set = applyOpenMp(threads);
  }
  out.threads = solver_threads.load();
  return out;
}

int solverThreads() { return solver_threads.load(); }

const char* linearSolverName(LinearSolverType type) {
  switch (type) {
    case LinearSolverType::kCholmodSupernodal:
      return "cholmod-supernodal";
    case LinearSolverType::kCholmodSimplicial:
      return "cholmod-simplicial";
    case LinearSolverType::kSimplicialLDLT:
      return "eigen-ldlt";
  }
  return "unknown";
}

namespace detail {
namespace {

// Any Eigen-style solver with analyzePattern / factorize / info / solve.
template <class Solver>
class EigenStyleCholesky : public SparseCholesky {
 public:
  void analyzePattern(const SparseMatrix& lower) override { solver_.analyzePattern(lower); }
  bool factorize(const SparseMatrix& lower) override {
    solver_.factorize(lower);
    return solver_.info() == Eigen::Success;
  }
  Eigen::VectorXd solve(const Eigen::VectorXd& rhs) override { return solver_.solve(rhs); }
  Eigen::MatrixXd solveColumns(const Eigen::MatrixXd& rhs) override { return solver_.solve(rhs); }

 protected:
  Solver solver_;
};

#ifdef TORO_HAVE_CHOLMOD
// Eigen's CHOLMOD wrappers with their factor reachable (Eigen keeps it protected).
template <class Wrapper>
class WithFactor : public Wrapper {
 public:
  cholmod_factor* factor() const { return this->m_cholmodFactor; }
};

template <class Solver>
class QuietCholmod : public EigenStyleCholesky<WithFactor<Solver>> {
 public:
  // CHOLMOD prints warnings (e.g. "not positive definite") by default; the library must not
  // print, and a failed factorisation is reported through factorize()'s result instead.
  //
  // The thread count of setSolverThreads reaches OpenMP here, in the thread that factorises.
  QuietCholmod() {
    this->solver_.cholmod().print = 0;
    // The finish hands over its matrix in a fill-reducing order of its blocks (FinishProblem::
    // orderBlocks): CHOLMOD keeps it (and only postorders its elimination tree) instead of trying
    // AMD on the scalar pattern, which took most of the analysis (bench/background_finish_results.md).
    this->solver_.cholmod().nmethods = 1;
    this->solver_.cholmod().method[0].ordering = CHOLMOD_NATURAL;
    // Nor postordered: AMD's order of the blocks is one already, and a postorder of CHOLMOD's own
    // makes the factor's order "given", so every factorisation first copied the matrix into it
    // (a transpose with values, 5.6 % of the sphere2500 replay's time).  In the natural order and
    // given its lower triangle, CHOLMOD's supernodal factorisation reads the matrix as it is.
    this->solver_.cholmod().postorder = 0;
    // Supernode amalgamation twice CHOLMOD's defaults (merged whatever the zeros up to 4 columns -> 8,
    // with < 80 % zeros up to 16 -> 32, with < 10 % up to 48 -> 96): its defaults are set for scalar
    // matrices, ours come in 6x6
    // (3x3) blocks, so a default supernode is one or two poses, too small for the dense kernels to
    // pay.  Measured (bench/background_finish_results.md, session 31): sphere2500 replay 13.40 ->
    // 12.71 s (median of 4 interleaved), finishes of manhattan 0.050 -> 0.039 s and parking-garage
    // 0.045 -> 0.035 s, sphere2500 / kitti_00 / city10000 unchanged; 4x was slower than 2x.
    cholmod_common& common = this->solver_.cholmod();
    for (std::size_t& n : common.nrelax) n *= 2;
    const int threads = solverThreads();
    applyOpenMp(threads);
#if CHOLMOD_MAIN_VERSION >= 5
    // CHOLMOD 5 sizes its OpenMP loops itself (Common.nthreads_max; 0: its own default).
    if (threads > 0) this->solver_.cholmod().nthreads_max = threads;
#endif
  }

  bool forwardSolveColumns(const Eigen::MatrixXd& rhs, Eigen::MatrixXd* y) override {
    cholmod_factor* l = this->solver_.factor();
    if (!l || !l->is_ll || this->solver_.info() != Eigen::Success) return false;
    cholmod_common& common = this->solver_.cholmod();
    // A view, as Eigen's own solve makes one: CHOLMOD only reads it.
    Eigen::Ref<const Eigen::MatrixXd> rhs_ref(rhs);
    cholmod_dense b = Eigen::viewAsCholmod(rhs_ref);
    cholmod_dense* permuted = cholmod_solve(CHOLMOD_P, l, &b, &common);
    if (!permuted) return false;
    cholmod_dense* forward = cholmod_solve(CHOLMOD_L, l, permuted, &common);
    cholmod_free_dense(&permuted, &common);
    if (!forward) return false;
    *y = Eigen::Map<const Eigen::MatrixXd>(static_cast<const double*>(forward->x), rhs.rows(), rhs.cols());
    cholmod_free_dense(&forward, &common);
    return true;
  }

  void analyzePattern(const SparseMatrix& lower) override {
    EigenStyleCholesky<WithFactor<Solver>>::analyzePattern(lower);
    tree_.reset();  // the factor's structure may have changed
  }

  bool forwardGram(const SparseMatrix& rhs, Eigen::MatrixXd* gram) override {
    const cholmod_factor* l = this->solver_.factor();
    if (!l || !l->is_ll || !l->is_super || l->xtype != CHOLMOD_REAL || l->itype != CHOLMOD_INT ||
        this->solver_.info() != Eigen::Success || rhs.rows() != static_cast<Eigen::Index>(l->n))
      return false;
    if (!tree_) tree_ = std::make_unique<SupernodeTree>(*l);
    SupernodeTree& tree = *tree_;
    const auto* super = static_cast<const int*>(l->super);
    const auto* pi = static_cast<const int*>(l->pi);
    const auto* px = static_cast<const int*>(l->px);
    const auto* rows = static_cast<const int*>(l->s);
    const auto* values = static_cast<const double*>(l->x);
    const Eigen::Index cols = rhs.cols();
    if (work_.rows() != rhs.rows() || work_.cols() != cols) work_ = Eigen::MatrixXd::Zero(rhs.rows(), cols);
    // P rhs scattered into the (zero) workspace, and the supernodes holding its rows.
    starts_.clear();
    for (Eigen::Index c = 0; c < cols; ++c)
      for (SparseMatrix::InnerIterator it(rhs, c); it; ++it) {
        const int k = tree.position[static_cast<std::size_t>(it.row())];
        work_(k, c) = it.value();
        starts_.push_back(tree.supernode[static_cast<std::size_t>(k)]);
      }
    // Their paths to the root (a supernode's parent holds its first row below the diagonal block,
    // and every row it updates lies on that path), in elimination order (parents come later).
    reach_.clear();
    for (const int start : starts_)
      for (int s = start; s >= 0 && !tree.marked[static_cast<std::size_t>(s)];
           s = tree.parent[static_cast<std::size_t>(s)]) {
        tree.marked[static_cast<std::size_t>(s)] = 1;
        reach_.push_back(s);
      }
    for (const int s : reach_) tree.marked[static_cast<std::size_t>(s)] = 0;
    std::sort(reach_.begin(), reach_.end());
    gram->setZero(cols, cols);
    for (const int s : reach_) {
      const int k1 = super[s], ncol = super[s + 1] - k1, first = pi[s], nrow = pi[s + 1] - first;
      const Eigen::Map<const Eigen::MatrixXd> ls(values + px[s], nrow, ncol);
      auto y = work_.middleRows(k1, ncol);
      ls.topRows(ncol).triangularView<Eigen::Lower>().solveInPlace(y);
      if (nrow > ncol) {
        update_.noalias() = ls.bottomRows(nrow - ncol) * y;
        for (int i = 0; i < nrow - ncol; ++i) work_.row(rows[first + ncol + i]) -= update_.row(i);
      }
      gram->noalias() += y.transpose() * y;
    }
    for (const int s : reach_) work_.middleRows(super[s], super[s + 1] - super[s]).setZero();
    return true;
  }

 private:
  // The factor's supernodal elimination tree and permutation, read once per analysis.
  struct SupernodeTree {
    std::vector<int> supernode;  // of each column of L
    std::vector<int> parent;     // of each supernode, -1 at a root
    std::vector<int> position;   // of each row of the matrix in P rhs
    std::vector<char> marked;    // per supernode: on the reach being collected (kept all 0)
    explicit SupernodeTree(const cholmod_factor& l) {
      const auto n = static_cast<std::size_t>(l.n), nsuper = static_cast<std::size_t>(l.nsuper);
      const auto* super = static_cast<const int*>(l.super);
      const auto* pi = static_cast<const int*>(l.pi);
      const auto* rows = static_cast<const int*>(l.s);
      const auto* perm = static_cast<const int*>(l.Perm);
      supernode.assign(n, 0);
      for (std::size_t s = 0; s < nsuper; ++s)
        for (int k = super[s]; k < super[s + 1]; ++k)
          supernode[static_cast<std::size_t>(k)] = static_cast<int>(s);
      parent.assign(nsuper, -1);
      for (std::size_t s = 0; s < nsuper; ++s) {
        const int ncol = super[s + 1] - super[s];
        int below = -1;  // the smallest row below the diagonal block
        for (int p = pi[s] + ncol; p < pi[s + 1]; ++p)
          if (below < 0 || rows[p] < below) below = rows[p];
        if (below >= 0) parent[s] = supernode[static_cast<std::size_t>(below)];
      }
      marked.assign(nsuper, 0);
      position.resize(n);
      for (std::size_t k = 0; k < n; ++k)  // (P b)[k] = b[Perm[k]]
        position[perm ? static_cast<std::size_t>(perm[k]) : k] = static_cast<int>(k);
    }
  };
  std::unique_ptr<SupernodeTree> tree_;
  Eigen::MatrixXd work_, update_;  // work_ kept zero between calls
  std::vector<int> starts_, reach_;
};
#endif

}  // namespace

std::vector<int> fillReducingPositions(const SparseMatrix& pattern) {
  const int n = static_cast<int>(pattern.rows());
  std::vector<int> eliminated(static_cast<std::size_t>(n));  // eliminated[k]: the k-th to go
#ifdef TORO_HAVE_CHOLMOD
  SparseMatrix a = pattern;
  a.makeCompressed();
  cholmod_common common;
  cholmod_start(&common);
  common.print = 0;
  cholmod_sparse view = Eigen::viewAsCholmod(a);
  view.stype = 1;  // symmetric: its upper triangle is read (unsymmetric, AMD would order A A^T)
  const bool ok = cholmod_amd(&view, nullptr, 0, eliminated.data(), &common) != 0;
  cholmod_finish(&common);
  if (!ok) throw std::runtime_error("sparse finish: AMD ordering failed");
#else
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> order;
  Eigen::AMDOrdering<int>()(pattern, order);  // the inverse permutation: indices()[k] goes k-th
  for (int k = 0; k < n; ++k) eliminated[static_cast<std::size_t>(k)] = order.indices()[k];
#endif
  std::vector<int> position(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) position[static_cast<std::size_t>(eliminated[static_cast<std::size_t>(k)])] = k;
  return position;
}

std::unique_ptr<SparseCholesky> makeSparseCholesky(LinearSolverType type) {
  switch (type) {
    case LinearSolverType::kSimplicialLDLT:
      return std::make_unique<EigenStyleCholesky<
          Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower, Eigen::NaturalOrdering<int>>>>();
#ifdef TORO_HAVE_CHOLMOD
    case LinearSolverType::kCholmodSupernodal:
      return std::make_unique<QuietCholmod<Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower>>>();
    case LinearSolverType::kCholmodSimplicial:
      return std::make_unique<QuietCholmod<Eigen::CholmodSimplicialLDLT<SparseMatrix, Eigen::Lower>>>();
#else
    case LinearSolverType::kCholmodSupernodal:
    case LinearSolverType::kCholmodSimplicial:
      break;
#endif
  }
  throw std::invalid_argument(std::string("linear solver ") + linearSolverName(type) +
                              " is not built in (CHOLMOD was not found at configure time)");
}

}  // namespace detail
}  // namespace toro
