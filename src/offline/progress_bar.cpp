#include "toro_ros/offline/progress_bar.h"

#include <algorithm>
#include <cmath>
#include <ostream>
#include <string>

namespace toro_ros {
namespace offline {

void ProgressBar::update(double fraction, std::size_t count) {
  if (!enabled_) return;
  const int percent = static_cast<int>(std::floor(100.0 * std::clamp(fraction, 0.0, 1.0)));
  if (percent != shown_) draw(percent, count);
}

void ProgressBar::finish(std::size_t count) {
  if (!enabled_) return;
  draw(100, count);
  out_ << '\n' << std::flush;
}

void ProgressBar::draw(int percent, std::size_t count) {
  constexpr int kWidth = 40;
  const int filled = percent * kWidth / 100;
  out_ << "\r[" << std::string(filled, '#') << std::string(kWidth - filled, ' ') << "] " << percent << "%  "
       << count << " msgs" << std::flush;
  shown_ = percent;
}

}  // namespace offline
}  // namespace toro_ros
