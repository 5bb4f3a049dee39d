// TORO lines: VERTEX3/EDGE3 (x y z roll pitch yaw, R = Rz Ry Rx) and VERTEX2/EDGE2 (also tagged
// VERTEX/EDGE).  TORO's information is per rad^2 on the angles; the order of the 3D matrix is
// chosen by ToroInformationOrder (graph_io.h).
#include "graph_io_detail.h"

namespace toro {
namespace detail {

namespace {
constexpr const char* kVertex3 = "VERTEX3";
constexpr const char* kEdge3 = "EDGE3";
constexpr const char* kVertex2 = "VERTEX2";
constexpr const char* kEdge2 = "EDGE2";
constexpr const char* kVertex2Short = "VERTEX";
constexpr const char* kEdge2Short = "EDGE";

constexpr const char* kPose3Names[6] = {"x", "y", "z", "roll", "pitch", "yaw"};
constexpr const char* kInformation3Names[21] = {"m00", "m01", "m02", "m03", "m04", "m05", "m11",
                                                "m12", "m13", "m14", "m15", "m22", "m23", "m24",
                                                "m25", "m33", "m34", "m35", "m44", "m45", "m55"};
// TORO 2D order: xx xy yy θθ xθ yθ.
// EDGE2 information: xx xy yy thetatheta xtheta ytheta (TORO's posegraph2 order).
constexpr PlanarInformationLayout kInformation2Layout{
    {"m00", "m01", "m11", "m22", "m02", "m12"}, {0, 0, 1, 2, 0, 1}, {0, 1, 1, 2, 2, 2}};

// Position of x y z roll pitch yaw in TORO's internal rotation-first order (roll pitch yaw x y z).
constexpr int kRotationFirstIndex[6] = {3, 4, 5, 0, 1, 2};

// The file's matrix (angle units, given order) in the internal convention.
Matrix6 informationFromToro(const Matrix6& file, ToroInformationOrder order) {
  if (order == ToroInformationOrder::kTranslationFirst) return angleToQuaternionUnits(file);
  Matrix6 translation_first;
  for (int i = 0; i < 6; ++i) {
    for (int j = 0; j < 6; ++j)
      translation_first(i, j) = file(kRotationFirstIndex[i], kRotationFirstIndex[j]);
  }
  return angleToQuaternionUnits(translation_first);
}

Matrix6 informationToToro(const Matrix6& information, ToroInformationOrder order) {
  const Matrix6 translation_first = quaternionToAngleUnits(information);
  if (order == ToroInformationOrder::kTranslationFirst) return translation_first;
  Matrix6 file;
  for (int i = 0; i < 6; ++i) {
    for (int j = 0; j < 6; ++j)
      file(kRotationFirstIndex[i], kRotationFirstIndex[j]) = translation_first(i, j);
  }
  return file;
}

Pose3 poseFromEuler(const double* v) { return Pose3::fromRollPitchYaw(v[0], v[1], v[2], v[3], v[4], v[5]); }

void parseVertex3(const LineFields& f, ParsedLines& out) {
  f.expectCount(7);
  out.setDimension(GraphDimension::k3D, f);
  const NodeId id = f.id(1, "id");
  double v[6];
  f.numbers(2, 6, kPose3Names, v);
  out.vertices.push_back(VertexRecord{id, poseFromEuler(v), f.line()});
}

void parseEdge3(const LineFields& f, ToroInformationOrder order, ParsedLines& out) {
  // GTSAM's examples write EDGE3 without the matrix (they bring their own noise model).
  if (f.size() != 8 && f.size() != 29) {
    f.fail("expected 29 fields (or 8 without an information matrix), got " + std::to_string(f.size()));
  }
  out.setDimension(GraphDimension::k3D, f);
  Constraint c;
  c.from = f.id(1, "id1");
  c.to = f.id(2, "id2");
  double v[6];
  f.numbers(3, 6, kPose3Names, v);
  c.measurement = poseFromEuler(v);
  if (f.size() == 29) {
    double upper[21];
    f.numbers(9, 21, kInformation3Names, upper);
    c.information = informationFromToro(symmetricFromUpperTriangle(upper), order);
  } else {
    c.information = Matrix6::Identity();
    ++out.edges_without_information;
  }
  out.edges.push_back(EdgeRecord{c, kEdge3, f.line()});
}

}  // namespace

bool isToroTag(std::string_view tag) {
  return tag == kVertex3 || tag == kEdge3 || tag == kVertex2 || tag == kEdge2 || tag == kVertex2Short ||
         tag == kEdge2Short;
}

void parseToroLine(const LineFields& f, ToroInformationOrder order, ParsedLines& out) {
  const std::string_view tag = f.tag();
  if (tag == kVertex3) return parseVertex3(f, out);
  if (tag == kEdge3) return parseEdge3(f, order, out);
  if (tag == kVertex2 || tag == kVertex2Short) return parsePlanarVertex(f, out);
  if (tag == kEdge2) return parsePlanarEdge(f, kEdge2, kInformation2Layout, out);
  if (tag == kEdge2Short) return parsePlanarEdge(f, kEdge2Short, kInformation2Layout, out);
  f.fail("not a TORO tag");
}

namespace {
void writeEuler(LineWriter& w, const Pose3& p) {
  const Vector3& t = p.translation();
  const Vector3 rpy = p.rollPitchYaw();
  w.number(t.x()).number(t.y()).number(t.z()).number(rpy.x()).number(rpy.y()).number(rpy.z());
}

void writeToro2d(const PoseGraph& graph, LineWriter& w, std::ostream& out) {
  for (const Node& node : graph.nodes()) {
    const Vector3 p = planarPose(node.pose);
    w.tag(kVertex2).id(node.id).number(p.x()).number(p.y()).number(p.z()).endLine(out);
  }
  for (const Constraint& c : graph.constraints()) {
    const Vector3 p = planarPose(c.measurement);
    const Matrix3 m = planarInformation(c.information);
    w.tag(kEdge2).id(c.from).id(c.to).number(p.x()).number(p.y()).number(p.z());
    w.number(m(0, 0)).number(m(0, 1)).number(m(1, 1)).number(m(2, 2)).number(m(0, 2)).number(m(1, 2));
    w.endLine(out);
  }
}
}  // namespace

void writeToro(const PoseGraph& graph, std::ostream& out, ToroInformationOrder order, int precision) {
  LineWriter w(precision);
  if (graph.dimension() == GraphDimension::k2D) return writeToro2d(graph, w, out);
  for (const Node& node : graph.nodes()) {
    w.tag(kVertex3).id(node.id);
    writeEuler(w, node.pose);
    w.endLine(out);
  }
  for (const Constraint& c : graph.constraints()) {
    w.tag(kEdge3).id(c.from).id(c.to);
    writeEuler(w, c.measurement);
    double upper[21];
    upperTriangle(informationToToro(c.information, order), upper);
    for (const double u : upper) w.number(u);
    w.endLine(out);
  }
}

}  // namespace detail
}  // namespace toro
