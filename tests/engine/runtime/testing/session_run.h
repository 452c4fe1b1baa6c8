// Running a Session over audio in tests: the push / step / end / pop loop every engine suite needs.
#ifndef DANCE_TESTS_ENGINE_RUNTIME_TESTING_SESSION_RUN_H_
#define DANCE_TESTS_ENGINE_RUNTIME_TESTING_SESSION_RUN_H_

#include <algorithm>
#include <vector>

#include "engine/runtime/session.h"
#include "gtest/gtest.h"

namespace dance::engine::testing {

// Takes every step that is ready.
inline void DrainSteps(Session& s) {
  while (s.StepsReady() > 0) ASSERT_TRUE(s.Step().ok());
}

// Pushes `audio` in the given chunk sizes (cycled), stepping whenever possible, then ends the stream and
// returns every frame.
inline std::vector<PoseFrame> RunStream(Session& s, const std::vector<float>& audio,
                                        const std::vector<size_t>& chunks) {
  size_t pos = 0, i = 0;
  while (pos < audio.size()) {
    const size_t n = std::min(chunks[i++ % chunks.size()], audio.size() - pos);
    EXPECT_TRUE(s.PushAudio(absl::MakeConstSpan(audio.data() + pos, n)).ok());
    pos += n;
    DrainSteps(s);
  }
  s.EndOfAudio();
  DrainSteps(s);
  std::vector<PoseFrame> out;
  s.PopFrames(&out);
  return out;
}

}  // namespace dance::engine::testing

#endif  // DANCE_TESTS_ENGINE_RUNTIME_TESTING_SESSION_RUN_H_
