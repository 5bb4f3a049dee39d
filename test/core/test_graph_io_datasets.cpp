// Every file of ../shared/datasets reads with the counts of its README, and the conventions agree
// with the other tools' conversions of the same data.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <map>

#include "toro_ros/core/graph_io.h"

using namespace toro;

// ---- the shared datasets ---------------------------------------------------------------------

namespace {
struct DatasetCounts {
  std::size_t nodes;
  std::size_t edges;
  GraphDimension dimension;
};

// Counts from ../shared/datasets/README.md.
const std::map<std::string, DatasetCounts>& datasetTable() {
  static const std::map<std::string, DatasetCounts> table = {
      {"sphere2500.g2o", {2500, 4949, GraphDimension::k3D}},
      {"parking-garage.g2o", {1661, 6275, GraphDimension::k3D}},
      {"sphere_bignoise_vertex3.g2o", {2200, 8647, GraphDimension::k3D}},
      {"smallGrid3D.g2o", {125, 297, GraphDimension::k3D}},
      {"small/tinyGrid3D.g2o", {9, 11, GraphDimension::k3D}},
      {"small/pose3example.txt", {5, 6, GraphDimension::k3D}},
      {"small/pose3example-grid.txt", {27, 44, GraphDimension::k3D}},
      {"toro/sphere_smallnoise.graph", {2200, 8647, GraphDimension::k3D}},
      {"toro/sphere_mednoise.graph", {2200, 8647, GraphDimension::k3D}},
      {"toro/sphere_bignoise.graph", {2200, 8647, GraphDimension::k3D}},
      {"toro/sphere_smallnoise_gtsam.graph", {2200, 8647, GraphDimension::k3D}},
      {"toro/sphere2500_gtsam.txt", {2500, 4949, GraphDimension::k3D}},
      {"toro/sphere2500_groundtruth_gtsam.txt", {2500, 4949, GraphDimension::k3D}},
      {"2d/intel.g2o", {1728, 2512, GraphDimension::k2D}},
      {"2d/intel_g2o-vertigo.g2o", {943, 1837, GraphDimension::k2D}},
      {"2d/manhattan.g2o", {3500, 5453, GraphDimension::k2D}},
      {"2d/manhattanOlson3500.g2o", {3500, 5598, GraphDimension::k2D}},
      {"2d/city10000.g2o", {10000, 20687, GraphDimension::k2D}},
      {"2d/CSAIL.g2o", {1045, 1172, GraphDimension::k2D}},
      {"2d/MIT.g2o", {808, 827, GraphDimension::k2D}},
      {"2d/ais2klinik.g2o", {15115, 16727, GraphDimension::k2D}},
      {"2d/kitti_00.g2o", {4541, 4677, GraphDimension::k2D}},
      {"2d/kitti_02.g2o", {4661, 4703, GraphDimension::k2D}},
      {"2d/kitti_05.g2o", {2761, 2826, GraphDimension::k2D}},
      {"toro/2d/w10000.graph", {10000, 64311, GraphDimension::k2D}},
      {"toro/2d/w100.graph", {100, 300, GraphDimension::k2D}},
  };
  return table;
}

const std::filesystem::path kDatasets = TORO_DATASETS_DIR;
}  // namespace

TEST(GraphIoDatasets, EveryFileReadsWithTheDocumentedCounts) {
  if (!std::filesystem::is_directory(kDatasets)) GTEST_SKIP() << "no datasets folder " << kDatasets;
  std::size_t files = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(kDatasets)) {
    if (!entry.is_regular_file()) continue;
    const std::string name = entry.path().filename().string();
    if (name == "README.md" || name == "REFERENCE.md") continue;
    const std::string relative = std::filesystem::relative(entry.path(), kDatasets).string();
    SCOPED_TRACE(relative);
    const auto it = datasetTable().find(relative);
    ASSERT_NE(it, datasetTable().end()) << "file not in the README table";
    ReadReport report;
    PoseGraph g;
    ASSERT_NO_THROW(g = readGraph(entry.path().string(), {}, &report));
    EXPECT_EQ(g.numNodes(), it->second.nodes);
    EXPECT_EQ(g.numConstraints(), it->second.edges);
    EXPECT_EQ(g.dimension(), it->second.dimension);
    ++files;
  }
  EXPECT_EQ(files, datasetTable().size());
}

TEST(GraphIoDatasets, ReportDetailsOfParticularFiles) {
  if (!std::filesystem::is_directory(kDatasets)) GTEST_SKIP() << "no datasets folder " << kDatasets;
  ReadReport r;
  readGraph((kDatasets / "toro/2d/w100.graph").string(), {}, &r);
  EXPECT_EQ(r.skipped_tags.at("EQUIV"), 40u);
  readGraph((kDatasets / "toro/sphere_smallnoise.graph").string(), {}, &r);
  EXPECT_EQ(r.comment_lines, 2u);  // #SEQUENTIAL / #LOOP
  EXPECT_TRUE(r.skipped_tags.empty());
  readGraph((kDatasets / "toro/sphere_smallnoise_gtsam.graph").string(), {}, &r);
  EXPECT_EQ(r.edges_without_information, 8647u);
  readGraph((kDatasets / "2d/manhattan.g2o").string(), {}, &r);
  EXPECT_FALSE(r.has_vertices);
  EXPECT_EQ(r.nodes_without_vertex.size(), 3500u);
  readGraph((kDatasets / "2d/kitti_00.g2o").string(), {}, &r);  // has blank lines
  EXPECT_EQ(r.edges, 4677u);
}

TEST(GraphIoDatasets, Sphere2500TranslationFirstToroMatchesG2oConversion) {
  // The same graph as g2o and as GTSAM's EDGE3 file: reading EDGE3 with R = Rz Ry Rx and the
  // translation-first order reproduces the g2o file (README: measurements to 5e-7, rotation
  // information (400, 400, 99.2) vs 4 x (100, 100, 25)).
  if (!std::filesystem::is_directory(kDatasets)) GTEST_SKIP() << "no datasets folder " << kDatasets;
  const PoseGraph g2o = readGraph((kDatasets / "sphere2500.g2o").string());
  const PoseGraph toro = readGraph((kDatasets / "toro/sphere2500_gtsam.txt").string());
  ASSERT_EQ(g2o.numConstraints(), toro.numConstraints());
  // The two files list the constraints in different orders; every (from, to) pair is unique.
  std::map<std::pair<NodeId, NodeId>, std::size_t> toro_index;
  for (std::size_t k = 0; k < toro.numConstraints(); ++k) {
    toro_index[{toro.constraints()[k].from, toro.constraints()[k].to}] = k;
  }
  ASSERT_EQ(toro_index.size(), toro.numConstraints());
  double worst_rotation = 0, worst_translation = 0;
  for (std::size_t k = 0; k < g2o.numConstraints(); ++k) {
    const Constraint& a = g2o.constraints()[k];
    const auto it = toro_index.find({a.from, a.to});
    ASSERT_NE(it, toro_index.end()) << a.from << " -> " << a.to;
    const Constraint& b = toro.constraints()[it->second];
    worst_rotation = std::max(worst_rotation, (a.measurement.inverse() * b.measurement).angle());
    worst_translation =
        std::max(worst_translation, (a.measurement.translation() - b.measurement.translation()).norm());
  }
  EXPECT_LT(worst_rotation, 2e-6);
  EXPECT_LT(worst_translation, 2e-5);
  const Matrix6& ia = g2o.constraints()[0].information;
  const Matrix6& ib = toro.constraints()[0].information;
  EXPECT_EQ(ib.diagonal(), (Vector6() << 10, 10, 10, 400, 400, 100).finished());
  EXPECT_NEAR(ia(3, 3), ib(3, 3), 0.01 * ib(3, 3));
  EXPECT_NEAR(ia(5, 5), ib(5, 5), 0.01 * ib(5, 5));
  EXPECT_NEAR(ia(0, 0), ib(0, 0), 1e-9);
}
