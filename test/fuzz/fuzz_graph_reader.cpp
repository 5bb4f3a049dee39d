// Fuzz target for the graph readers (g2o and TORO, 2D and 3D).  The first byte chooses the format
// and the EDGE3 information order, the rest is the file text.  Properties checked:
// - reading never crashes and fails only with ParseError (file:line: reason), whose messages are
//   printable ASCII (quoted content is sanitised) and whose redacted form quotes nothing (the
//   node's services hand it to any ROS client);
// - whatever is read writes out and reads back to the same counts and poses (round trip).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <sstream>
#include <string>

#include "toro_ros/core/graph_io.h"

namespace {

[[noreturn]] void fail(const char* what) {
  // A property violation must stop the fuzzer like a crash does.
  std::fputs(what, stderr);
  std::fputc('\n', stderr);
  std::abort();
}

bool samePoses(const toro::PoseGraph& a, const toro::PoseGraph& b) {
  if (a.numNodes() != b.numNodes() || a.numConstraints() != b.numConstraints()) return false;
  for (std::size_t i = 0; i < a.numNodes(); ++i) {
    const toro::Pose3& p = a.node(i).pose;
    const toro::Pose3& q = b.pose(a.node(i).id);
    const double scale = 1.0 + p.translation().norm();
    if ((p.translation() - q.translation()).norm() > 1e-9 * scale) return false;
    if (p.rotation().angularDistance(q.rotation()) > 1e-9) return false;
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  toro::ReadOptions options;
  const std::uint8_t selector = data[0];
  options.format = selector % 3 == 0 ? toro::GraphFormat::kAuto
                   : selector % 3 == 1 ? toro::GraphFormat::kG2o
                                       : toro::GraphFormat::kToro;
  options.toro_information_order = (selector & 4) ? toro::ToroInformationOrder::kRotationFirst
                                                  : toro::ToroInformationOrder::kTranslationFirst;
  options.repair_information = (selector & 8) == 0;
  std::istringstream in(std::string(reinterpret_cast<const char*>(data) + 1, size - 1));
  toro::PoseGraph graph;
  try {
    graph = toro::readGraph(in, "fuzz", options);
  } catch (const toro::ParseError& e) {
    const auto printable = [](const std::string& m) {
      for (const char c : m)
        if (c < 0x20 || c > 0x7e) return false;
      return true;
    };
    if (!printable(e.what()) || !printable(e.redactedWhat())) fail("a ParseError message is not printable ASCII");
    if (e.redactedWhat().find('\'') != std::string::npos) fail("a redacted ParseError message quotes the file");
    return 0;  // refused with a located message: the expected outcome for garbage
  }
  // Round trip through the writer of the same family.
  for (toro::GraphFormat format : {toro::GraphFormat::kG2o, toro::GraphFormat::kToro}) {
    toro::WriteOptions write_options;
    write_options.format = format;
    write_options.toro_information_order = options.toro_information_order;
    std::ostringstream out;
    toro::writeGraph(graph, out, write_options);
    std::istringstream back_in(out.str());
    toro::ReadOptions back_options = options;
    back_options.format = format;
    toro::PoseGraph back;
    try {
      back = toro::readGraph(back_in, "round-trip", back_options);
    } catch (const toro::ParseError& e) {
      fail(e.what());
    }
    if (!samePoses(graph, back)) fail("round trip changed the graph");
  }
  return 0;
}
