#include "toro_ros/core/chi_square.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

namespace toro {

namespace {

// P(a, x) by its power series x^a e^-x / Gamma(a + 1) * sum_n x^n / ((a + 1) ... (a + n)); the
// terms shrink once n > x, so it converges for every x (used where x < a + 1).
double gammaPSeries(double a, double x) {
  double term = 1.0 / a, sum = term;
  for (int n = 1; n < 10000; ++n) {
    term *= x / (a + n);
    sum += term;
    if (std::abs(term) < std::abs(sum) * 1e-16) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Q(a, x) = 1 - P(a, x) by its continued fraction (modified Lentz evaluation), fast for x > a + 1
// where the series would need many terms.
double gammaQContinuedFraction(double a, double x) {
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

}  // namespace

double regularizedGammaP(double a, double x) {
  if (!(a > 0) || !(x >= 0)) throw std::invalid_argument("regularizedGammaP needs a > 0 and x >= 0");
  if (x == 0) return 0.0;
  if (std::isinf(x)) return 1.0;
  return x < a + 1.0 ? gammaPSeries(a, x) : 1.0 - gammaQContinuedFraction(a, x);
}

double chiSquareCdf(double x, double dof) {
  if (!(dof > 0)) throw std::invalid_argument("chi-square needs dof > 0");
  return x <= 0 ? 0.0 : regularizedGammaP(dof / 2.0, x / 2.0);
}

double chiSquareQuantile(double probability, double dof) {
  if (!(probability >= 0 && probability < 1))
    throw std::invalid_argument("chi-square quantile needs a probability in [0, 1)");
  if (!(dof > 0)) throw std::invalid_argument("chi-square needs dof > 0");
  if (probability == 0) return 0.0;
  // Callers ask for the same few quantiles again and again (the support thresholds are read for
  // every held loop closure at every release test: 6 % of a replay with 1000 wrong ones went into
  // this bisection), so the last few answers are kept, per thread.
  struct Answer {
    double probability, dof, quantile;
  };
  constexpr std::size_t kKept = 8;
  thread_local std::array<Answer, kKept> kept{};
  thread_local std::size_t kept_count = 0, next = 0;
  for (std::size_t k = 0; k < kept_count; ++k)
    if (kept[k].probability == probability && kept[k].dof == dof) return kept[k].quantile;
  // The CDF increases monotonically: bracket the quantile by doubling, then bisect.
  double lo = 0.0, hi = dof + 10.0;
  while (chiSquareCdf(hi, dof) < probability) {
    lo = hi;
    hi *= 2.0;
  }
  for (int i = 0; i < 200 && hi - lo > 1e-12 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (chiSquareCdf(mid, dof) < probability ? lo : hi) = mid;
  }
  const double quantile = 0.5 * (lo + hi);
  kept[next] = {probability, dof, quantile};
  next = (next + 1) % kKept;
  kept_count = std::min(kept_count + 1, kKept);
  return quantile;
}

}  // namespace toro
