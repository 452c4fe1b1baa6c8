// A whole dance from SGMD (docs/diffusion.md sections 5 and 6): the song's features cut into windows that
// agree on their overlaps, the controls turned into each window's known values and mask, every window
// sampled by DDIM, and the frames finished as the token model's are (bone lengths, foot lock where the lower
// body is free, joint rotations).
//
// Usage:
//   ASSIGN_OR_RETURN(FeatureFrames song, SongFeatures(audio));        // the engine's features, whole song
//   SgmdDanceOptions o;
//   o.seed = 1;
//   o.style = {{"waltz", 1.0f}};
//   o.controls = controls;                                            // control_spec.h
//   ASSIGN_OR_RETURN(SgmdDance d, GenerateSgmdDance(*model, song, o));
//
// Errors: InvalidArgument for bad options (steps outside 1..T, guidance not > 0, an overlap not below the
// window, bad style weights, bad controls), NotFound for an unknown style (naming the known ones),
// Cancelled when `progress` returns false. Thread safety: pure function of its arguments; one call uses one
// thread.
#ifndef DANCE_ENGINE_DIFFUSION_SGMD_DANCE_H_
#define DANCE_ENGINE_DIFFUSION_SGMD_DANCE_H_

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "engine/audio/audio_front_end.h"
#include "engine/audio/decoder.h"
#include "engine/diffusion/sgmd_model.h"
#include "engine/runtime/controls.h"
#include "engine/runtime/pose_frame.h"

namespace dance::engine {

struct SgmdDanceOptions {
  uint64_t seed = 0;
  std::vector<std::pair<std::string, float>> style;  // empty = "none"
  int steps = 0;            // DDIM steps; 0 = the model's default (sampling.steps)
  float guidance = 0.0f;    // w; 0 = the model's default (sampling.guidance); 1 = no guidance
  int overlap_frames = -1;  // frames two windows share; -1 = the model's default; 0..frames-1
  Controls controls;
  bool foot_lock = true;    // docs/model.md section 7, on frames whose lower body is not given
  // Seam blend (docs/diffusion.md section 5): where generated frames meet frames they did not make (the
  // previous window's, or given joints), the jump against a constant-velocity continuation is faded out
  // over this many generated frames, per joint; given joints are never moved. 0 = off.
  int seam_blend_frames = 10;
  // Glitch repair (docs/diffusion.md section 5): runs of at most this many generated frames whose pelvis
  // leaves its neighbours' path (farther than 0.25 m from the 17-frame median of the pelvis on the floor)
  // or whose facing turns more than 60 degrees from the median's are replaced by the interpolation of the
  // frames around them. Frames with any given joint are never touched. 0 = off.
  int glitch_max_frames = 8;
  // Re-anchoring (docs/diffusion.md section 5): after each window seam, the worst break of the pelvis path
  // or facing among this many new frames (against the constant-velocity, constant-turn continuation of
  // the two frames before it), if over 8 cm (+ 0.5 m per radian), is removed by turning and moving the rest
  // of the dance as one piece, up to a frame with any given joint or the trajectory's span. 0 = off.
  int reanchor_search_frames = 8;
  // Called after every denoising step with (steps done, steps in all windows); return false to cancel.
  std::function<bool(int64_t, int64_t)> progress;
};

struct SgmdDance {
  std::vector<PoseFrame> frames;  // one per feature frame; codes are -1 (the diffusion model has none)
  int windows = 0;
  int steps = 0;
  float guidance = 1.0f;
  int overlap_frames = 0;
  int64_t repaired_frames = 0;    // frames the glitch repair replaced
  int reanchored_seams = 0;       // window seams whose break the re-anchoring removed
};

// The engine's causal features of a whole decoded song (as dance-features computes them).
absl::StatusOr<audio::FeatureFrames> SongFeatures(const audio::DecodedAudio& audio);

// The style weights (n_styles + 1, the last "none") of a mix; an empty mix is "none".
absl::StatusOr<Eigen::VectorXf> SgmdStyleWeights(const SgmdModel& model,
                                                 const std::vector<std::pair<std::string, float>>& mix);

namespace sgmd_internal {
// The glitch repair of GenerateSgmdDance (SgmdDanceOptions::glitch_max_frames) on world positions of frames
// [0, total); returns the frames it replaced. For tests.
int64_t RepairGlitches(const Controls& controls, int max_run, std::vector<JointPositions>& world, int64_t total);
// The re-anchoring (SgmdDanceOptions::reanchor_search_frames) at the given window seams (each window's
// first new frame); returns the seams it moved the dance at.
int ReanchorSeams(const Controls& controls, const std::vector<int64_t>& window_seams, int search,
                  std::vector<JointPositions>& world, int64_t total);
}  // namespace sgmd_internal

absl::StatusOr<SgmdDance> GenerateSgmdDance(const SgmdModel& model, const audio::FeatureFrames& song,
                                            const SgmdDanceOptions& options);

}  // namespace dance::engine

#endif  // DANCE_ENGINE_DIFFUSION_SGMD_DANCE_H_
