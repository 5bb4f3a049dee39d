// g2o lines: VERTEX_SE3:QUAT, EDGE_SE3:QUAT, VERTEX_SE2, EDGE_SE2, FIX.
// The 3D information is already in the internal convention (translation first, q-vector units);
// the 2D one is per rad^2 on theta and is lifted (graph_io.h).
#include <algorithm>

#include "graph_io_detail.h"

namespace toro {
namespace detail {

namespace {
constexpr const char* kVertexSe3 = "VERTEX_SE3:QUAT";
constexpr const char* kEdgeSe3 = "EDGE_SE3:QUAT";
constexpr const char* kVertexSe2 = "VERTEX_SE2";
constexpr const char* kEdgeSe2 = "EDGE_SE2";
constexpr const char* kFix = "FIX";

constexpr const char* kPose3Names[7] = {"x", "y", "z", "qx", "qy", "qz", "qw"};
constexpr const char* kInformation3Names[21] = {"I11", "I12", "I13", "I14", "I15", "I16", "I22",
                                                "I23", "I24", "I25", "I26", "I33", "I34", "I35",
                                                "I36", "I44", "I45", "I46", "I55", "I56", "I66"};
// EDGE_SE2 information: xx xy xtheta yy ytheta thetatheta.
constexpr PlanarInformationLayout kInformation2Layout{
    {"I11", "I12", "I13", "I22", "I23", "I33"}, {0, 0, 0, 1, 1, 2}, {0, 1, 2, 1, 2, 2}};

void parseVertexSe3(const LineFields& f, ParsedLines& out) {
  f.expectCount(8);
  out.setDimension(GraphDimension::k3D, f);
  const NodeId id = f.id(1, "id");
  double v[7];
  f.numbers(2, 7, kPose3Names, v);
  out.vertices.push_back(VertexRecord{id, poseFromTranslationQuaternion(f, v, 5), f.line()});
}

void parseEdgeSe3(const LineFields& f, ParsedLines& out) {
  f.expectCount(30);
  out.setDimension(GraphDimension::k3D, f);
  Constraint c;
  c.from = f.id(1, "id1");
  c.to = f.id(2, "id2");
  double v[7];
  f.numbers(3, 7, kPose3Names, v);
  c.measurement = poseFromTranslationQuaternion(f, v, 6);
  double upper[21];
  f.numbers(10, 21, kInformation3Names, upper);
  c.information = symmetricFromUpperTriangle(upper);
  out.edges.push_back(EdgeRecord{c, kEdgeSe3, f.line()});
}

void parseFix(const LineFields& f, ParsedLines& out) {
  // g2o reads every id on the line.
  if (f.size() == 0) f.fail("expected at least 1 field (a node id), got 0");
  for (std::size_t k = 1; k <= f.size(); ++k) out.fixes.push_back(FixRecord{f.id(k, "id"), f.line(), k});
}
}  // namespace

bool isG2oTag(std::string_view tag) {
  return tag == kVertexSe3 || tag == kEdgeSe3 || tag == kVertexSe2 || tag == kEdgeSe2 || tag == kFix;
}

void parseG2oLine(const LineFields& f, ParsedLines& out) {
  const std::string_view tag = f.tag();
  if (tag == kVertexSe3) return parseVertexSe3(f, out);
  if (tag == kEdgeSe3) return parseEdgeSe3(f, out);
  if (tag == kVertexSe2) return parsePlanarVertex(f, out);
  if (tag == kEdgeSe2) return parsePlanarEdge(f, kEdgeSe2, kInformation2Layout, out);
  if (tag == kFix) return parseFix(f, out);
  f.fail("not a g2o tag");
}

namespace {
void writeTranslationQuaternion(LineWriter& w, const Pose3& p) {
  const Vector3& t = p.translation();
  const Quaternion& q = p.rotation();
  w.number(t.x()).number(t.y()).number(t.z()).number(q.x()).number(q.y()).number(q.z()).number(q.w());
}

void writePlanar(LineWriter& w, const Pose3& p) {
  const Vector3 xyt = planarPose(p);
  w.number(xyt.x()).number(xyt.y()).number(xyt.z());
}

void writeFixes(const PoseGraph& graph, LineWriter& w, std::ostream& out) {
  std::vector<NodeId> fixed = graph.fixedNodes();
  std::sort(fixed.begin(), fixed.end());
  fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
  for (const NodeId id : fixed) w.tag(kFix).id(id).endLine(out);
}
}  // namespace

void writeG2o(const PoseGraph& graph, std::ostream& out, int precision) {
  const bool planar = graph.dimension() == GraphDimension::k2D;
  LineWriter w(precision);
  for (const Node& node : graph.nodes()) {
    w.tag(planar ? kVertexSe2 : kVertexSe3).id(node.id);
    planar ? writePlanar(w, node.pose) : writeTranslationQuaternion(w, node.pose);
    w.endLine(out);
  }
  for (const Constraint& c : graph.constraints()) {
    w.tag(planar ? kEdgeSe2 : kEdgeSe3).id(c.from).id(c.to);
    if (planar) {
      writePlanar(w, c.measurement);
      const Matrix3 m = planarInformation(c.information);
      w.number(m(0, 0)).number(m(0, 1)).number(m(0, 2)).number(m(1, 1)).number(m(1, 2)).number(m(2, 2));
    } else {
      writeTranslationQuaternion(w, c.measurement);
      double upper[21];
      upperTriangle(c.information, upper);
      for (const double u : upper) w.number(u);
    }
    w.endLine(out);
  }
  writeFixes(graph, w, out);
}

}  // namespace detail
}  // namespace toro
