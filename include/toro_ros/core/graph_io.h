// Reading and writing pose-graph files: g2o (3D SE3:QUAT and 2D SE2) and TORO (.graph: 3D
// VERTEX3/EDGE3 and 2D VERTEX2/EDGE2, also the 2D tags VERTEX/EDGE).  The line formats and the
// evidence for every convention below are in ../shared/datasets/README.md, "Formats".
//
// Information conventions.  Internally (PoseGraph) the 6x6 information is g2o's: translation
// (x y z) first, then rotation, with the rotational block in units of the quaternion's vector part.
// Files that give rotational information per rad^2 of angle (TORO's Euler angles, the 2D theta)
// are converted with an exact power-of-two scaling: rotation block x4, translation-rotation cross
// block x2 (q-vec ~ angle/2).  Writers divide back, so information round-trips bit for bit.
//
// TORO EDGE3 information order is ambiguous between tools.  Default (kTranslationFirst): the 21
// numbers are the upper triangle of a matrix in the order x y z roll pitch yaw, as HOG-Man and g2o
// read them and as the shared data was converted.  kRotationFirst reads them in the order
// roll pitch yaw x y z, as TORO's own optimiser uses them.
//
// 2D graphs are lifted into the plane z = 0 (PoseGraph::dimension() == k2D).  The lifted
// information keeps the planar 3x3 at indices (x, y, yaw) = (0, 1, 5); the out-of-plane entries,
// which only hold the graph in its plane, are: z information = mean of the xx and yy entries,
// roll and pitch information = the theta-theta entry (4*theta-theta in internal units), no cross
// terms.  Writers recover the planar 3x3 from indices (0, 1, 5) and ignore the rest.
#pragma once

#include <cstddef>
#include <iosfwd>
#include <map>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

enum class GraphFormat { kAuto, kG2o, kToro };
enum class ToroInformationOrder { kTranslationFirst, kRotationFirst };

// A malformed input file.  what() is "file:line: message" ("file: message" when the problem is
// not on one line, e.g. the file cannot be opened).  The message may quote a short excerpt of the
// file (see excerpt()), which helps the file's owner (toro_optimize); redactedWhat() says the
// same with no part of the file's content, for callers that answer someone who may not be allowed
// to read the file (the node's services answer any client on the ROS network).
class ParseError : public std::runtime_error {
 public:
  // `redacted_message`: `message` without the quoted content; empty when `message` quotes none.
  ParseError(const std::string& file, std::size_t line, const std::string& message,
             const std::string& redacted_message = "");
  const std::string& file() const { return file_; }
  std::size_t line() const { return line_; }  // 1-based; 0 when not about one line
  const std::string& message() const { return message_; }
  const std::string& redactedMessage() const { return redacted_message_; }
  // "file:line: " + redactedMessage().
  const std::string& redactedWhat() const { return redacted_what_; }

 private:
  std::string file_;
  std::size_t line_;
  std::string message_;
  std::string redacted_message_;
  std::string redacted_what_;
};

// A piece of file content for an error message: in single quotes, at most kMaxExcerpt characters
// (then "..."), every byte outside printable ASCII shown as \xNN (so no terminal control sequence
// or invalid UTF-8 reaches a log or a terminal).
constexpr std::size_t kMaxExcerpt = 40;
std::string excerpt(std::string_view text);

// The format a file name's extension says (case-insensitive): .g2o -> kG2o; .graph, .toro ->
// kToro; anything else kAuto.
GraphFormat formatFromExtension(const std::string& path);

struct ReadOptions {
  // kAuto: by extension (.g2o -> g2o; .graph, .toro -> TORO), otherwise by the first data tag.
  GraphFormat format = GraphFormat::kAuto;
  ToroInformationOrder toro_information_order = ToroInformationOrder::kTranslationFirst;
  // Project symmetric information matrices that are not positive definite onto the nearest
  // positive-definite one (see repairInformation) instead of refusing the line.
  bool repair_information = true;
};

// What a read found, for the caller to show or check.
struct ReadReport {
  static constexpr std::size_t kMaxListedLines = 10;

  std::string source;                       // file name as given (or the stream's display name)
  GraphFormat format = GraphFormat::kAuto;  // the format actually read
  GraphDimension dimension = GraphDimension::k3D;
  std::size_t lines = 0;                            // lines read, blank and comment lines included
  std::size_t comment_lines = 0;                    // lines starting with '#'
  std::size_t vertices = 0;                         // VERTEX lines
  std::size_t edges = 0;                            // EDGE lines (= constraints)
  std::size_t fixed = 0;                            // distinct nodes named on FIX lines
  bool has_vertices = false;                        // false: no VERTEX line, every pose needs a guess
  std::map<std::string, std::size_t> skipped_tags;  // unknown tags (e.g. EQUIV) and their counts
  // Edge endpoints without a VERTEX line; they were added with the identity pose (ascending ids,
  // after the nodes that have a VERTEX line), so only a chained initial guess makes sense for them.
  std::vector<NodeId> nodes_without_vertex;
  std::size_t edges_without_information = 0;  // GTSAM-style EDGE3 with 6 values: identity used
  std::size_t repaired_information = 0;       // matrices changed by repairInformation
  std::vector<std::size_t> repaired_lines;    // their line numbers, the first kMaxListedLines

  bool emptyGraph() const { return vertices == 0 && edges == 0; }
};

// Multi-line human-readable summary of a report (no trailing newline), e.g. for toro_optimize.
std::string describeReport(const ReadReport& report);

const char* formatName(GraphFormat format);

// Reads a graph file.  Throws ParseError for a file that cannot be opened or a malformed line.
PoseGraph readGraph(const std::string& path, const ReadOptions& options = {}, ReadReport* report = nullptr);
// Same from a stream; `display_name` is used in messages and, for kAuto, for its extension.
PoseGraph readGraph(std::istream& in, const std::string& display_name, const ReadOptions& options = {},
                    ReadReport* report = nullptr);

struct WriteOptions {
  // kAuto: by extension (.graph, .toro -> TORO; otherwise g2o).  The stream overload writes g2o.
  GraphFormat format = GraphFormat::kAuto;
  ToroInformationOrder toro_information_order = ToroInformationOrder::kTranslationFirst;
  // Significant digits (1..17).  17 makes g2o files round-trip bit for bit.
  int precision = 17;
};

// Writes every node (VERTEX lines, in node order), every constraint and, for g2o, the FIX lines
// (TORO has no such tag).  2D graphs are written with the 2D tags of the format.
// Throws std::runtime_error naming the path if it cannot be written.
void writeGraph(const PoseGraph& graph, const std::string& path, const WriteOptions& options = {});
void writeGraph(const PoseGraph& graph, std::ostream& out, const WriteOptions& options = {});

}  // namespace toro
