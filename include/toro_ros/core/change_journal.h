// What changed in an optimiser since its consumer last asked: the dense indices of the nodes whose
// pose changed and of the constraints whose chi2 or robust weight changed, or "everything".  It
// lets a consumer that mirrors the graph (the pipeline's snapshot) update only what moved, so the
// work per update is proportional to the change, not to the graph.
#pragma once

#include <cstddef>
#include <vector>

namespace toro {

struct OptimizerChanges {
  // Everything may have changed (a full pass, setGraph, an optimiser replaced by a copy): the
  // consumer must read it all.  The lists are then empty.
  bool all = false;
  std::vector<std::size_t> nodes;        // dense node indices, each once, in no order
  std::vector<std::size_t> constraints;  // constraint indices, each once, in no order
};

class ChangeJournal {
 public:
  ChangeJournal() = default;
  // A copy (or a moved-from history) is not the history the consumer has followed: an optimiser
  // restored from a copy (the gate's "before" state) has other poses than the consumer last read,
  // so it reports everything.
  ChangeJournal(const ChangeJournal&) : all_(true) {}
  ChangeJournal(ChangeJournal&&) noexcept : all_(true) {}
  ChangeJournal& operator=(const ChangeJournal&) {
    markAll();
    return *this;
  }
  ChangeJournal& operator=(ChangeJournal&&) noexcept {
    markAll();
    return *this;
  }

  void markAll() {
    clearLists();
    all_ = true;
  }
  // The lists hold each index once (marks); past half the graph they turn into "all", which costs
  // the consumer no more and bounds the journal when nobody takes it (an offline run).
  void node(std::size_t v, std::size_t num_nodes) { add(v, num_nodes, nodes_, node_mark_); }
  void constraint(std::size_t c, std::size_t num_constraints) {
    add(c, num_constraints, constraints_, constraint_mark_);
  }
  bool all() const { return all_; }

  // Hands the changes over and starts a new record.
  OptimizerChanges take() {
    OptimizerChanges out;
    out.all = all_;
    if (!all_) {
      for (std::size_t v : nodes_) node_mark_[v] = 0;
      for (std::size_t c : constraints_) constraint_mark_[c] = 0;
      out.nodes.swap(nodes_);
      out.constraints.swap(constraints_);
    }
    nodes_.clear();
    constraints_.clear();
    all_ = false;
    return out;
  }

 private:
  static constexpr std::size_t kMinListed = 64;  // small graphs: lists, not "all"

  void add(std::size_t i, std::size_t total, std::vector<std::size_t>& list, std::vector<char>& mark) {
    if (all_) return;
    if (mark.size() <= i) mark.resize(i + 1 + i / 2, 0);
    if (mark[i]) return;
    if (list.size() >= kMinListed && 2 * list.size() >= total) {
      markAll();
      return;
    }
    mark[i] = 1;
    list.push_back(i);
  }
  void clearLists() {
    for (std::size_t v : nodes_) node_mark_[v] = 0;
    for (std::size_t c : constraints_) constraint_mark_[c] = 0;
    nodes_.clear();
    constraints_.clear();
  }

  bool all_ = true;  // a new optimiser: nothing was read yet
  std::vector<std::size_t> nodes_, constraints_;
  std::vector<char> node_mark_, constraint_mark_;
};

}  // namespace toro
