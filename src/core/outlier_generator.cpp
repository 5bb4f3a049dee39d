#include "toro_ros/core/outlier_generator.h"

#include <algorithm>
#include <random>
#include <stdexcept>

namespace toro {

std::optional<OutlierKind> outlierKindFromString(const std::string& name) {
  for (OutlierKind k : {OutlierKind::kRandom, OutlierKind::kLocal, OutlierKind::kGrouped})
    if (name == outlierKindName(k)) return k;
  return std::nullopt;
}

const char* outlierKindName(OutlierKind kind) {
  switch (kind) {
    case OutlierKind::kRandom:
      return "random";
    case OutlierKind::kLocal:
      return "local";
    case OutlierKind::kGrouped:
      return "grouped";
  }
  return "unknown";
}

namespace {

class Generator {
 public:
  Generator(const PoseGraph& graph, const OutlierOptions& options, const PoseGraph& reference)
      : graph_(graph), options_(options), reference_(reference), random_(options.seed) {
    for (const Node& n : graph.nodes()) ids_.push_back(n.id);
    std::sort(ids_.begin(), ids_.end());
    for (std::size_t c = 0; c < graph.numConstraints(); ++c)
      if (isLoopClosure(graph.constraints()[c])) donors_.push_back(c);
    if (donors_.empty())
      for (std::size_t c = 0; c < graph.numConstraints(); ++c) donors_.push_back(c);
  }

  // A loop closure from -> to that borrows a random constraint's measurement and information.
  Constraint borrowed(NodeId from, NodeId to) {
    const Constraint& donor = graph_.constraints()[donors_[pick(donors_.size())]];
    Constraint c;
    c.from = from;
    c.to = to;
    c.measurement = donor.measurement;
    c.information = donor.information;
    c.kind = ConstraintKind::kLoopClosure;
    return c;
  }

  std::size_t pick(std::size_t n) { return std::uniform_int_distribution<std::size_t>(0, n - 1)(random_); }

  // Two positions in ids_, at least `gap` apart, the first smaller.
  std::pair<std::size_t, std::size_t> randomPair(std::size_t gap, std::size_t tail) {
    const std::size_t n = ids_.size() - tail;
    for (;;) {
      std::size_t a = pick(n), b = pick(n);
      if (a > b) std::swap(a, b);
      if (b - a >= gap) return {a, b};
    }
  }

  void add(std::vector<Constraint>* out) {
    switch (options_.kind) {
      case OutlierKind::kRandom: {
        const auto [a, b] = randomPair(2, 0);
        out->push_back(borrowed(ids_[a], ids_[b]));
        break;
      }
      case OutlierKind::kLocal: {
        const int span = std::max(2, options_.local_max_offset);
        const std::size_t offset = 2 + pick(static_cast<std::size_t>(span - 1));
        const std::size_t a = pick(ids_.size() - std::min(offset, ids_.size() - 1));
        out->push_back(borrowed(ids_[a], ids_[a + offset]));
        break;
      }
      case OutlierKind::kGrouped: {
        const std::size_t g = options_.group_size;
        const auto [a, b] = randomPair(g + 2, g);
        const Constraint wrong = borrowed(ids_[a], ids_[b]);
        const Pose3& xa = reference_.pose(ids_[a]);
        const Pose3& xb = reference_.pose(ids_[b]);
        for (std::size_t k = 0; k < g; ++k) {
          // (a + k)_T_(b + k) = (a_T_(a+k))^-1 * wrong * b_T_(b+k) along the reference.
          Constraint c = wrong;
          c.from = ids_[a + k];
          c.to = ids_[b + k];
          c.measurement = relativePose(xa, reference_.pose(c.from)).inverse() * wrong.measurement *
                          relativePose(xb, reference_.pose(c.to));
          out->push_back(c);
        }
        break;
      }
    }
  }

 private:
  const PoseGraph& graph_;
  const OutlierOptions& options_;
  const PoseGraph& reference_;
  std::mt19937 random_;
  std::vector<NodeId> ids_;
  std::vector<std::size_t> donors_;
};

}  // namespace

GraphWithOutliers addOutliers(const PoseGraph& graph, const OutlierOptions& options, const PoseGraph* reference) {
  if (graph.numConstraints() == 0) throw std::invalid_argument("addOutliers: the graph has no constraints");
  if (graph.numNodes() < 2 * options.group_size + 4)
    throw std::invalid_argument("addOutliers: the graph has too few nodes (" + std::to_string(graph.numNodes()) + ")");
  GraphWithOutliers out{graph, {}};
  Generator generator(graph, options, reference ? *reference : graph);
  std::vector<Constraint> wrong;
  while (wrong.size() < options.count) generator.add(&wrong);
  for (const Constraint& c : wrong) out.outliers.push_back(out.graph.addConstraint(c));
  return out;
}

}  // namespace toro
