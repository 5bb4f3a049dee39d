// How well the rest of the graph predicts a loop closure: its leave-one-out innovation chi2
//   e^T (Sigma_z + Sigma_path)^-1 e,
// e its residual at the current poses, Sigma_z its own covariance and Sigma_path the covariance of
// the relative pose of its two ends along the tree path, each tree edge's covariance being the
// inverse of the robust-weighted information of the constraints between the node and its tree
// parent (this one left out), all carried into the frame of the loop closure's `to` end (first
// order).  Why: the plain chi2 e^T Omega_z e of a right loop closure that closes a long loop is the
// whole drift; against the uncertainty of the path that drift is plausible.  Where other loop
// closures already hold the two ends together the path is stiff and the test is as strict as the
// plain chi2.  A single path is one of several the graph has, so Sigma_path over-estimates the
// real uncertainty: lenient, never stricter than the truth.
#pragma once

#include <cstddef>
#include <vector>

#include "toro_ros/core/pose3.h"

namespace toro {

class TreeOptimizer;

// Scratch buffers for loopClosureInnovationChi2 (no allocation per call once grown), and a cache
// of tree-edge covariances for a batch of calls (TreeOptimizer::refreshWeights): loop closures'
// paths share most of their tree edges, and each edge's covariance costs two to four 6x6
// inversions (sphere2500 replayed: 70 % of the time of a weight refresh went to them).
struct InnovationScratch {
  std::vector<std::size_t> up, down;
  // While `caching`, edge_covariance[v] (valid[v] != 0) is the covariance of node v relative to
  // its tree parent from all constraints between them.  Only for a batch in which poses and the
  // tree stay as they are; a weight that changes within it must forget(its ends).
  bool caching = false;
  std::vector<Matrix6> edge_covariance;
  std::vector<char> valid;
  // Starts a batch (every entry invalid) or ends it.
  void beginBatch(std::size_t nodes);
  void endBatch() { caching = false; }
  void forget(std::size_t v) {
    if (v < valid.size()) valid[v] = 0;
  }
};

// The leave-one-out innovation chi2 of constraint `c` of `optimizer` (units of the g2o chi2).
// Nodes whose tree edge carries no weighted information (only down-weighted loop closures) make
// the path unconstrained there: the result is then -1 (nothing can be judged; the kernel gives
// full weight, and the value is no sample of the right loop closures' innovations).
double loopClosureInnovationChi2(const TreeOptimizer& optimizer, std::size_t c, InnovationScratch& scratch);

}  // namespace toro
