#include "engine/nn/half.h"

#include <bit>
#include <cmath>

namespace dance::engine {
namespace {

// binary16: 1 sign bit, 5 exponent bits (bias 15), 10 mantissa bits. float32: 1, 8 (bias 127), 23.
constexpr int kExponentShift = 127 - 15;
constexpr float kTwoPow24 = 16777216.0f;  // 2^24: one binary16 subnormal step is 2^-24

}  // namespace

float HalfToFloat(uint16_t h) {
  const uint32_t sign = static_cast<uint32_t>(h & 0x8000u) << 16;
  const uint32_t exponent = (h >> 10) & 0x1Fu;
  const uint32_t mantissa = h & 0x3FFu;
  if (exponent == 0) {
    // Zero and subnormals: mantissa * 2^-24, exact (an integer below 2^10 times a power of two).
    const float magnitude = static_cast<float>(mantissa) / kTwoPow24;
    return sign != 0 ? -magnitude : magnitude;  // keeps -0.0
  }
  if (exponent == 0x1F) return std::bit_cast<float>(sign | 0x7F800000u | (mantissa << 13));  // Inf, NaN
  return std::bit_cast<float>(sign | ((exponent + kExponentShift) << 23) | (mantissa << 13));
}

uint16_t FloatToHalf(float x) {
  const uint32_t bits = std::bit_cast<uint32_t>(x);
  const uint16_t sign = static_cast<uint16_t>((bits >> 16) & 0x8000u);
  const uint32_t magnitude = bits & 0x7FFFFFFFu;
  if (magnitude > 0x7F800000u) return static_cast<uint16_t>(sign | 0x7E00u);   // NaN -> quiet NaN
  if (magnitude >= 0x477FF000u) return static_cast<uint16_t>(sign | 0x7C00u);  // >= 65520 (incl. Inf) rounds to Inf
  if (magnitude < 0x38800000u) {
    // Below 2^-14: a subnormal half (or zero). x * 2^24 is exact in float32; nearbyint rounds it to the
    // nearest integer, ties to even (the default rounding mode); 1024 is the smallest normal, 0x0400.
    const float steps = std::nearbyint(std::bit_cast<float>(magnitude) * kTwoPow24);
    return static_cast<uint16_t>(sign | static_cast<uint32_t>(steps));
  }
  // Normal: rebias the exponent, keep the top 10 mantissa bits, round the 13 dropped bits to nearest even.
  // A carry out of the mantissa correctly increments the exponent (up to 0x7BFF, kept finite above).
  uint32_t half = ((magnitude >> 23) - kExponentShift) << 10 | ((magnitude >> 13) & 0x3FFu);
  const uint32_t dropped = magnitude & 0x1FFFu;
  if (dropped > 0x1000u || (dropped == 0x1000u && (half & 1u) != 0)) ++half;
  return static_cast<uint16_t>(sign | half);
}

}  // namespace dance::engine
