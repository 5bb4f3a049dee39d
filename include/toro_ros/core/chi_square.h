// Chi-square distribution functions for gating constraints by their residual (pure C++17).
#pragma once

namespace toro {

// Regularised lower incomplete gamma function P(a, x) = gamma(a, x) / Gamma(a), a > 0, x >= 0.
double regularizedGammaP(double a, double x);

// P(X <= x) for X ~ chi-square with `dof` degrees of freedom (dof > 0).
double chiSquareCdf(double x, double dof);

// The x with chiSquareCdf(x, dof) == probability, for 0 <= probability < 1 (0 gives 0).  Throws
// std::invalid_argument for a probability outside [0, 1) or dof <= 0.
double chiSquareQuantile(double probability, double dof);

}  // namespace toro
