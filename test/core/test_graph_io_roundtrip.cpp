// Read -> write -> read gives the same graph: bit for bit for g2o at 17 digits, TORO's Euler angles
// to 1e-12, information matrices exactly (the unit conversions are powers of two).
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/random_draws.h"

using namespace toro;

namespace {

PoseGraph readText(const std::string& text, const std::string& name, const ReadOptions& options = {}) {
  std::istringstream in(text);
  return readGraph(in, name, options);
}

std::string writeText(const PoseGraph& graph, GraphFormat format,
                      ToroInformationOrder order = ToroInformationOrder::kTranslationFirst) {
  std::ostringstream out;
  WriteOptions options;
  options.format = format;
  options.toro_information_order = order;
  writeGraph(graph, out, options);
  return out.str();
}

}  // namespace

// ---- round trips -----------------------------------------------------------------------------

namespace {

Matrix6 randomInformation(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Matrix6 a;
  for (int i = 0; i < 36; ++i) a(i) = u(rng);
  const Matrix6 m = a * a.transpose() + Matrix6::Identity();
  return 0.5 * (m + m.transpose());  // exactly symmetric, as a file can only express
}

PoseGraph randomGraph(std::mt19937& rng, bool planar) {
  std::normal_distribution<double> n(0.0, 1.0);
  PoseGraph g;
  for (NodeId id = 0; id < 6; ++id) {
    const auto xy_yaw = [&] {
      const auto d = drawLastFirst<3>(n, rng);
      return Pose3::fromRollPitchYaw(d[0], d[1], 0, 0, 0, d[2]);
    };
    const Pose3 p = planar ? xy_yaw() : drawPose3(n, n, rng);
    g.addNode(id * 3, p);
  }
  for (NodeId k = 0; k < 10; ++k) {
    Constraint c;
    c.from = 3 * (k % 6);
    c.to = 3 * ((k * 5 + 1) % 6);
    if (c.from == c.to) c.to = 3 * ((k + 1) % 6);
    const double yaw = 0.1 * n(rng), z = planar ? 0 : 0.1 * n(rng), y = 0.1 * n(rng), x = 0.1 * n(rng);
    c.measurement = relativePose(g.pose(c.from), g.pose(c.to)) * Pose3::fromRollPitchYaw(x, y, z, 0, 0, yaw);
    if (planar) {
      Eigen::Matrix3d a = Eigen::Matrix3d::Random();
      Eigen::Matrix3d p = a * a.transpose() + Eigen::Matrix3d::Identity();
      p = (0.5 * (p + p.transpose())).eval();
      Matrix6 lifted = Matrix6::Zero();
      const int idx[3] = {0, 1, 5};
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) lifted(idx[i], idx[j]) = p(i, j) * (i == 2 ? 2 : 1) * (j == 2 ? 2 : 1);
      lifted(2, 2) = 0.5 * (p(0, 0) + p(1, 1));
      lifted(3, 3) = lifted(4, 4) = 4 * p(2, 2);
      c.information = lifted;
    } else {
      c.information = randomInformation(rng);
    }
    g.addConstraint(c);
  }
  if (planar) g.setDimension(GraphDimension::k2D);
  g.addFixed(0);
  return g;
}

void expectSameStructure(const PoseGraph& a, const PoseGraph& b) {
  ASSERT_EQ(a.numNodes(), b.numNodes());
  ASSERT_EQ(a.numConstraints(), b.numConstraints());
  EXPECT_EQ(a.dimension(), b.dimension());
  for (std::size_t i = 0; i < a.numNodes(); ++i) EXPECT_EQ(a.node(i).id, b.node(i).id);
  for (std::size_t k = 0; k < a.numConstraints(); ++k) {
    EXPECT_EQ(a.constraints()[k].from, b.constraints()[k].from);
    EXPECT_EQ(a.constraints()[k].to, b.constraints()[k].to);
    EXPECT_EQ(a.constraints()[k].information, b.constraints()[k].information) << "constraint " << k;
  }
}

void expectPosesNear(const Pose3& a, const Pose3& b, double tol) {
  EXPECT_LT((a.inverse() * b).angle(), tol);
  EXPECT_LT((a.translation() - b.translation()).norm(), tol);
}

}  // namespace

TEST(GraphIo, RoundTripG2o3dIsBitwise) {
  std::mt19937 rng(7);
  const PoseGraph original = randomGraph(rng, false);
  const PoseGraph a = readText(writeText(original, GraphFormat::kG2o), "a.g2o");
  const std::string text = writeText(a, GraphFormat::kG2o);
  const PoseGraph b = readText(text, "b.g2o");
  expectSameStructure(a, b);
  expectSameStructure(original, a);
  for (std::size_t i = 0; i < a.numNodes(); ++i) {
    EXPECT_EQ(a.node(i).pose.rotation().coeffs(), b.node(i).pose.rotation().coeffs());
    EXPECT_EQ(a.node(i).pose.translation(), b.node(i).pose.translation());
    EXPECT_EQ(original.node(i).pose.rotation().coeffs(), a.node(i).pose.rotation().coeffs());
  }
  for (std::size_t k = 0; k < a.numConstraints(); ++k) {
    EXPECT_EQ(a.constraints()[k].measurement.rotation().coeffs(),
              b.constraints()[k].measurement.rotation().coeffs());
    EXPECT_EQ(a.constraints()[k].measurement.translation(), b.constraints()[k].measurement.translation());
  }
  EXPECT_EQ(text, writeText(b, GraphFormat::kG2o));
  EXPECT_EQ(b.fixedNodes(), std::vector<NodeId>{0});
}

TEST(GraphIo, RoundTripToro3dBothOrders) {
  std::mt19937 rng(8);
  const PoseGraph original = randomGraph(rng, false);
  for (const auto order : {ToroInformationOrder::kTranslationFirst, ToroInformationOrder::kRotationFirst}) {
    ReadOptions options;
    options.toro_information_order = order;
    const PoseGraph a = readText(writeText(original, GraphFormat::kToro, order), "a.graph", options);
    const PoseGraph b = readText(writeText(a, GraphFormat::kToro, order), "b.graph", options);
    expectSameStructure(original, a);  // information exact: powers of two and a permutation
    expectSameStructure(a, b);
    for (std::size_t i = 0; i < a.numNodes(); ++i) {
      expectPosesNear(original.node(i).pose, a.node(i).pose, 1e-12);
      EXPECT_LT((a.node(i).pose.rollPitchYaw() - b.node(i).pose.rollPitchYaw()).cwiseAbs().maxCoeff(), 1e-12);
      EXPECT_EQ(a.node(i).pose.translation(), b.node(i).pose.translation());
    }
    for (std::size_t k = 0; k < a.numConstraints(); ++k) {
      expectPosesNear(a.constraints()[k].measurement, b.constraints()[k].measurement, 1e-12);
    }
  }
  // Reading with the other order than the writer's gives a different weighting: the option matters.
  ReadOptions rotation_first;
  rotation_first.toro_information_order = ToroInformationOrder::kRotationFirst;
  const PoseGraph swapped = readText(writeText(original, GraphFormat::kToro), "c.graph", rotation_first);
  EXPECT_NE(swapped.constraints()[0].information, original.constraints()[0].information);
}

TEST(GraphIo, RoundTrip2dG2oAndToro) {
  std::mt19937 rng(9);
  const PoseGraph original = randomGraph(rng, true);
  for (const auto format : {GraphFormat::kG2o, GraphFormat::kToro}) {
    const std::string text = writeText(original, format);
    EXPECT_NE(text.find(format == GraphFormat::kG2o ? "EDGE_SE2 " : "EDGE2 "), std::string::npos);
    const PoseGraph a = readText(text, format == GraphFormat::kG2o ? "a.g2o" : "a.graph");
    const PoseGraph b = readText(writeText(a, format), format == GraphFormat::kG2o ? "b.g2o" : "b.graph");
    expectSameStructure(original, a);
    expectSameStructure(a, b);
    for (std::size_t i = 0; i < a.numNodes(); ++i) {
      EXPECT_EQ(a.node(i).pose.translation(), b.node(i).pose.translation());
      EXPECT_NEAR(a.node(i).pose.rollPitchYaw().z(), b.node(i).pose.rollPitchYaw().z(), 1e-15);
      expectPosesNear(original.node(i).pose, a.node(i).pose, 1e-15);
    }
  }
}

TEST(GraphIo, WriteFileByExtensionAndUnwritablePath) {
  std::mt19937 rng(10);
  const PoseGraph original = randomGraph(rng, false);
  const auto dir = std::filesystem::temp_directory_path() / ("toro_graph_io_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  for (const char* name : {"out.g2o", "out.graph", "out.toro"}) {
    const std::string path = (dir / name).string();
    writeGraph(original, path);
    std::ifstream in(path);
    std::string tag;
    in >> tag;
    EXPECT_EQ(tag, std::string(name) == "out.g2o" ? "VERTEX_SE3:QUAT" : "VERTEX3") << name;
    ReadOptions options;
    options.format = std::string(name) == "out.g2o" ? GraphFormat::kG2o : GraphFormat::kToro;
    expectSameStructure(original, readGraph(path, options));
  }
  std::filesystem::remove_all(dir);
  try {
    writeGraph(original, "/nonexistent/dir/out.g2o");
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot write '/nonexistent/dir/out.g2o'"), std::string::npos);
  }
}
