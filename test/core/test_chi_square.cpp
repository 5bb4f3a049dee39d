// Chi-square CDF and quantile against published table values (e.g. NIST/SEMATECH e-Handbook,
// "Critical values of the chi-square distribution", 3 decimals) and closed forms.
#include <cmath>
#include <stdexcept>

#include <gtest/gtest.h>

#include "toro_ros/core/chi_square.h"

namespace {

TEST(ChiSquare, QuantileMatchesTableValues) {
  struct Row {
    double p, dof, x;
  };
  for (const Row& r : {Row{0.95, 1, 3.841}, Row{0.99, 1, 6.635}, Row{0.95, 3, 7.815}, Row{0.99, 3, 11.345},
                       Row{0.90, 6, 10.645}, Row{0.95, 6, 12.592}, Row{0.99, 6, 16.812},
                       Row{0.999, 6, 22.458}, Row{0.05, 6, 1.635}, Row{0.99, 100, 135.807}})
    EXPECT_NEAR(toro::chiSquareQuantile(r.p, r.dof), r.x, 1.5e-3) << "p " << r.p << " dof " << r.dof;
}

TEST(ChiSquare, CdfMatchesClosedFormForEvenDof) {
  // dof 6: P(X <= x) = 1 - e^(-x/2) (1 + x/2 + (x/2)^2 / 2).
  for (double x : {0.1, 1.0, 5.0, 12.592, 40.0, 200.0}) {
    const double h = x / 2;
    EXPECT_NEAR(toro::chiSquareCdf(x, 6), 1 - std::exp(-h) * (1 + h + h * h / 2), 1e-13) << x;
  }
  EXPECT_EQ(toro::chiSquareCdf(0, 6), 0.0);
}

TEST(ChiSquare, QuantileInvertsCdf) {
  for (double p : {1e-6, 0.3, 0.5, 0.9999, 1 - 1e-9})
    EXPECT_NEAR(toro::chiSquareCdf(toro::chiSquareQuantile(p, 6), 6), p, 1e-10) << p;
  EXPECT_EQ(toro::chiSquareQuantile(0, 6), 0.0);
}

// Answers are kept for repeated questions: whatever was asked in between (more pairs than are
// kept, and the same probability at other dof), each answer is the one the CDF gives.
TEST(ChiSquare, RepeatedQuantilesAreTheSameAnswers) {
  for (int round = 0; round < 3; ++round)
    for (double p : {0.2, 0.99, 0.999})
      for (double dof : {3.0, 6.0, 1.0, 12.0}) {
        const double x = toro::chiSquareQuantile(p, dof);
        EXPECT_NEAR(toro::chiSquareCdf(x, dof), p, 1e-10) << "p " << p << " dof " << dof;
        EXPECT_EQ(toro::chiSquareQuantile(p, dof), x);
      }
}

TEST(ChiSquare, RefusesInvalidArguments) {
  EXPECT_THROW(toro::chiSquareQuantile(1.0, 6), std::invalid_argument);
  EXPECT_THROW(toro::chiSquareQuantile(-0.1, 6), std::invalid_argument);
  EXPECT_THROW(toro::chiSquareQuantile(std::nan(""), 6), std::invalid_argument);
  EXPECT_THROW(toro::chiSquareQuantile(0.5, 0), std::invalid_argument);
  EXPECT_THROW(toro::regularizedGammaP(-1, 1), std::invalid_argument);
}

}  // namespace
