// IEEE 754 binary16 ("half", the `.dncw` dtype "f16") <-> float32, in portable integer arithmetic (no
// compiler `_Float16`, no F16C instructions), so every platform the engine builds on reads the same values.
//
// Every binary16 value (zero, subnormal, normal, Inf, NaN) is exactly representable in float32, so
// HalfToFloat is exact. FloatToHalf rounds to nearest, ties to even (numpy's `astype(np.float16)`), and
// gives +-Inf for |x| >= 65520 and a quiet NaN for NaN.
//
// Usage:
//   float x = dance::engine::HalfToFloat(0x3C00);   // 1.0f
//   uint16_t h = dance::engine::FloatToHalf(0.1f);   // 0x2E66
//
// Thread safety: pure functions, safe from any thread.
#ifndef DANCE_ENGINE_NN_HALF_H_
#define DANCE_ENGINE_NN_HALF_H_

#include <cstdint>

namespace dance::engine {

// The float32 value of the binary16 bit pattern `h` (exact; Inf and NaN map to Inf and NaN).
float HalfToFloat(uint16_t h);

// The binary16 bit pattern nearest to `x` (ties to even).
uint16_t FloatToHalf(float x);

// Largest finite binary16 value.
inline constexpr float kHalfMax = 65504.0f;

}  // namespace dance::engine

#endif  // DANCE_ENGINE_NN_HALF_H_
