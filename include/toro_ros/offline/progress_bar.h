// A one-line progress bar on stderr ("[#####     ]  52%  1234 msgs"), redrawn only when the
// percentage changes so that printing never dominates a fast run.
#pragma once

#include <cstddef>
#include <iosfwd>

namespace toro_ros {
namespace offline {

class ProgressBar {
 public:
  ProgressBar(std::ostream& out, bool enabled) : out_(out), enabled_(enabled) {}
  // fraction in [0, 1]; count is shown beside it.
  void update(double fraction, std::size_t count);
  void finish(std::size_t count);  // draws 100% and ends the line

 private:
  void draw(int percent, std::size_t count);
  std::ostream& out_;
  bool enabled_;
  int shown_ = -1;
};

}  // namespace offline
}  // namespace toro_ros
