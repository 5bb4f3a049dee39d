// Internals shared by the graph file readers and writers (graph_io.cpp, g2o_io.cpp, toro_io.cpp).
// Not installed; the public API is include/toro_ros/core/graph_io.h.
#pragma once

#include <cstddef>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

#include "toro_ros/core/graph_io.h"

namespace toro {
namespace detail {

// One data line split at whitespace: the tag and its fields (numbered from 1 in messages, as
// "EDGE_SE3:QUAT field 9 (qw)").  Every accessor throws ParseError naming file, line, tag and field.
class LineFields {
 public:
  LineFields(const std::string& source, std::size_t line, const std::vector<std::string_view>& tokens)
      : source_(source), line_(line), tokens_(tokens) {}

  std::string_view tag() const { return tokens_[0]; }
  std::size_t size() const { return tokens_.size() - 1; }
  std::size_t line() const { return line_; }

  // Throws unless the line has exactly `expected` fields after the tag.
  void expectCount(std::size_t expected) const;
  NodeId id(std::size_t field, const char* name) const;
  // A finite number.
  double number(std::size_t field, const char* name) const;
  // `count` consecutive numbers from `first`, named by `names`.
  void numbers(std::size_t first, std::size_t count, const char* const* names, double* out) const;

  [[noreturn]] void fail(const std::string& message) const;  // "TAG: message"

 private:
  std::string_view field(std::size_t field) const { return tokens_[field]; }
  [[noreturn]] void failField(std::size_t field, const char* name, const std::string& what) const;

  const std::string& source_;
  std::size_t line_;
  const std::vector<std::string_view>& tokens_;
};

struct VertexRecord {
  NodeId id;
  Pose3 pose;
  std::size_t line;
};

struct EdgeRecord {
  Constraint constraint;
  const char* tag;  // a string literal
  std::size_t line;
};

struct FixRecord {
  NodeId id;
  std::size_t line;
  std::size_t field;
};

// What the line parsers collect; graph_io.cpp turns it into a PoseGraph.
struct ParsedLines {
  std::vector<VertexRecord> vertices;
  std::vector<EdgeRecord> edges;
  std::vector<FixRecord> fixes;
  std::size_t edges_without_information = 0;
  std::optional<GraphDimension> dimension;
  std::size_t dimension_line = 0;  // first line that set the dimension

  // Records the dimension of a line; throws if the file mixes 2D and 3D.
  void setDimension(GraphDimension d, const LineFields& fields);
};

// Tags each format knows (the parsers below handle exactly these).
bool isG2oTag(std::string_view tag);
bool isToroTag(std::string_view tag);

// Parse one line whose tag satisfies isG2oTag / isToroTag.
void parseG2oLine(const LineFields& fields, ParsedLines& out);
void parseToroLine(const LineFields& fields, ToroInformationOrder order, ParsedLines& out);

void writeG2o(const PoseGraph& graph, std::ostream& out, int precision);
void writeToro(const PoseGraph& graph, std::ostream& out, ToroInformationOrder order, int precision);

// ---- conventions shared by the formats (see graph_io.h) ----

// Symmetric matrix from its upper triangle given row by row (21 numbers), and back.
Matrix6 symmetricFromUpperTriangle(const double* upper);
void upperTriangle(const Matrix6& m, double* upper);

// Planar information in the order (x, y, theta), angle units -> lifted internal 6x6, and back.
Matrix6 liftPlanarInformation(const Matrix3& planar);
Matrix3 planarInformation(const Matrix6& information);

Pose3 liftPlanarPose(double x, double y, double theta);

// Where a planar edge's six information numbers go in the symmetric 3x3 (x, y, theta): g2o and
// TORO order them differently.
struct PlanarInformationLayout {
  const char* names[6];
  int row[6];
  int col[6];
};
// `TAG id x y theta` (g2o VERTEX_SE2, TORO VERTEX2/VERTEX).
void parsePlanarVertex(const LineFields& f, ParsedLines& out);
// `TAG id1 id2 dx dy dtheta` + six information numbers in `layout` order.
void parsePlanarEdge(const LineFields& f, const char* tag, const PlanarInformationLayout& layout, ParsedLines& out);
// (x, y, yaw) of a pose of a lifted 2D graph.
Vector3 planarPose(const Pose3& pose);

// Pose from x y z qx qy qz qw; the quaternion is normalised unless it already is to rounding
// (so that written-and-read-back files keep their bits).  Throws for a (near) zero quaternion.
Pose3 poseFromTranslationQuaternion(const LineFields& fields, const double* xyz_qxyzw,
                                    std::size_t first_quaternion_field);

// Builds one output line; numbers are printed with std::to_chars (locale independent, shortest
// round-trip at 17 digits).
class LineWriter {
 public:
  explicit LineWriter(int precision) : precision_(precision) {}
  LineWriter& tag(const char* tag);
  LineWriter& id(NodeId id);
  LineWriter& number(double value);
  void endLine(std::ostream& out);

 private:
  int precision_;
  std::string buffer_;
};

}  // namespace detail
}  // namespace toro
