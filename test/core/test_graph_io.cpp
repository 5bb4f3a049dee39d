#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <sstream>

#include "toro_ros/core/graph_io.h"

using namespace toro;

namespace {

PoseGraph readText(const std::string& text, const std::string& name, const ReadOptions& options = {},
                   ReadReport* report = nullptr) {
  std::istringstream in(text);
  return readGraph(in, name, options, report);
}

// The ParseError a text produces (fails the test if none).
ParseError parseError(const std::string& text, const std::string& name, const ReadOptions& options = {}) {
  try {
    readText(text, name, options);
  } catch (const ParseError& e) {
    return e;
  }
  ADD_FAILURE() << "no ParseError for:\n" << text;
  return ParseError(name, 0, "none");
}

#define EXPECT_PARSE_ERROR(text, name, line_number, wording)                              \
  do {                                                                                    \
    const ParseError e_ = parseError(text, name);                                         \
    EXPECT_EQ(e_.line(), std::size_t(line_number)) << e_.what();                          \
    EXPECT_NE(std::string(e_.what()).find(wording), std::string::npos) << e_.what();      \
    EXPECT_EQ(std::string(e_.what()).rfind(std::string(name) + ":", 0), 0u) << e_.what(); \
  } while (0)

Matrix6 diag6(double a, double b, double c, double d, double e, double f) {
  Vector6 v;
  v << a, b, c, d, e, f;
  return v.asDiagonal();
}

const char* kIdentityInfo3 = " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";

}  // namespace

TEST(GraphIo, G2o3dValues) {
  const std::string text =
      "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"
      "VERTEX_SE3:QUAT 1 1.5 -2 3 0 0 0 2\n"  // unnormalised quaternion
      "EDGE_SE3:QUAT 0 1 1 2 3 0 0 0.6 0.8 "
      "10 1 2 3 4 5 20 6 7 8 9 30 10 11 12 40 13 14 50 15 60\n"
      "FIX 0\n";
  ReadReport report;
  const PoseGraph g = readText(text, "a.g2o", {}, &report);
  ASSERT_EQ(g.numNodes(), 2u);
  ASSERT_EQ(g.numConstraints(), 1u);
  EXPECT_EQ(g.dimension(), GraphDimension::k3D);
  EXPECT_EQ(g.pose(1).translation(), Vector3(1.5, -2, 3));
  EXPECT_DOUBLE_EQ(g.pose(1).rotation().w(), 1.0);  // normalised
  const Constraint& c = g.constraints()[0];
  EXPECT_EQ(c.from, 0);
  EXPECT_EQ(c.to, 1);
  EXPECT_EQ(c.measurement.translation(), Vector3(1, 2, 3));
  EXPECT_DOUBLE_EQ(c.measurement.rotation().z(), 0.6);
  EXPECT_DOUBLE_EQ(c.measurement.rotation().w(), 0.8);
  // Upper triangle row by row, mirrored, already in the internal convention.
  EXPECT_EQ(c.information(0, 0), 10);
  EXPECT_EQ(c.information(0, 5), 5);
  EXPECT_EQ(c.information(5, 0), 5);
  EXPECT_EQ(c.information(1, 2), 6);
  EXPECT_EQ(c.information(3, 3), 40);
  EXPECT_EQ(c.information(4, 5), 15);
  EXPECT_EQ(c.information(5, 5), 60);
  ASSERT_EQ(g.fixedNodes().size(), 1u);
  EXPECT_EQ(g.fixedNodes()[0], 0);
  EXPECT_EQ(report.format, GraphFormat::kG2o);
  EXPECT_EQ(report.vertices, 2u);
  EXPECT_EQ(report.edges, 1u);
  EXPECT_EQ(report.fixed, 1u);
  EXPECT_EQ(report.lines, 4u);
  EXPECT_TRUE(report.has_vertices);
}

TEST(GraphIo, G2o2dLiftedAndPlanarQuadraticFormKept) {
  const std::string text =
      "VERTEX_SE2 0 0 0 0\n"
      "VERTEX_SE2 1 1 2 0.5\n"
      "EDGE_SE2 0 1 1 2 0.5 10 1 2 20 3 30\n";  // xx xy xθ yy yθ θθ
  const PoseGraph g = readText(text, "a.g2o");
  EXPECT_EQ(g.dimension(), GraphDimension::k2D);
  EXPECT_NEAR(g.pose(1).rollPitchYaw().z(), 0.5, 1e-15);
  EXPECT_EQ(g.pose(1).translation(), Vector3(1, 2, 0));
  const Matrix6& I = g.constraints()[0].information;
  Matrix6 expected = Matrix6::Zero();
  expected(0, 0) = 10;
  expected(0, 1) = expected(1, 0) = 1;
  expected(1, 1) = 20;
  expected(0, 5) = expected(5, 0) = 2 * 2;  // cross x2
  expected(1, 5) = expected(5, 1) = 2 * 3;
  expected(5, 5) = 4 * 30;                   // rotation x4
  expected(2, 2) = 15;                       // mean of xx, yy
  expected(3, 3) = expected(4, 4) = 4 * 30;  // roll/pitch = θθ
  EXPECT_EQ(I, expected);
  // For a planar residual (ex, ey, dθ) the internal error (ex, ey, 0, 0, 0, sin(dθ/2)) weighs
  // (nearly) what the planar information gives: the chi2 is kept.
  const double ex = 0.01, ey = -0.02, dth = 1e-3;
  Vector6 e;
  e << ex, ey, 0, 0, 0, std::sin(dth / 2);
  const Eigen::Vector3d p(ex, ey, dth);
  Eigen::Matrix3d planar;
  planar << 10, 1, 2, 1, 20, 3, 2, 3, 30;
  EXPECT_NEAR(e.dot(I * e), p.dot(planar * p), 1e-9);
}

TEST(GraphIo, ToroInformationOrderBothOptions) {
  // diag(1..6) plus m01 = 0.1 (first-first pair) and m04 = 0.2 (first-block with index 4).
  const std::string text =
      "VERTEX3 0 0 0 0 0 0 0\n"
      "VERTEX3 1 1 2 3 0.1 -0.2 0.3\n"
      "EDGE3 0 1 1 2 3 0.1 -0.2 0.3 1 0.1 0 0 0.2 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6\n";
  ReadOptions options;
  const PoseGraph t = readText(text, "a.graph", options);
  Matrix6 expected_t = diag6(1, 2, 3, 4 * 4, 4 * 5, 4 * 6);
  expected_t(0, 1) = expected_t(1, 0) = 0.1;      // x-y
  expected_t(0, 4) = expected_t(4, 0) = 2 * 0.2;  // x-pitch cross
  EXPECT_EQ(t.constraints()[0].information, expected_t);

  options.toro_information_order = ToroInformationOrder::kRotationFirst;
  const PoseGraph r = readText(text, "a.graph", options);
  Matrix6 expected_r = diag6(4, 5, 6, 4 * 1, 4 * 2, 4 * 3);
  expected_r(3, 4) = expected_r(4, 3) = 4 * 0.1;  // roll-pitch
  expected_r(1, 3) = expected_r(3, 1) = 2 * 0.2;  // y-roll cross
  EXPECT_EQ(r.constraints()[0].information, expected_r);

  // Poses: x y z roll pitch yaw with R = Rz Ry Rx.
  const Pose3 expected_pose = Pose3::fromRollPitchYaw(1, 2, 3, 0.1, -0.2, 0.3);
  EXPECT_LT((t.pose(1).inverse() * expected_pose).angle(), 1e-15);
  EXPECT_EQ(t.pose(1).translation(), Vector3(1, 2, 3));
  EXPECT_LT((t.constraints()[0].measurement.rollPitchYaw() - Vector3(0.1, -0.2, 0.3)).norm(), 1e-15);
}

TEST(GraphIo, Toro2dOrderShortTagsAndSkippedTags) {
  const std::string text =
      "# a comment\n"
      "VERTEX2 0 0 0 0\n"
      "VERTEX 1 1 2 0.5\n"
      "EDGE2 0 1 1 2 0.5 10 1 20 30 2 3\n"  // xx xy yy θθ xθ yθ
      "EDGE 1 0 -1 -2 -0.5 10 1 20 30 2 3\n"
      "EQUIV 0 1\n"
      "\n"
      "EQUIV 1 0\n";
  ReadReport report;
  const PoseGraph g = readText(text, "w.graph", {}, &report);
  EXPECT_EQ(g.dimension(), GraphDimension::k2D);
  ASSERT_EQ(g.numConstraints(), 2u);
  const Matrix6& I = g.constraints()[0].information;
  EXPECT_EQ(I(0, 0), 10);
  EXPECT_EQ(I(0, 1), 1);
  EXPECT_EQ(I(1, 1), 20);
  EXPECT_EQ(I(5, 5), 120);
  EXPECT_EQ(I(0, 5), 4);
  EXPECT_EQ(I(1, 5), 6);
  EXPECT_EQ(report.skipped_tags.size(), 1u);
  EXPECT_EQ(report.skipped_tags.at("EQUIV"), 2u);
  EXPECT_EQ(report.comment_lines, 1u);
  EXPECT_EQ(report.lines, 8u);
  EXPECT_EQ(report.format, GraphFormat::kToro);
}

TEST(GraphIo, FormatDetectedFromContentAndExtension) {
  ReadReport report;
  readText("# x\nFOO 1\nEDGE3 0 1 1 0 0 0 0 0\n", "data.txt", {}, &report);
  EXPECT_EQ(report.format, GraphFormat::kToro);
  EXPECT_EQ(report.skipped_tags.at("FOO"), 1u);
  readText("VERTEX_SE2 0 0 0 0\n", "data.txt", {}, &report);
  EXPECT_EQ(report.format, GraphFormat::kG2o);
  // A tag of the other format is an error, not a silent skip.
  EXPECT_PARSE_ERROR("VERTEX3 0 0 0 0 0 0 0\n", "x.g2o", 1,
                     "VERTEX3: a TORO tag, but the file is read as g2o (by its extension)");
  EXPECT_PARSE_ERROR("EDGE3 0 1 1 0 0 0 0 0\nVERTEX_SE2 0 0 0 0\n", "x.txt", 2,
                     "a g2o tag, but the file is read as TORO");
  ReadOptions g2o;
  g2o.format = GraphFormat::kG2o;
  EXPECT_THROW(readText("VERTEX3 0 0 0 0 0 0 0\n", "x.graph", g2o), ParseError);
}

TEST(GraphIo, EmptyFileIsAnEmptyGraph) {
  ReadReport report;
  const PoseGraph g = readText("", "empty.g2o", {}, &report);
  EXPECT_TRUE(g.empty());
  EXPECT_TRUE(report.emptyGraph());
  EXPECT_FALSE(report.has_vertices);
  EXPECT_NE(describeReport(report).find("empty graph"), std::string::npos);
  readText("\n  \n# only a comment\r\n", "blank.g2o", {}, &report);
  EXPECT_TRUE(report.emptyGraph());
  EXPECT_EQ(report.lines, 3u);
}

TEST(GraphIo, EdgesWithoutVerticesAndWithoutInformation) {
  ReadReport report;
  const PoseGraph g =
      readText("VERTEX3 5 0 0 0 0 0 0\nEDGE3 7 5 1 0 0 0 0 0\nEDGE3 5 3 1 0 0 0 0 0\n", "a.txt", {}, &report);
  ASSERT_EQ(g.numNodes(), 3u);
  EXPECT_EQ(g.nodes()[0].id, 5);  // VERTEX nodes first, then the missing ones by id
  EXPECT_EQ(g.nodes()[1].id, 3);
  EXPECT_EQ(g.nodes()[2].id, 7);
  EXPECT_EQ(report.nodes_without_vertex, (std::vector<NodeId>{3, 7}));
  EXPECT_TRUE(g.pose(7).translation().isZero());
  EXPECT_TRUE(report.has_vertices);
  EXPECT_NE(
      describeReport(report).find("1 vertices, 2 edges, 0 fixed; 3 nodes\n  2 nodes without a VERTEX line"),
      std::string::npos)
      << describeReport(report);
  EXPECT_EQ(report.edges_without_information, 2u);
  EXPECT_EQ(g.constraints()[0].information, Matrix6::Identity());

  readText("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "a.g2o", {}, &report);
  EXPECT_FALSE(report.has_vertices);
  EXPECT_EQ(report.nodes_without_vertex.size(), 2u);
}

TEST(GraphIo, MalformedTooFewAndTooManyFields) {
  EXPECT_PARSE_ERROR(
      "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n"
      "EDGE_SE3:QUAT 0 1 1 2 3 0 0 0 1 1 0 0\n",
      "sphere.g2o", 3, "sphere.g2o:3: EDGE_SE3:QUAT: expected 30 fields, got 12");
  EXPECT_PARSE_ERROR("VERTEX2 0 0 0 0 9\n", "w.graph", 1, "VERTEX2: expected 4 fields, got 5");
  EXPECT_PARSE_ERROR("EDGE3 0 1 1 2 3\n", "w.graph", 1,
                     "EDGE3: expected 29 fields (or 8 without an information matrix), got 5");
  EXPECT_PARSE_ERROR("FIX\n", "w.g2o", 1, "FIX: expected at least 1 field");
}

TEST(GraphIo, MalformedNotANumber) {
  EXPECT_PARSE_ERROR("\n\nEDGE_SE3:QUAT 0 1 1 2 3 0 0 0 abc" + std::string(kIdentityInfo3) + "\n",
                     "sphere.g2o", 3, "sphere.g2o:3: EDGE_SE3:QUAT field 9 (qw): 'abc' is not a number");
  EXPECT_PARSE_ERROR("VERTEX_SE2 1.5 0 0 0\n", "a.g2o", 1,
                     "VERTEX_SE2 field 1 (id): '1.5' is not an integer id");
  EXPECT_PARSE_ERROR("EDGE2 0 1 1 0 0 1 0 1 1 1x 0\n", "a.graph", 1,
                     "EDGE2 field 10 (m02): '1x' is not a number");
}

TEST(GraphIo, MalformedNonFinite) {
  EXPECT_PARSE_ERROR("VERTEX3 0 0 nan 0 0 0 0\n", "a.graph", 1, "VERTEX3 field 3 (y): 'nan' is not finite");
  EXPECT_PARSE_ERROR("EDGE_SE3:QUAT 0 1 1 2 3 0 0 0 1 inf 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n", "a.g2o",
                     1, "EDGE_SE3:QUAT field 10 (I11): 'inf' is not finite");
  EXPECT_PARSE_ERROR("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1e999\n", "a.g2o", 1,
                     "field 8 (qw): '1e999' is out of the double range");
  EXPECT_PARSE_ERROR("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\n", "a.g2o", 1, "the quaternion is zero");
}

TEST(GraphIo, MalformedDuplicateVertexAndSelfLoop) {
  EXPECT_PARSE_ERROR("VERTEX_SE2 5 0 0 0\nVERTEX_SE2 6 0 0 0\nVERTEX_SE2 5 1 0 0\n", "a.g2o", 3,
                     "duplicate VERTEX id 5 (first on line 1)");
  EXPECT_PARSE_ERROR("VERTEX3 3 0 0 0 0 0 0\nEDGE3 3 3 1 0 0 0 0 0\n", "a.graph", 2,
                     "EDGE3: constraint 3 -> 3: self-loop");
}

TEST(GraphIo, MalformedMixed2dAnd3d) {
  EXPECT_PARSE_ERROR("VERTEX_SE2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n", "a.g2o", 2,
                     "VERTEX_SE3:QUAT: a 3D record in a 2D graph (line 1 is 2D)");
  EXPECT_PARSE_ERROR("EDGE3 0 1 1 0 0 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n", "a.graph", 2,
                     "EDGE2: a 2D record in a 3D graph");
}

TEST(GraphIo, MalformedFixOfUnknownNode) {
  EXPECT_PARSE_ERROR("VERTEX_SE2 0 0 0 0\nFIX 0 4\n", "a.g2o", 2, "FIX field 2 (id): unknown node 4");
}

TEST(GraphIo, AsymmetricInformationCannotComeFromAFileAndIsNotRepaired) {
  // Every format stores the upper triangle only; the reader mirrors it (TORO's own 3D loader did
  // not, leaving zeros below the diagonal).
  const PoseGraph g =
      readText(std::string("EDGE3 0 1 1 0 0 0 0 0 1 0.5 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n"), "a.graph");
  EXPECT_EQ(g.constraints()[0].information(1, 0), 0.5);
  Matrix6 asymmetric = Matrix6::Identity();
  asymmetric(0, 1) = 0.5;
  EXPECT_FALSE(repairInformation(asymmetric));
  EXPECT_NE(checkInformation(asymmetric).find("not symmetric"), std::string::npos);
}

TEST(GraphIo, IndefiniteInformationRefusedOrRepaired) {
  // Both 3x3 blocks are the identity (positive definite), the x-roll coupling makes the whole
  // indefinite: eigenvalues 3 and -1 on (x + roll, x - roll).
  const std::string line = "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0 2 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n";
  const std::string text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n" + line + line;
  ReadOptions off;
  off.repair_information = false;
  const ParseError e = parseError(text, "cubicle.g2o", off);
  EXPECT_EQ(e.line(), 3u);
  EXPECT_NE(
      std::string(e.what()).find("cubicle.g2o:3: EDGE_SE3:QUAT: constraint 0 -> 1: information matrix is "
                                 "not positive definite (information repair is off)"),
      std::string::npos)
      << e.what();

  ReadReport report;
  const PoseGraph g = readText(text, "cubicle.g2o", {}, &report);
  EXPECT_EQ(report.repaired_information, 2u);
  EXPECT_EQ(report.repaired_lines, (std::vector<std::size_t>{3, 4}));
  const Matrix6& I = g.constraints()[0].information;
  EXPECT_TRUE(checkInformation(I).empty());
  // The positive eigen-direction is kept, the negative one raised to the small floor.
  Vector6 plus = Vector6::Zero(), minus = Vector6::Zero();
  plus(0) = plus(3) = std::sqrt(0.5);
  minus(0) = std::sqrt(0.5);
  minus(3) = -std::sqrt(0.5);
  EXPECT_NEAR(plus.dot(I * plus), 3.0, 1e-12);
  EXPECT_NEAR(minus.dot(I * minus), 3.0 * kRepairEigenvalueFraction, 1e-12);
  EXPECT_NEAR(I(1, 1), 1.0, 1e-12);
  EXPECT_NE(describeReport(report).find("2 information matrices not positive definite, repaired (lines 3 4)"),
            std::string::npos)
      << describeReport(report);
}

TEST(GraphIo, NegativeDefiniteInformationCannotBeRepaired) {
  EXPECT_PARSE_ERROR("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 -1 0 0 0 0 0 -1 0 0 0 0 -1 0 0 0 -1 0 0 -1 0 -1\n",
                     "a.g2o", 1,
                     "EDGE_SE3:QUAT: constraint 0 -> 1: information matrix is not positive definite");
}

TEST(GraphIo, MissingFileAndDirectory) {
  try {
    readGraph("/nonexistent/dir/graph.g2o");
    FAIL() << "no error";
  } catch (const ParseError& e) {
    EXPECT_EQ(e.line(), 0u);
    EXPECT_EQ(std::string(e.what()),
              "/nonexistent/dir/graph.g2o: cannot open for reading: No such file or directory");
  }
  EXPECT_THROW(readGraph(std::filesystem::temp_directory_path().string()), ParseError);
}

TEST(GraphIo, GarbageBinaryAndNonTagLines) {
  std::string garbage = "VERTEX_SE2 0 0 0 0\n";
  garbage += std::string(
      "\x7f"
      "ELF\x02\x01\x01\0\0\0",
      10);
  EXPECT_PARSE_ERROR(garbage, "a.out", 2, "binary data (byte 0x7f at column 1): not a text graph file");
  EXPECT_PARSE_ERROR("1 2 3\n", "a.g2o", 1, "'1' is not a tag");
  EXPECT_PARSE_ERROR("\xc3\xa9t\xc3\xa9 1\n", "a.g2o", 1, "'\\xc3\\xa9t\\xc3\\xa9' is not a tag");
}

// The quoted part of a message helps the file's owner; redactedWhat() (the node's services) says
// the same without any of the file's content.
TEST(GraphIo, ErrorsQuoteAShortSanitisedExcerptAndTheRedactedFormNone) {
  EXPECT_EQ(excerpt("abc"), "'abc'");
  EXPECT_EQ(excerpt("a\x1b]0;x\x07\xc2\x9b"), "'a\\x1b]0;x\\x07\\xc2\\x9b'");  // no terminal escape passes
  EXPECT_EQ(excerpt(std::string(100, 'x')), "'" + std::string(kMaxExcerpt, 'x') + "...'");
  const std::string passwd_line = "root:x:0:0:root:/root:/bin/bash\n";
  const ParseError not_tag = parseError(passwd_line, "/etc/passwd");
  EXPECT_EQ(std::string(not_tag.what()),
            "/etc/passwd:1: 'root:x:0:0:root:/root:/bin/bash' is not a tag (a data line starts with a tag such "
            "as VERTEX_SE3:QUAT or EDGE3)");
  EXPECT_EQ(not_tag.redactedWhat(),
            "/etc/passwd:1: the line does not start with a tag (a data line starts with a tag such as "
            "VERTEX_SE3:QUAT or EDGE3)");
  const ParseError field = parseError("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 secret\n", "a.g2o");
  EXPECT_EQ(field.redactedWhat(), "a.g2o:1: VERTEX_SE3:QUAT field 8 (qw): the value is not a number");
  EXPECT_NE(std::string(field.what()).find("'secret'"), std::string::npos);
  const ParseError binary = parseError("VERTEX_SE2 0 0 0 0\nab\x01\n", "a.g2o");
  EXPECT_EQ(binary.redactedWhat(), "a.g2o:2: binary data (a control character at column 3): not a text graph file");
  // Messages that quote nothing are the same in both forms.
  const ParseError count = parseError("VERTEX2 0 0 0 0 9\n", "w.graph");
  EXPECT_EQ(count.redactedWhat(), std::string(count.what()));
}
