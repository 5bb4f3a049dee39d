// Graph files: line splitting, format detection, building the PoseGraph from the parsed records,
// the report, and the writers' dispatch.  The per-format lines are in g2o_io.cpp and toro_io.cpp.
#include "toro_ros/core/graph_io.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>

#include "graph_io_detail.h"

namespace toro {

namespace {
std::string locate(const std::string& file, std::size_t line) {
  return line == 0 ? file : file + ":" + std::to_string(line);
}

// Lower-case extension of a path including the dot, e.g. ".g2o".
std::string extensionOf(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext;
}

bool isSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

bool isTag(std::string_view token) {
  const auto letter = [](char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_'; };
  if (token.empty() || !letter(token[0])) return false;
  return std::all_of(token.begin(), token.end(),
                     [&](char c) { return letter(c) || (c >= '0' && c <= '9') || c == ':'; });
}

// Splits a file into records, line by line.
class LineReader {
 public:
  LineReader(const std::string& source, const ReadOptions& options, ReadReport& report)
      : source_(source), options_(options), report_(report) {
    format_ = options.format;
    reason_ = "as requested";
    if (format_ == GraphFormat::kAuto) {
      format_ = formatFromExtension(source);
      reason_ = "by its extension";
    }
  }

  void readAll(const std::string& content) {
    std::size_t pos = 0, number = 0;
    while (pos < content.size()) {
      std::size_t end = content.find('\n', pos);
      if (end == std::string::npos) end = content.size();
      processLine(std::string_view(content).substr(pos, end - pos), ++number);
      pos = end + 1;
    }
    report_.lines = number;
  }

  detail::ParsedLines& parsed() { return parsed_; }
  GraphFormat format() const { return format_; }

 private:
  void processLine(std::string_view text, std::size_t number);
  void checkText(std::string_view text, std::size_t number) const;
  void split(std::string_view text);

  const std::string& source_;
  const ReadOptions& options_;
  ReadReport& report_;
  GraphFormat format_;
  std::string reason_;  // why format_ was chosen, for messages
  std::vector<std::string_view> tokens_;
  detail::ParsedLines parsed_;
};

void LineReader::checkText(std::string_view text, std::size_t number) const {
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if ((c < 0x20 && !isSpace(text[i])) || c == 0x7f) {
      std::ostringstream s;
      s << "binary data (byte 0x" << std::hex << static_cast<int>(c) << std::dec << " at column " << i + 1
        << "): not a text graph file";
      throw ParseError(source_, number, s.str(),
                       "binary data (a control character at column " + std::to_string(i + 1) +
                           "): not a text graph file");
    }
  }
}

void LineReader::split(std::string_view text) {
  tokens_.clear();
  std::size_t i = 0;
  while (i < text.size()) {
    while (i < text.size() && isSpace(text[i])) ++i;
    const std::size_t start = i;
    while (i < text.size() && !isSpace(text[i])) ++i;
    if (i > start) tokens_.push_back(text.substr(start, i - start));
  }
}

void LineReader::processLine(std::string_view text, std::size_t number) {
  checkText(text, number);
  split(text);
  if (tokens_.empty()) return;
  if (tokens_[0][0] == '#') {
    ++report_.comment_lines;
    return;
  }
  const std::string_view tag = tokens_[0];
  if (!isTag(tag)) {
    constexpr const char* kExpected = "(a data line starts with a tag such as VERTEX_SE3:QUAT or EDGE3)";
    throw ParseError(source_, number, excerpt(tag) + " is not a tag " + kExpected,
                     std::string("the line does not start with a tag ") + kExpected);
  }
  const bool g2o = detail::isG2oTag(tag);
  if (!g2o && !detail::isToroTag(tag)) {
    ++report_.skipped_tags[std::string(tag)];
    return;
  }
  const GraphFormat line_format = g2o ? GraphFormat::kG2o : GraphFormat::kToro;
  if (format_ == GraphFormat::kAuto) {
    format_ = line_format;
    reason_ = "from its first data line, " + std::to_string(number);
  }
  if (line_format != format_) {
    throw ParseError(source_, number,
                     std::string(tag) + ": a " + formatName(line_format) + " tag, but the file is read as " +
                         formatName(format_) + " (" + reason_ + ")");
  }
  const detail::LineFields fields(source_, number, tokens_);
  if (g2o) {
    detail::parseG2oLine(fields, parsed_);
  } else {
    detail::parseToroLine(fields, options_.toro_information_order, parsed_);
  }
}

void addVertices(const detail::ParsedLines& parsed, const std::string& source, PoseGraph& graph) {
  for (const detail::VertexRecord& v : parsed.vertices) {
    if (graph.hasNode(v.id)) {
      const std::size_t first = parsed.vertices[graph.indexOf(v.id)].line;
      throw ParseError(
          source, v.line,
          "duplicate VERTEX id " + std::to_string(v.id) + " (first on line " + std::to_string(first) + ")");
    }
    try {
      graph.addNode(v.id, v.pose);
    } catch (const GraphError& error) {
      throw ParseError(source, v.line, error.what());
    }
  }
}

// Edge endpoints without a VERTEX line get the identity pose (the chained guess replaces it).
void addMissingNodes(const detail::ParsedLines& parsed, PoseGraph& graph, ReadReport& report) {
  std::set<NodeId> missing;
  for (const detail::EdgeRecord& e : parsed.edges) {
    if (!graph.hasNode(e.constraint.from)) missing.insert(e.constraint.from);
    if (!graph.hasNode(e.constraint.to)) missing.insert(e.constraint.to);
  }
  for (const NodeId id : missing) graph.addNode(id, Pose3());
  report.nodes_without_vertex.assign(missing.begin(), missing.end());
}

void addEdges(detail::ParsedLines& parsed, const std::string& source, const ReadOptions& options,
              PoseGraph& graph, ReadReport& report) {
  for (detail::EdgeRecord& e : parsed.edges) {
    Matrix6& information = e.constraint.information;
    if (options.repair_information && !checkInformation(information).empty() &&
        repairInformation(information)) {
      ++report.repaired_information;
      if (report.repaired_lines.size() < ReadReport::kMaxListedLines) report.repaired_lines.push_back(e.line);
    }
    try {
      graph.addConstraint(e.constraint);
    } catch (const GraphError& error) {
      std::string message = std::string(e.tag) + ": " + error.what();
      if (!options.repair_information && message.find("positive definite") != std::string::npos) {
        message += " (information repair is off)";
      }
      throw ParseError(source, e.line, message);
    }
  }
}

void addFixes(const detail::ParsedLines& parsed, const std::string& source, PoseGraph& graph,
              ReadReport& report) {
  std::set<NodeId> fixed;
  for (const detail::FixRecord& f : parsed.fixes) {
    if (!graph.hasNode(f.id)) {
      throw ParseError(
          source, f.line,
          "FIX field " + std::to_string(f.field) + " (id): unknown node " + std::to_string(f.id));
    }
    if (fixed.insert(f.id).second) graph.addFixed(f.id);
  }
  report.fixed = fixed.size();
}
}  // namespace

ParseError::ParseError(const std::string& file, std::size_t line, const std::string& message,
                       const std::string& redacted_message)
    : std::runtime_error(locate(file, line) + ": " + message),
      file_(file),
      line_(line),
      message_(message),
      redacted_message_(redacted_message.empty() ? message : redacted_message),
      redacted_what_(locate(file, line) + ": " + redacted_message_) {}

std::string excerpt(std::string_view text) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out = "'";
  for (std::size_t i = 0; i < text.size() && i < kMaxExcerpt; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 0xf];
    }
  }
  if (text.size() > kMaxExcerpt) out += "...";
  return out + "'";
}

GraphFormat formatFromExtension(const std::string& path) {
  const std::string ext = extensionOf(path);
  if (ext == ".g2o") return GraphFormat::kG2o;
  if (ext == ".graph" || ext == ".toro") return GraphFormat::kToro;
  return GraphFormat::kAuto;
}

const char* formatName(GraphFormat format) {
  switch (format) {
    case GraphFormat::kG2o:
      return "g2o";
    case GraphFormat::kToro:
      return "TORO";
    case GraphFormat::kAuto:
      break;
  }
  return "unknown";
}

PoseGraph readGraph(std::istream& in, const std::string& display_name, const ReadOptions& options,
                    ReadReport* report_out) {
  const std::string content{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  if (in.bad()) throw ParseError(display_name, 0, "read error");
  ReadReport report;
  report.source = display_name;
  LineReader reader(display_name, options, report);
  reader.readAll(content);
  detail::ParsedLines& parsed = reader.parsed();

  PoseGraph graph;
  report.format = reader.format();
  report.dimension = parsed.dimension.value_or(GraphDimension::k3D);
  graph.setDimension(report.dimension);
  addVertices(parsed, display_name, graph);
  addMissingNodes(parsed, graph, report);
  addEdges(parsed, display_name, options, graph, report);
  addFixes(parsed, display_name, graph, report);
  report.vertices = parsed.vertices.size();
  report.edges = parsed.edges.size();
  report.has_vertices = !parsed.vertices.empty();
  report.edges_without_information = parsed.edges_without_information;
  if (report_out) *report_out = std::move(report);
  return graph;
}

PoseGraph readGraph(const std::string& path, const ReadOptions& options, ReadReport* report) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw ParseError(path, 0, "is a directory, not a graph file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ParseError(path, 0, std::string("cannot open for reading: ") + std::strerror(errno));
  return readGraph(in, path, options, report);
}

std::string describeReport(const ReadReport& r) {
  std::ostringstream s;
  s << r.source << ": " << formatName(r.format) << ' ' << (r.dimension == GraphDimension::k2D ? "2D" : "3D")
    << ", " << r.lines << " lines: " << r.vertices << " vertices, " << r.edges << " edges, " << r.fixed
    << " fixed; " << r.vertices + r.nodes_without_vertex.size() << " nodes";
  if (r.emptyGraph()) s << "\n  empty graph (no vertex and no edge)";
  if (!r.skipped_tags.empty()) {
    s << "\n  skipped unknown tags:";
    for (const auto& [tag, count] : r.skipped_tags) s << ' ' << tag << " x" << count;
  }
  if (!r.nodes_without_vertex.empty()) {
    s << "\n  " << r.nodes_without_vertex.size()
      << " nodes without a VERTEX line (identity pose; chain the guess)";
  }
  if (r.edges_without_information > 0) {
    s << "\n  " << r.edges_without_information << " edges without an information matrix (identity used)";
  }
  if (r.repaired_information > 0) {
    s << "\n  " << r.repaired_information << " information matrices not positive definite, repaired (lines";
    for (const std::size_t line : r.repaired_lines) s << ' ' << line;
    if (r.repaired_information > r.repaired_lines.size()) s << " ...";
    s << ')';
  }
  return s.str();
}

namespace {
void writeFormat(const PoseGraph& graph, std::ostream& out, GraphFormat format, const WriteOptions& options) {
  if (options.precision < 1 || options.precision > 17) {
    throw std::runtime_error("write precision must be 1..17, got " + std::to_string(options.precision));
  }
  if (format == GraphFormat::kToro) {
    detail::writeToro(graph, out, options.toro_information_order, options.precision);
  } else {
    detail::writeG2o(graph, out, options.precision);
  }
}
}  // namespace

void writeGraph(const PoseGraph& graph, std::ostream& out, const WriteOptions& options) {
  writeFormat(graph, out, options.format, options);
}

void writeGraph(const PoseGraph& graph, const std::string& path, const WriteOptions& options) {
  GraphFormat format = options.format;
  if (format == GraphFormat::kAuto) format = formatFromExtension(path);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw std::runtime_error("cannot write '" + path + "': " + std::strerror(errno));
  writeFormat(graph, out, format, options);
  out.flush();
  if (!out) throw std::runtime_error("error while writing '" + path + "': " + std::strerror(errno));
}

}  // namespace toro
