// Field parsing, information conventions and number printing shared by the g2o and TORO formats.
#include <charconv>
#include <cmath>
#include <limits>
#include <sstream>

#include "graph_io_detail.h"

namespace toro {
namespace detail {

void LineFields::fail(const std::string& message) const {
  throw ParseError(source_, line_, std::string(tag()) + ": " + message);
}

void LineFields::failField(std::size_t index, const char* name, const std::string& what) const {
  // The field's text (capped: long garbage tokens would drown the message) helps the file's
  // owner; the redacted form names the field only.
  std::ostringstream where;
  where << tag() << " field " << index << " (" << name << "): ";
  throw ParseError(source_, line_, where.str() + excerpt(field(index)) + ' ' + what,
                   where.str() + "the value " + what);
}

void LineFields::expectCount(std::size_t expected) const {
  if (size() != expected) {
    fail("expected " + std::to_string(expected) + " fields, got " + std::to_string(size()));
  }
}

NodeId LineFields::id(std::size_t index, const char* name) const {
  const std::string_view text = field(index);
  NodeId value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec == std::errc::result_out_of_range) failField(index, name, "is out of the id range");
  if (ec != std::errc() || end != text.data() + text.size()) failField(index, name, "is not an integer id");
  return value;
}

double LineFields::number(std::size_t index, const char* name) const {
  std::string_view text = field(index);
  // from_chars refuses a leading '+', which some writers print.
  if (text.size() > 1 && text[0] == '+' && text[1] != '-') text.remove_prefix(1);
  double value = 0.0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec == std::errc::result_out_of_range) failField(index, name, "is out of the double range");
  if (ec != std::errc() || end != text.data() + text.size()) failField(index, name, "is not a number");
  if (!std::isfinite(value)) failField(index, name, "is not finite");
  return value;
}

void LineFields::numbers(std::size_t first, std::size_t count, const char* const* names, double* out) const {
  for (std::size_t k = 0; k < count; ++k) out[k] = number(first + k, names[k]);
}

void ParsedLines::setDimension(GraphDimension d, const LineFields& fields) {
  if (!dimension) {
    dimension = d;
    dimension_line = fields.line();
    return;
  }
  if (*dimension != d) {
    const char* mine = d == GraphDimension::k2D ? "2D" : "3D";
    const char* theirs = d == GraphDimension::k2D ? "3D" : "2D";
    fields.fail(std::string("a ") + mine + " record in a " + theirs + " graph (line " +
                std::to_string(dimension_line) + " is " + theirs + "); a file must not mix 2D and 3D");
  }
}

Matrix6 symmetricFromUpperTriangle(const double* upper) {
  Matrix6 m;
  std::size_t k = 0;
  for (int i = 0; i < 6; ++i) {
    for (int j = i; j < 6; ++j) {
      m(i, j) = upper[k];
      m(j, i) = upper[k];
      ++k;
    }
  }
  return m;
}

void upperTriangle(const Matrix6& m, double* upper) {
  std::size_t k = 0;
  for (int i = 0; i < 6; ++i) {
    for (int j = i; j < 6; ++j) upper[k++] = m(i, j);
  }
}

Matrix6 liftPlanarInformation(const Matrix3& planar) {
  // Indices of x, y, theta (= yaw) in the 6x6 order x y z roll pitch yaw.
  constexpr int kIndex[3] = {0, 1, 5};
  Matrix6 angle_units = Matrix6::Zero();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) angle_units(kIndex[i], kIndex[j]) = planar(i, j);
  }
  // Out of plane: only keeps the graph flat; weights comparable with the in-plane ones.
  angle_units(2, 2) = 0.5 * (planar(0, 0) + planar(1, 1));
  angle_units(3, 3) = planar(2, 2);
  angle_units(4, 4) = planar(2, 2);
  return angleToQuaternionUnits(angle_units);
}

Matrix3 planarInformation(const Matrix6& information) {
  constexpr int kIndex[3] = {0, 1, 5};
  const Matrix6 angle_units = quaternionToAngleUnits(information);
  Matrix3 planar;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) planar(i, j) = angle_units(kIndex[i], kIndex[j]);
  }
  return planar;
}

Pose3 liftPlanarPose(double x, double y, double theta) {
  return Pose3::fromRollPitchYaw(x, y, 0.0, 0.0, 0.0, theta);
}

Vector3 planarPose(const Pose3& pose) {
  return Vector3(pose.translation().x(), pose.translation().y(), pose.rollPitchYaw().z());
}

Pose3 poseFromTranslationQuaternion(const LineFields& fields, const double* v,
                                    std::size_t first_quaternion_field) {
  Quaternion q(v[6], v[3], v[4], v[5]);  // (w, x, y, z) from x y z qx qy qz qw
  double norm2 = q.squaredNorm();
  if (std::isinf(norm2)) {
    // Huge components: scale down first so the norm does not overflow.
    q.coeffs() /= q.coeffs().cwiseAbs().maxCoeff();
    norm2 = q.squaredNorm();
  }
  if (!(norm2 > 1e-20)) {
    fields.fail("fields " + std::to_string(first_quaternion_field) + "-" +
                std::to_string(first_quaternion_field + 3) + " (qx qy qz qw): the quaternion is zero");
  }
  Pose3 pose;
  pose.setTranslation(Vector3(v[0], v[1], v[2]));
  // Renormalising an already unit quaternion could flip last bits and break exact round trips.
  const bool unit = std::abs(norm2 - 1.0) <= 8.0 * std::numeric_limits<double>::epsilon();
  pose.setRotationUnchecked(unit ? q : q.normalized());
  return pose;
}

LineWriter& LineWriter::tag(const char* tag) {
  buffer_ += tag;
  return *this;
}

LineWriter& LineWriter::id(NodeId id) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text), id);
  buffer_ += ' ';
  buffer_.append(text, result.ptr);
  return *this;
}

LineWriter& LineWriter::number(double value) {
  char text[64];
  const auto result = std::to_chars(text, text + sizeof(text), value, std::chars_format::general, precision_);
  buffer_ += ' ';
  buffer_.append(text, result.ptr);
  return *this;
}

void LineWriter::endLine(std::ostream& out) {
  buffer_ += '\n';
  out.write(buffer_.data(), static_cast<std::streamsize>(buffer_.size()));
  buffer_.clear();
}

namespace {
constexpr const char* kPose2Names[3] = {"x", "y", "theta"};
}  // namespace

void parsePlanarVertex(const LineFields& f, ParsedLines& out) {
  f.expectCount(4);
  out.setDimension(GraphDimension::k2D, f);
  const NodeId id = f.id(1, "id");
  double v[3];
  f.numbers(2, 3, kPose2Names, v);
  out.vertices.push_back(VertexRecord{id, liftPlanarPose(v[0], v[1], v[2]), f.line()});
}

void parsePlanarEdge(const LineFields& f, const char* tag, const PlanarInformationLayout& layout, ParsedLines& out) {
  f.expectCount(11);
  out.setDimension(GraphDimension::k2D, f);
  Constraint c;
  c.from = f.id(1, "id1");
  c.to = f.id(2, "id2");
  double v[3];
  f.numbers(3, 3, kPose2Names, v);
  c.measurement = liftPlanarPose(v[0], v[1], v[2]);
  double m[6];
  f.numbers(6, 6, layout.names, m);
  Matrix3 planar;
  for (int k = 0; k < 6; ++k) planar(layout.row[k], layout.col[k]) = planar(layout.col[k], layout.row[k]) = m[k];
  c.information = liftPlanarInformation(planar);
  out.edges.push_back(EdgeRecord{c, tag, f.line()});
}

}  // namespace detail
}  // namespace toro
