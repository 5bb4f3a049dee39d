// GraphDirectory: the names ~save_graph and ~load_graph take are confined to graph_directory.
// Every refusal is checked for "nothing read or written" (the target's bytes, the directory's
// listing) and for a message that names the problem without any content of the file.
#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include <gtest/gtest.h>

#include "drift_scenario.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/graph_directory.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;

namespace {

namespace fs = std::filesystem;

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void put(const fs::path& path, const std::string& text) { std::ofstream(path, std::ios::binary) << text; }

std::set<std::string> listing(const fs::path& dir) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  return names;
}

bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// A temporary tree: `root` is the graph directory (not created: the save creates it), `outside`
// a sibling holding files the services must never touch.
struct Tree {
  Tree() {
    char t[] = "/tmp/toro_graph_directory_XXXXXX";
    base = mkdtemp(t);
    root = base / "graphs";
    outside = base / "outside";
    fs::create_directories(outside);
  }
  ~Tree() { fs::remove_all(base); }
  fs::path base, root, outside;
};

// A pipeline holding a small graph (a drifting square, one loop closure).
struct Mapped {
  Mapped() : pipeline(toro_ros::testing::baseTestOptions()) {
    const auto s = toro_ros::testing::makeDriftingSquare(1);
    for (const auto& m : s.odometry) pipeline.handleOdometry(m);
    pipeline.handleLoopClosure(toro_ros::testing::trueLoopClosure(s, 0, s.odometry.size() - 1));
    while (pipeline.runScheduledOptimization() || pipeline.hasScheduledWork()) {
    }
  }
  Pipeline pipeline;
};

const std::string kNotes = "my notes: do not lose\nsecond line\n";

}  // namespace

TEST(GraphDirectory, DefaultIsTheToroRosFolderOfTheRosHome) {
  const char* ros_home = std::getenv("ROS_HOME");
  const std::string saved = ros_home ? ros_home : "";
  ::setenv("ROS_HOME", "/data/ros_home", 1);
  EXPECT_EQ(defaultGraphDirectory(), "/data/ros_home/toro_ros");
  EXPECT_EQ(GraphDirectory().path(), "/data/ros_home/toro_ros");
  ::unsetenv("ROS_HOME");
  EXPECT_EQ(defaultGraphDirectory(), std::string(std::getenv("HOME")) + "/.ros/toro_ros");
  if (ros_home) ::setenv("ROS_HOME", saved.c_str(), 1);
  EXPECT_EQ(GraphDirectory("/a/b/../c/").path(), "/a/c");
}

TEST(GraphDirectory, RelativeSaveAndLoadRoundTripInsideAndTheDirectoryIsCreatedOnDemand) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  EXPECT_FALSE(fs::exists(t.root));  // nothing touched until a file is to go in
  const ConfinedFile save = dir.forSave("map.g2o");
  ASSERT_TRUE(save.file) << save.error;
  EXPECT_TRUE(save.file->confined());
  EXPECT_EQ(save.file->displayPath(), (t.root / "map.g2o").string());
  ASSERT_EQ(m.pipeline.saveGraph(*save.file), "");
  EXPECT_EQ(listing(t.root), (std::set<std::string>{"map.g2o", "map.g2o.stamps"}));
  // Saving again replaces our own pair (a graph and our sidecar).
  const ConfinedFile again = dir.forSave("map.g2o");
  ASSERT_TRUE(again.file) << again.error;
  ASSERT_EQ(m.pipeline.saveGraph(*again.file), "");

  const ConfinedFile load = dir.forLoad("map.g2o");
  ASSERT_TRUE(load.file) << load.error;
  Pipeline q(toro_ros::testing::baseTestOptions());
  ASSERT_EQ(q.loadGraph(*load.file), "");
  EXPECT_EQ(q.graph().numNodes(), m.pipeline.graph().numNodes());
  EXPECT_EQ(q.graph().numConstraints(), m.pipeline.graph().numConstraints());
  EXPECT_EQ(q.keyframes().newest().stamp, m.pipeline.keyframes().newest().stamp);

  // An absolute path inside, a subdirectory that exists, the TORO format by extension.
  fs::create_directories(t.root / "runs");
  const ConfinedFile toro = dir.forSave((t.root / "runs" / "a.graph").string());
  ASSERT_TRUE(toro.file) << toro.error;
  ASSERT_EQ(m.pipeline.saveGraph(*toro.file), "");
  EXPECT_EQ(slurp(t.root / "runs" / "a.graph").rfind("VERTEX3 ", 0), 0u);
  // A subdirectory that does not exist is not created.
  const ConfinedFile missing = dir.forSave("nope/a.g2o");
  EXPECT_FALSE(missing.file);
  EXPECT_TRUE(contains(missing.error, "no directory nope")) << missing.error;
  EXPECT_FALSE(fs::exists(t.root / "nope"));
}

TEST(GraphDirectory, AbsolutePathOutsideAndDotDotAreRefusedAndNothingIsWritten) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root / "sub");
  for (const std::string& name :
       {(t.outside / "x.g2o").string(), std::string("../outside/x.g2o"), std::string("../x.g2o"),
        std::string("sub/../../x.g2o"), std::string("/etc/x.g2o")}) {
    const ConfinedFile save = dir.forSave(name);
    EXPECT_FALSE(save.file) << name;
    EXPECT_TRUE(contains(save.error, "is outside graph_directory " + t.root.string())) << save.error;
    EXPECT_TRUE(contains(save.error, "refused")) << save.error;
    const ConfinedFile load = dir.forLoad(name);
    EXPECT_FALSE(load.file) << name;
    EXPECT_TRUE(contains(load.error, "outside graph_directory")) << load.error;
  }
  EXPECT_TRUE(listing(t.outside).empty());
  EXPECT_EQ(listing(t.base), (std::set<std::string>{"graphs", "outside"}));
  // ".." that stays inside is only a name.
  const ConfinedFile inside = dir.forSave("sub/../y.g2o");
  ASSERT_TRUE(inside.file) << inside.error;
  EXPECT_EQ(inside.file->displayPath(), (t.root / "y.g2o").string());
}

TEST(GraphDirectory, SymbolicLinksLeadingOutAreRefusedForFilesAndDirectories) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root);
  put(t.outside / "target.g2o", kNotes);
  fs::create_symlink(t.outside / "target.g2o", t.root / "file_link.g2o");
  fs::create_symlink(t.outside, t.root / "dir_link");
  for (const char* name : {"file_link.g2o", "dir_link/target.g2o", "dir_link/new.g2o"}) {
    const ConfinedFile save = dir.forSave(name);
    EXPECT_FALSE(save.file) << name;
    EXPECT_TRUE(contains(save.error, "leads outside graph_directory")) << save.error;
    EXPECT_TRUE(contains(save.error, "symbolic link")) << save.error;
    EXPECT_FALSE(contains(save.error, t.outside.string()))
        << "where the link leads is not told: " << save.error;
    const ConfinedFile load = dir.forLoad(name);
    EXPECT_FALSE(load.file) << name;
    EXPECT_TRUE(contains(load.error, "leads outside graph_directory")) << load.error;
  }
  // A link to nothing (yet) outside, directly or on the way: where it would lead is not known.
  fs::create_symlink(t.outside / "new.g2o", t.root / "dangling.g2o");
  fs::create_symlink(t.outside / "new_dir", t.root / "dangling_dir");
  for (const char* name : {"dangling.g2o", "dangling_dir/x.g2o"}) {
    for (const ConfinedFile& f : {dir.forSave(name), dir.forLoad(name)}) {
      EXPECT_FALSE(f.file) << name;
      EXPECT_TRUE(contains(f.error, "symbolic link to a missing file or directory")) << f.error;
    }
  }
  EXPECT_EQ(slurp(t.outside / "target.g2o"), kNotes);
  EXPECT_EQ(listing(t.outside), (std::set<std::string>{"target.g2o"}));
}

TEST(GraphDirectory, ALinkInsideLeadingInsideIsFollowedAndKept) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  ASSERT_EQ(m.pipeline.saveGraph(*dir.forSave("run1.g2o").file), "");
  fs::create_symlink("run1.g2o", t.root / "latest.g2o");
  const ConfinedFile save = dir.forSave("latest.g2o");
  ASSERT_TRUE(save.file) << save.error;
  EXPECT_EQ(save.file->displayPath(), (t.root / "run1.g2o").string());
  ASSERT_EQ(m.pipeline.saveGraph(*save.file), "");
  EXPECT_TRUE(fs::is_symlink(t.root / "latest.g2o"));
  // A link inside to a file without a graph extension is refused.
  put(t.root / "notes.txt", kNotes);
  fs::create_symlink("notes.txt", t.root / "notes.g2o");
  const ConfinedFile notes = dir.forSave("notes.g2o");
  EXPECT_FALSE(notes.file);
  EXPECT_TRUE(contains(notes.error, "without a graph extension")) << notes.error;
  EXPECT_EQ(slurp(t.root / "notes.txt"), kNotes);
}

TEST(GraphDirectory, ASaveNeverReplacesAFileThatIsNotAGraphOrItsSidecarWithOneThatIsNotOurs) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root);
  put(t.root / "notes.g2o", kNotes);
  const ConfinedFile notes = dir.forSave("notes.g2o");
  EXPECT_FALSE(notes.file);
  EXPECT_TRUE(contains(notes.error, "refusing to replace 'notes.g2o'")) << notes.error;
  // (Each line starts with a word, which the reader takes for another tool's tag: no graph line.)
  EXPECT_TRUE(contains(notes.error, "notes.g2o is not a graph file")) << notes.error;
  EXPECT_TRUE(contains(notes.error, "no VERTEX or EDGE line")) << notes.error;
  EXPECT_FALSE(contains(notes.error, "my notes")) << notes.error;
  EXPECT_EQ(slurp(t.root / "notes.g2o"), kNotes);
  EXPECT_FALSE(fs::exists(t.root / "notes.g2o.stamps"));
  // Nor one the reader refuses; the message gives its line, not its content.
  const std::string script = "#!/bin/sh\n./install.sh --force\n";
  put(t.root / "script.g2o", script);
  const ConfinedFile sh = dir.forSave("script.g2o");
  EXPECT_FALSE(sh.file);
  EXPECT_TRUE(contains(sh.error, "script.g2o:2: the line does not start with a tag")) << sh.error;
  EXPECT_FALSE(contains(sh.error, "install")) << sh.error;
  EXPECT_EQ(slurp(t.root / "script.g2o"), script);

  // A graph whose sidecar is not ours: neither is replaced.
  ASSERT_EQ(m.pipeline.saveGraph((t.root / "map.g2o").string()), "");
  const std::string graph_before = slurp(t.root / "map.g2o");
  for (const std::string& sidecar : {kNotes, std::string("# only a comment\n"), std::string("KEYFRAME 1 2\n"),
                                     std::string("# toro_ros keyframe sidecar v1\nnotes\n")}) {
    put(t.root / "map.g2o.stamps", sidecar);
    const ConfinedFile save = dir.forSave("map.g2o");
    EXPECT_FALSE(save.file) << sidecar;
    EXPECT_TRUE(contains(save.error, "map.g2o.stamps is not a keyframe sidecar")) << save.error;
    EXPECT_FALSE(contains(save.error, "notes")) << save.error;
    EXPECT_EQ(slurp(t.root / "map.g2o.stamps"), sidecar);
    EXPECT_EQ(slurp(t.root / "map.g2o"), graph_before);
  }
  // Nor a directory, a FIFO or a link at the sidecar's name.
  fs::remove(t.root / "map.g2o.stamps");
  ASSERT_EQ(::mkfifo((t.root / "map.g2o.stamps").c_str(), 0600), 0);
  EXPECT_TRUE(contains(dir.forSave("map.g2o").error, "is not a regular file"));
  fs::remove(t.root / "map.g2o.stamps");
  fs::create_symlink(t.outside / "x", t.root / "map.g2o.stamps");
  EXPECT_TRUE(contains(dir.forSave("map.g2o").error, "is a symbolic link"));
  EXPECT_TRUE(listing(t.outside).empty());
  // Names without a graph extension are refused outright (also for a load).
  for (const char* name : {"notes.txt", "map.g2o.stamps", ".g2o", "map", "dir/"}) {
    EXPECT_TRUE(contains(dir.forSave(name).error, "is not a graph file name")) << name;
    EXPECT_TRUE(contains(dir.forLoad(name).error, "is not a graph file name")) << name;
  }
}

TEST(GraphDirectory, LoadOfEtcPasswdIsRefusedAndNoMessageHoldsItsContent) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root);
  const std::string passwd = slurp("/etc/passwd");
  ASSERT_FALSE(passwd.empty());
  // Pieces of the file no message may hold: every field of its first line.
  std::vector<std::string> pieces;
  const std::string first_line = passwd.substr(0, passwd.find('\n'));
  for (std::size_t start = 0; start <= first_line.size();) {
    const std::size_t end = std::min(first_line.find(':', start), first_line.size());
    if (end - start >= 2) pieces.push_back(first_line.substr(start, end - start));
    start = end + 1;
  }
  ASSERT_FALSE(pieces.empty());
  const auto expectNoContent = [&](const std::string& message) {
    for (const std::string& piece : pieces) EXPECT_FALSE(contains(message, piece)) << message;
  };

  const ConfinedFile direct = dir.forLoad("/etc/passwd");
  EXPECT_FALSE(direct.file);
  expectNoContent(direct.error);
  const ConfinedFile up = dir.forLoad("../../../../../../../../etc/passwd.g2o");
  EXPECT_FALSE(up.file);
  EXPECT_TRUE(contains(up.error, "outside graph_directory")) << up.error;
  fs::create_symlink("/etc/passwd", t.root / "users.g2o");
  const ConfinedFile link = dir.forLoad("users.g2o");
  EXPECT_FALSE(link.file);
  expectNoContent(link.error);
  // Its content inside the directory (copied, or reached by some other way): the reader's message
  // gives the file and line, not the line.
  put(t.root / "copy.g2o", passwd);
  const ConfinedFile copy = dir.forLoad("copy.g2o");
  ASSERT_TRUE(copy.file) << copy.error;
  const std::string error = m.pipeline.loadGraph(*copy.file);
  EXPECT_TRUE(contains(error, (t.root / "copy.g2o").string() + ":1: the line does not start with a tag"))
      << error;
  expectNoContent(error);
  // The operator's own tools keep the excerpt (toro_optimize, toro_offline's load_path).
  EXPECT_TRUE(contains(m.pipeline.loadGraph((t.root / "copy.g2o").string()), "'" + pieces[0]));
}

TEST(GraphDirectory, ServiceLoadErrorsOfGraphsAndSidecarsInsideQuoteNoContent) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root);
  put(t.root / "bad.g2o", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 secret-value\n");
  std::string error = m.pipeline.loadGraph(*dir.forLoad("bad.g2o").file);
  EXPECT_TRUE(contains(error, "bad.g2o:2: EDGE_SE3:QUAT: expected 30 fields, got 3")) << error;
  put(t.root / "bad.g2o", "VERTEX_SE3:QUAT 0 0 0 secret-value 0 0 0 1\n");
  error = m.pipeline.loadGraph(*dir.forLoad("bad.g2o").file);
  EXPECT_TRUE(contains(error, "bad.g2o:1: VERTEX_SE3:QUAT field 4 (z): the value is not a number")) << error;
  EXPECT_FALSE(contains(error, "secret")) << error;
  put(t.root / "bad.g2o", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n\x1b]0;secret\x07\n");
  error = m.pipeline.loadGraph(*dir.forLoad("bad.g2o").file);
  EXPECT_TRUE(contains(error, "bad.g2o:2: binary data (a control character at column 1)")) << error;

  ASSERT_EQ(m.pipeline.saveGraph(*dir.forSave("good.g2o").file), "");
  std::string sidecar = slurp(t.root / "good.g2o.stamps");
  put(t.root / "good.g2o.stamps", sidecar + "SECRET_TAG 1 2 3\n");
  error = m.pipeline.loadGraph(*dir.forLoad("good.g2o").file);
  EXPECT_TRUE(contains(error, "good.g2o.stamps:")) << error;
  EXPECT_TRUE(contains(error, "unknown tag (expected KEYFRAME, LOOP_CLOSURE or REJECTED)")) << error;
  EXPECT_FALSE(contains(error, "SECRET")) << error;
  // The operator's path keeps a sanitised excerpt.
  EXPECT_TRUE(contains(m.pipeline.loadGraph((t.root / "good.g2o").string()), "'SECRET_TAG'"));
}

TEST(GraphDirectory, OddNamesWorkAndEmptyOrControlCharacterNamesAreRefused) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  for (const char* name :
       {"map with spaces.g2o",
        "\xc3\xbcn\xc3\xaf"
        "c\xc3\xb8"
        "de.g2o",
        "-dash.toro", "quote'\"$(touch x);`x`*?.g2o", "UPPER.G2O", "a..b.g2o", "..hidden.g2o"}) {
    const ConfinedFile save = dir.forSave(name);
    ASSERT_TRUE(save.file) << name << ": " << save.error;
    ASSERT_EQ(m.pipeline.saveGraph(*save.file), "") << name;
    EXPECT_TRUE(fs::is_regular_file(t.root / name)) << name;
    const ConfinedFile load = dir.forLoad(name);
    ASSERT_TRUE(load.file) << load.error;
    Pipeline q(toro_ros::testing::baseTestOptions());
    EXPECT_EQ(q.loadGraph(*load.file), "") << name;
    EXPECT_EQ(q.graph().numNodes(), m.pipeline.graph().numNodes()) << name;
  }
  EXPECT_FALSE(fs::exists(t.root / "x"));
  const ConfinedFile empty = dir.forSave("");
  EXPECT_FALSE(empty.file);
  EXPECT_TRUE(contains(empty.error, "no file name given")) << empty.error;
  EXPECT_TRUE(contains(empty.error, t.root.string())) << empty.error;
  EXPECT_FALSE(dir.forLoad("").file);
  const ConfinedFile control = dir.forSave("a\nb.g2o");
  EXPECT_FALSE(control.file);
  EXPECT_TRUE(contains(control.error, "control character")) << control.error;
  EXPECT_FALSE(contains(control.error, "\n")) << control.error;
  EXPECT_FALSE(fs::exists(t.root / "a\nb.g2o"));
}

TEST(GraphDirectory, FifoAndDirectoryNamedLikeGraphsNeitherHangNorAreReplaced) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root / "d.g2o");
  ASSERT_EQ(::mkfifo((t.root / "f.g2o").c_str(), 0600), 0);
  EXPECT_TRUE(contains(m.pipeline.loadGraph(*dir.forLoad("f.g2o").file), "is not a regular file"));
  EXPECT_TRUE(contains(m.pipeline.loadGraph(*dir.forLoad("d.g2o").file), "is a directory"));
  EXPECT_TRUE(contains(dir.forSave("f.g2o").error, "is not a regular file"));
  EXPECT_TRUE(contains(dir.forSave("d.g2o").error, "is not a regular file"));
}

TEST(GraphDirectory, WhatWasCheckedIsWhatIsWrittenEvenIfADirectoryIsSwappedForALinkAfterwards) {
  Tree t;
  Mapped m;
  const GraphDirectory dir(t.root.string());
  fs::create_directories(t.root / "sub");
  const ConfinedFile save = dir.forSave("sub/x.g2o");
  ASSERT_TRUE(save.file) << save.error;
  // Between the check and the write, sub is moved away and replaced by a link leading out.
  fs::rename(t.root / "sub", t.root / "moved");
  fs::create_symlink(t.outside, t.root / "sub");
  ASSERT_EQ(m.pipeline.saveGraph(*save.file), "");
  EXPECT_TRUE(listing(t.outside).empty());
  EXPECT_EQ(listing(t.root / "moved"), (std::set<std::string>{"x.g2o", "x.g2o.stamps"}));

  // A file checked for a load and then replaced by a link is not followed.
  ASSERT_EQ(m.pipeline.saveGraph(*dir.forSave("y.g2o").file), "");
  const ConfinedFile load = dir.forLoad("y.g2o");
  ASSERT_TRUE(load.file);
  fs::remove(t.root / "y.g2o");
  fs::create_symlink("/etc/passwd", t.root / "y.g2o");
  const std::string error = m.pipeline.loadGraph(*load.file);
  EXPECT_TRUE(contains(error, "is a symbolic link")) << error;
}

TEST(GraphDirectory, OperatorPathsResolveAgainstTheDirectoryAndAreReported) {
  Tree t;
  const GraphDirectory dir(t.root.string());
  std::string load = "maps/run.g2o", autosave = (t.outside / "auto.g2o").string();
  const std::string line = dir.resolveOperatorPaths(&load, &autosave);
  EXPECT_EQ(load, (t.root / "maps" / "run.g2o").string());
  EXPECT_EQ(autosave, (t.outside / "auto.g2o").string());  // trusted: may lie outside
  EXPECT_TRUE(fs::is_directory(t.root));                   // created for the relative path
  EXPECT_TRUE(contains(line, "graph_directory " + t.root.string())) << line;
  EXPECT_TRUE(contains(line, "load_path " + load)) << line;
  EXPECT_TRUE(contains(line, "autosave_path " + autosave)) << line;
  // Links are resolved: the autosave replaces the file a link leads to, not the link (also when
  // that file does not exist yet, through a relative link and a linked directory).
  fs::create_symlink(t.outside / "real.g2o", t.base / "link.g2o");
  fs::create_symlink("outside", t.base / "dir_link");
  fs::create_symlink("../link.g2o", t.outside / "relative_link.g2o");
  std::string none, linked = (t.base / "link.g2o").string();
  EXPECT_TRUE(contains(dir.resolveOperatorPaths(&none, &linked), "load_path off"));
  EXPECT_EQ(none, "");
  EXPECT_EQ(linked, (t.outside / "real.g2o").string());
  put(t.outside / "real.g2o", "");
  std::string twice = (t.base / "dir_link" / "relative_link.g2o").string();
  dir.resolveOperatorPaths(&none, &twice);
  EXPECT_EQ(twice, (t.outside / "real.g2o").string());
}

TEST(GraphDirectory, StartUpRefusesAnAutosavePathHoldingSomethingElse) {
  Tree t;
  put(t.outside / "notes.g2o", kNotes);
  PipelineOptions options = toro_ros::testing::baseTestOptions();
  options.persistence.autosave_path = (t.outside / "notes.g2o").string();
  Pipeline p(options);
  try {
    loadOnStart(p, "");
    FAIL() << "an autosave over a text file was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_TRUE(contains(e.what(), "autosave_path: refusing to replace it")) << e.what();
    EXPECT_TRUE(contains(e.what(), "notes.g2o is not a graph file")) << e.what();
  }
  EXPECT_EQ(slurp(t.outside / "notes.g2o"), kNotes);
  // A graph there (a previous autosave) is fine, and so is nothing.
  options.persistence.autosave_path = (t.outside / "new.g2o").string();
  Pipeline q(options);
  EXPECT_EQ(loadOnStart(q, ""), "");
  // A load_path that is not a graph stops the start; the node (whose log anyone on the network
  // reads on /rosout) asks for messages without the file's content, toro_offline keeps them.
  put(t.outside / "script.g2o", "./install.sh --force\n");
  for (const bool quote : {true, false}) {
    try {
      loadOnStart(q, (t.outside / "script.g2o").string(), quote);
      FAIL() << "a load_path that is not a graph was accepted";
    } catch (const std::runtime_error& e) {
      EXPECT_TRUE(contains(e.what(), "load_path: " + (t.outside / "script.g2o").string() + ":1: "))
          << e.what();
      EXPECT_EQ(contains(e.what(), "install"), quote) << e.what();
    }
  }
  EXPECT_TRUE(q.graph().empty());
}
