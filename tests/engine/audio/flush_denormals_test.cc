#include "engine/audio/flush_denormals.h"

#include <cmath>
#include <limits>

#include "gtest/gtest.h"

namespace dance::engine::audio {
namespace {

// volatile: the products must be computed at run time, under the mode in force.
float Multiply(float a, float b) {
  volatile float x = a;
  volatile float y = b;
  return x * y;
}

#if defined(__x86_64__) || defined(__aarch64__)
TEST(ScopedFlushDenormalsTest, FlushesSubnormalResultsInsideTheScopeOnly) {
  const float tiny = std::numeric_limits<float>::min();  // smallest normal, 1.18e-38
  ASSERT_EQ(std::fpclassify(Multiply(tiny, 0.5f)), FP_SUBNORMAL);
  {
    ScopedFlushDenormals flush;
    EXPECT_EQ(Multiply(tiny, 0.5f), 0.0f);
    EXPECT_EQ(Multiply(tiny, 2.0f), 2.0f * tiny);  // normal results are untouched
    {
      ScopedFlushDenormals nested;
      EXPECT_EQ(Multiply(tiny, 0.25f), 0.0f);
    }
    EXPECT_EQ(Multiply(tiny, 0.5f), 0.0f);  // the inner scope restored the outer one's mode
  }
  EXPECT_EQ(std::fpclassify(Multiply(tiny, 0.5f)), FP_SUBNORMAL);  // the previous mode is back
}
#endif

}  // namespace
}  // namespace dance::engine::audio
