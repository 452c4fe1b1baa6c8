// SequenceLanes: a session's sequence-model state, one "lane" (SequenceState: KV caches, Mamba states, step,
// style factors) per logit source that guidance combines, and the codes the next step reads.
//
// The lanes (docs/model.md section 6): conditional (the session's style, the song's music); unconditional
// (style "none", the song's music; style guidance); music-mean conditional and music-mean unconditional
// (the same two reading the model's music mean; music guidance). Only the conditional lane always steps.
// A lane switched on mid-stream starts from the history closest to it (its missed steps cannot be
// replayed). The two music-mean lanes are empty until first needed (most sessions never use them).
//
// Usage (inside StepBatch):
//   lanes.Prepare(guidance_on, music_guidance_on);
//   lanes.AddInputs(music, pre, &inputs);           // cond, [uncond], [music cond, [music uncond]]
//   model.sequence().Step(inputs, workspace);
//   StepLogits logits = lanes.Logits(workspace, first_input);
//   lanes.SetCodes(u, l);
//
// State: every field that changes lives in LaneState (snapshot = copy). Not thread-safe.
#ifndef DANCE_ENGINE_RUNTIME_INTERNAL_SEQUENCE_LANES_H_
#define DANCE_ENGINE_RUNTIME_INTERNAL_SEQUENCE_LANES_H_

#include <cstdint>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "engine/model/sequence_model.h"
#include "engine/model/sequence_state.h"
#include "engine/runtime/model.h"
#include "engine/runtime/style_mix.h"

namespace dance::engine {

// One lane's logits of a step (upper, lower; K each); null when the lane did not step.
struct LaneLogits {
  const float* u = nullptr;
  const float* l = nullptr;
};

// A step's logits from every lane.
struct StepLogits {
  LaneLogits cond, uncond, music_cond, music_uncond;
};

struct LaneState {
  SequenceState cond;
  SequenceState uncond;        // style "none" (it never takes a style), for style guidance
  SequenceState music_cond;    // reading the music mean; empty until first needed
  SequenceState music_uncond;
  bool uncond_live = false, music_cond_live = false, music_uncond_live = false;  // stepped last step
  int upper_code = 0, lower_code = 0;  // the codes the next step reads (BOS = K before the first step)
};

class SequenceLanes {
 public:
  explicit SequenceLanes(const Model& model);

  // The style's factors into the conditional lanes (the music-mean one if it exists).
  void SetStyle(const ResolvedStyle& style);
  // Before a step: starts each lane this step needs that did not step last time, then records which step.
  void Prepare(bool guidance, bool music_guidance);
  // Appends this step's lane inputs in the order above (Prepare first). `music` is the song's token (4F);
  // the music-mean lanes read MeanMusicToken(music), valid until the next AddInputs.
  void AddInputs(const float* music, const float* pre, std::vector<LaneInput>* inputs);
  // The logits of this session's lanes whose inputs start at column `first` of the workspace.
  StepLogits Logits(const Workspace& workspace, int first) const;
  void SetCodes(int upper, int lower) {
    state_.upper_code = upper;
    state_.lower_code = lower;
  }

  int64_t step() const { return state_.cond.step; }
  std::pair<int, int> codes() const { return {state_.upper_code, state_.lower_code}; }
  const LaneState& state() const { return state_; }

  // InvalidArgument ("snapshot is from a different model") unless every lane has this model's shapes.
  absl::Status Validate(const LaneState& state) const;
  // `state` must have passed Validate.
  void Restore(const LaneState& state);
  void Reset(const ResolvedStyle& style);
  // Bytes of the lanes in use (the unconditional one only with `guidance`).
  int64_t Bytes(bool guidance) const;

 private:
  // The token the music-mean lanes read: the model's music mean, or with Model::music_guidance_features the
  // song's token with those columns the mean.
  const float* MeanMusicToken(const float* music);
  LaneState Fresh() const;

  const Model* model_;
  LaneState state_;
  std::vector<float> mean_token_;  // (4F) scratch
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_RUNTIME_INTERNAL_SEQUENCE_LANES_H_
