// TEST DOUBLE of the engine port (server/core/engine_port.h) for the core's unit tests: no model, a fixed
// step cost. A step is ready per 3200 input samples (24 kHz mono), costs `step_cost` of wall time in
// StepBatch (a sleep: the scheduler is busy, the CPU is not) and emits 4 frames.
#ifndef DANCE_TESTS_SERVER_TESTING_FAKE_ENGINE_H_
#define DANCE_TESTS_SERVER_TESTING_FAKE_ENGINE_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "absl/types/span.h"
#include "server/core/engine_port.h"

namespace dance::server::testing {

class FakeStream : public EngineStream {
 public:
  absl::Status PushAudio(absl::Span<const float> s) override {
    samples_ += static_cast<int64_t>(s.size());
    return absl::OkStatus();
  }
  absl::Status PushAudioInt16(absl::Span<const int16_t> s) override {
    samples_ += static_cast<int64_t>(s.size());
    return absl::OkStatus();
  }
  void EndOfAudio() override { samples_ = (samples_ + 3199) / 3200 * 3200; }
  int StepsReady() const override { return static_cast<int>(samples_ / 3200 - steps_); }
  void PopFrames(std::vector<FrameData>* out) override {
    for (; popped_ < steps_ * 4; ++popped_) {
      FrameData f{};
      f.index = popped_;
      out->push_back(f);
    }
  }
  absl::Status SetStyle(const StyleMix&) override { return absl::OkStatus(); }
  absl::Status SetSampling(const SamplingConfig&) override { return absl::OkStatus(); }
  void Step() { ++steps_; }

 private:
  int64_t samples_ = 0;
  int64_t steps_ = 0;
  int64_t popped_ = 0;
};

class FakeBackend : public EngineBackend {
 public:
  explicit FakeBackend(absl::Duration step_cost) : step_cost_(step_cost) {}
  const ModelDescription& Describe() const override { return model_; }
  absl::StatusOr<std::unique_ptr<EngineStream>> Open(const StreamConfig&) const override {
    return std::make_unique<FakeStream>();
  }
  absl::Status StepBatch(absl::Span<EngineStream* const> streams) const override {
    absl::SleepFor(step_cost_);
    for (EngineStream* s : streams) static_cast<FakeStream*>(s)->Step();
    return absl::OkStatus();
  }

 private:
  const absl::Duration step_cost_;
  ModelDescription model_;
};

}  // namespace dance::server::testing

#endif  // DANCE_TESTS_SERVER_TESTING_FAKE_ENGINE_H_
