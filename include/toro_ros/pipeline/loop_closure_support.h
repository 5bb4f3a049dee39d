// Which loop closures count (OptimizationOptions::hold_until_supported, with robust loop closures
// on): the rules that hold a new loop closure at weight 0 until its support is known, release held
// ones when neighbours, the settled map or a finish's innovation test agree with them, and judge
// accepted ones again when the learnt scale narrows.  Why a loop closure is held at all, and what
// each rule weighs: map_optimizer.h (OptimizationOptions) and the constants in the .cpp.
//
// It decides with LoopClosureEvidence (what the odometry, the map and the neighbours say) and acts
// on the map's weight caps and tree (the TreeOptimizer it is given); what a decision means for the
// schedule (a pass due, a finish due, a finish from scratch) it tells its Owner, the MapOptimizer,
// which keeps the schedule.  Like MapOptimizer it starts no threads and reads no clock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/pipeline/finish_job.h"
#include "toro_ros/pipeline/loop_closure_evidence.h"
#include "toro_ros/pipeline/snapshot.h"

namespace toro_ros {

class LoopClosureSupport {
 public:
  // What the rules read from, and tell, the schedule that owns the map.
  class Owner {
   public:
    // The robust kernel's width now (adapted to the accepted loop closures).
    virtual double kernelWidth() const = 0;
    // Degrees of freedom of a loop closure's error: 3 for planar input, else 6.
    virtual double dof() const = 0;
    // The background finish is on, and can run on this map (finishDetermined may say once why
    // not): a held loop closure far from the map then waits for its innovation test.
    virtual bool backgroundFinishOn() const = 0;
    virtual bool finishDetermined() = 0;
    // Changes when constraint indices change (a removal, a replaced graph): calibration samples of
    // another structure are forgotten.
    virtual std::uint64_t structure() const = 0;
    // A loop closure was held (weight cap 0).  `testable`: enough loop closures count for a finish
    // to test it (the next finish should).
    virtual void loopClosureHeld(bool testable) = 0;
    // A held one was released (weight cap 1, in the tree, marked affected): its pass is due.
    virtual void loopClosureReleased() = 0;
    // An accepted one (constraint c) was held again (rejudgeAccepted) and marked affected: the map
    // it bent is to be settled again without it.
    virtual void acceptedLoopClosureHeld(std::size_t c) = 0;

   protected:
    ~Owner() = default;
  };
  using WarningSink = std::function<void(const std::string&)>;

  // `map`, `evidence`, `is_loop_closure` (per constraint index), `counters` (held / released counts)
  // and `owner` belong to the caller and must outlive this.
  LoopClosureSupport(toro::TreeOptimizer& map, LoopClosureEvidence& evidence,
                     const std::vector<bool>& is_loop_closure, PipelineCounters* counters, Owner& owner,
                     WarningSink warn = nullptr);
  LoopClosureSupport(const LoopClosureSupport&) = delete;
  LoopClosureSupport& operator=(const LoopClosureSupport&) = delete;

  // On (hold_until_supported with robust loop closures) and the support window, in keyframes.
  void configure(bool enabled, std::size_t window);
  bool enabled() const { return enabled_; }
  // Forgets what was accepted and tested (a reset of the map).
  void clear();

  // A new loop closure (constraint c, just added): it agrees with the map, or with the odometry
  // over a short span, or with neighbours (which are released if they were held), or it is held.
  void judgeSupport(std::size_t c);
  // Every loop closure, as after a load: the unsupported ones are held (no counts, no schedule).
  void judgeAllSupport();
  // Held ones the settled map now agrees with are released; true if any.
  bool releaseAgreed();
  // Held ones a finish's innovation test predicts (FinishOutcome::innovations) are released; true if
  // any.  Keeps the outcome's calibration samples first.
  bool releasePredicted(const FinishOutcome& outcome);

  // Fills a finish job's tests from its weights and options: its loop_closure_weight, the held
  // loop closures to test (innovationCandidates) when `test_held` (a loop closure was held since the
  // last finish, or an explicit finish) or when the map's loop closures grew enough since the last
  // tests (innovationRetestDue), and the calibration samples beside them (calibrationSamples).
  void addTests(FinishJob* job, bool test_held);
  // What a finish job is to test.  innovationCandidates: held loop closures (left out of the finish
  // by weights below set_aside_weight) whose innovation it gives, those tested longest ago first,
  // at most kInnovationTestsPerFinish; remembers `loop_closure_weight` for innovationRetestDue.
  // calibrationSamples: accepted ones whose leave-one-out innovation it gives (round robin), none
  // when it tests no held one (`testing_held`) unless the calibration still lacks samples.
  std::vector<std::size_t> innovationCandidates(const std::vector<double>& weights, double set_aside_weight,
                                                double loop_closure_weight);
  std::vector<std::size_t> calibrationSamples(const std::vector<double>& weights, double set_aside_weight,
                                              double loop_closure_weight, bool testing_held);
  // The map's loop closures counted grew enough since the last tests that held ones are worth
  // testing again (what they are measured against has changed).
  bool innovationRetestDue(double loop_closure_weight) const;
  // Sum over loop closures of min(1, weight): the redundancy of a finish over its dof.
  double loopClosureWeight(const std::vector<double>& weights) const;
  // Loop closures held now (weight cap below 1).
  std::size_t held() const;

 private:
  void hold(std::size_t c);                            // weight cap 0 until a release; counted
  void release(std::size_t c, double lenience = 1.0);  // lenience: of its re-judging (rejudgeAccepted)
  void rejudgeAccepted();
  bool agreesWithMap(std::size_t c) const;
  // Held c may count now: agreesWithMap, or within kReleaseWidths of the map and its evidence.
  bool agreesWithSettledMap(std::size_t c);
  double supportThreshold() const;
  // The innovation chi2 a held loop closure must be within to be released by the finish
  // (releasePredicted); -1 while too few loop closures count to read the covariances' scale.
  double innovationThreshold(const FinishOutcome& outcome) const;
  // The kCalibrationQuantile of the accepted loop closures' sampled leave-one-out innovations
  // (accepted_innovation_, those still accepted), once kMinCalibrationSamples are known; else -1.
  // The release test of a held loop closure spanning more than the support window reads it
  // (within kMaxCalibratedWidening of its model threshold).
  double calibratedInnovationThreshold() const;
  // Accepted loop closures with a sampled innovation (accepted_innovation_ not NaN) for the
  // owner's structure.
  std::size_t calibrationSamplesKnown() const;
  // Whether loopClosureWeight(the map's weights) reaches kMinLoopClosuresForScale (stops there:
  // asked at every held arrival).
  bool scaleReadable() const;
  // Ends within the support window: +1 the odometry between them agrees, -1 it contradicts; 0
  // farther apart (or not connected by odometry): the odometry cannot tell.
  // `threshold`: supportThreshold(), taken once by the caller (it sorts the tested pairs' sample,
  // and the partner search asks for every candidate).
  int odometryVerdict(std::size_t c, double threshold);
  // odometryVerdict as an arrival's judge: its +1 only once the sender's scale is learnt and when
  // the test had power (the loop closure's chi2 on the map within kOdometryPowerRatio times the
  // threshold), else 0 (judged like an arrival the odometry cannot reach); -1 as it is.
  int shortSpanVerdict(std::size_t c, double threshold);
  // The evidence between c's two places (LoopClosureEvidence::mapPathChi2, odometryCycleChi2)
  // read at the thresholds: -1 it contradicts c (beyond LoopClosureEvidence::pathThreshold), +1 it
  // agrees, 0 it cannot tell; `record` feeds the thresholds' statistics (a new arrival).  A path
  // through accepted loop closures decides when it is clear (beyond the declared covariances'
  // quantile as well as its scaled threshold, or within a tenth of that); otherwise the odometry
  // over the whole span does.  Partners' support cannot overrule -1: a wrong claim repeated along a
  // revisit (a recogniser confusing two places) agrees with itself, not with the odometry or the
  // loop closures accepted between the two places.
  int mapPathVerdict(std::size_t c, bool record);
  // The loop closures near c that agree with it (`record`: its tests feed the threshold's
  // statistic, for a new arrival only), and whether there are enough of them.
  std::vector<std::size_t> consistentPartners(std::size_t c, bool record);
  // supportedByPartners: corroboratedByPartners (enough neighbours agree and the evidence between
  // its places does not refute it) and not leftToInnovation.  leftToInnovation: c is far from the
  // map and the finish can test it, so the next finish's innovation test decides instead
  // (releasePredicted, with kCorroboratedInnovationLenience when corroborated).
  bool supportedByPartners(std::size_t c);
  // Another loop closure joins c's two places (one end within the support window of each of c's):
  // a pair that teaches the sender's scale can be tested.
  bool hasNeighbours(std::size_t c);
  bool corroboratedByPartners(std::size_t c);
  // For the finish's test of a held loop closure far from the map: two loop closures within a
  // window scaled to c's span agree with it and with each other at `pair_threshold` (the finish's
  // release threshold, scaled by the map's variance factor).  The caller adds the path's verdict.
  bool witnessedAcrossSpan(std::size_t c, double pair_threshold);
  bool leftToInnovation(std::size_t c);

  toro::TreeOptimizer& map_;
  LoopClosureEvidence& evidence_;
  const std::vector<bool>& is_loop_closure_;
  PipelineCounters* counters_;
  Owner& owner_;
  WarningSink warn_;
  bool enabled_ = false;
  std::size_t window_ = 0;
  // Loop closures the odometry supported, or an innovation test released, still at full weight:
  // judged again whenever the learnt threshold has narrowed below kRejudgeNarrowing of
  // rejudged_threshold_ (rejudgeAccepted), held when the odometry refutes them by `lenience` times
  // it (1; kOdometryPathLenience for those whose innovation agreed, as releasePredicted's veto).
  struct AcceptedLoopClosure {
    std::size_t constraint;
    double lenience;
  };
  std::vector<AcceptedLoopClosure> accepted_at_wider_threshold_;
  double rejudged_threshold_ = std::numeric_limits<double>::infinity();
  // Per constraint: the finish sequence that last tested its innovation (0: never).
  std::vector<std::uint64_t> innovation_tested_;
  std::uint64_t innovation_round_ = 0;  // innovation test batches so far
  // Per constraint: the leave-one-out innovation chi2 of an accepted loop closure at the last finish
  // that sampled it (NaN: none), for calibratedInnovationThreshold; valid for calibration_structure_.
  std::vector<double> accepted_innovation_;
  std::uint64_t calibration_structure_ = 0;
  std::size_t calibration_cursor_ = 0;     // the constraint calibrationSamples looks at next (round robin)
  double innovation_tested_weight_ = 0.0;  // loopClosureWeight at the last batch
};

}  // namespace toro_ros
