// binary16 <-> float32: HalfToFloat is exact for all 65536 patterns, FloatToHalf rounds to nearest even.
#include "engine/nn/half.h"

#include <bit>
#include <cmath>
#include <limits>

#include "gtest/gtest.h"

namespace dance::engine {
namespace {

// The value of a binary16 pattern straight from the definition, as an independent reference.
double ReferenceHalf(uint16_t h) {
  const int sign = h >> 15, exponent = (h >> 10) & 0x1F, mantissa = h & 0x3FF;
  const double magnitude = exponent == 0 ? std::ldexp(mantissa, -24) : std::ldexp(1024 + mantissa, exponent - 25);
  return sign != 0 ? -magnitude : magnitude;
}

TEST(Half, KnownValues) {
  EXPECT_EQ(HalfToFloat(0x3C00), 1.0f);
  EXPECT_EQ(HalfToFloat(0xC000), -2.0f);
  EXPECT_EQ(HalfToFloat(0x7BFF), 65504.0f);
  EXPECT_EQ(HalfToFloat(0x0400), std::ldexp(1.0f, -14));  // smallest normal
  EXPECT_EQ(HalfToFloat(0x03FF), std::ldexp(1023.0f, -24));  // largest subnormal
  EXPECT_EQ(HalfToFloat(0x0001), std::ldexp(1.0f, -24));  // smallest subnormal
  EXPECT_EQ(std::bit_cast<uint32_t>(HalfToFloat(0x0000)), 0x00000000u);
  EXPECT_EQ(std::bit_cast<uint32_t>(HalfToFloat(0x8000)), 0x80000000u);  // -0.0
  EXPECT_EQ(HalfToFloat(0x7C00), std::numeric_limits<float>::infinity());
  EXPECT_EQ(HalfToFloat(0xFC00), -std::numeric_limits<float>::infinity());
  EXPECT_TRUE(std::isnan(HalfToFloat(0x7E00)));
  EXPECT_TRUE(std::isnan(HalfToFloat(0xFC01)));
  EXPECT_EQ(FloatToHalf(0.1f), 0x2E66);  // numpy: np.float16(0.1).view(np.uint16)
}

TEST(Half, EveryFinitePatternIsExactAndRoundTrips) {
  for (uint32_t h = 0; h <= 0xFFFF; ++h) {
    const uint16_t bits = static_cast<uint16_t>(h);
    if (((bits >> 10) & 0x1F) == 0x1F) continue;  // Inf / NaN: KnownValues
    const float f = HalfToFloat(bits);
    ASSERT_EQ(static_cast<double>(f), ReferenceHalf(bits)) << std::hex << h;
    ASSERT_EQ(std::signbit(f), (bits & 0x8000) != 0) << std::hex << h;
    ASSERT_EQ(FloatToHalf(f), bits) << std::hex << h;
  }
}

TEST(Half, RoundsToNearestTiesToEven) {
  const float ulp1 = std::ldexp(1.0f, -10);  // binary16 spacing in [1, 2)
  EXPECT_EQ(FloatToHalf(1.0f + ulp1 / 2), 0x3C00);      // tie, 0x3C00 is even
  EXPECT_EQ(FloatToHalf(1.0f + 3 * ulp1 / 2), 0x3C02);  // tie, rounds up to even
  EXPECT_EQ(FloatToHalf(std::nextafter(1.0f + ulp1 / 2, 2.0f)), 0x3C01);
  EXPECT_EQ(FloatToHalf(-(1.0f + ulp1 / 2)), 0xBC00);
  // Subnormal range: steps of 2^-24.
  EXPECT_EQ(FloatToHalf(std::ldexp(1.0f, -25)), 0x0000);  // tie between 0 and 2^-24
  EXPECT_EQ(FloatToHalf(std::nextafter(std::ldexp(1.0f, -25), 1.0f)), 0x0001);
  EXPECT_EQ(FloatToHalf(std::ldexp(3.0f, -25)), 0x0002);  // tie, rounds up to even
  EXPECT_EQ(FloatToHalf(std::ldexp(2047.0f, -25)), 0x0400);  // the largest subnormal's tie: the smallest normal
  EXPECT_EQ(FloatToHalf(-std::ldexp(1.0f, -30)), 0x8000);  // underflow keeps the sign
}

TEST(Half, OverflowAndSpecials) {
  EXPECT_EQ(FloatToHalf(65519.0f), 0x7BFF);
  EXPECT_EQ(FloatToHalf(65520.0f), 0x7C00);  // tie between 65504 and 2^16: even is Inf
  EXPECT_EQ(FloatToHalf(-1e6f), 0xFC00);
  EXPECT_EQ(FloatToHalf(std::numeric_limits<float>::infinity()), 0x7C00);
  EXPECT_EQ(FloatToHalf(std::numeric_limits<float>::quiet_NaN()) & 0x7E00, 0x7E00);
}

}  // namespace
}  // namespace dance::engine
