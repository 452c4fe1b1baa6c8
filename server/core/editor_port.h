// The server's view of the diffusion editor (SGMD, docs/diffusion.md): a narrow port like engine_port.h.
// The real implementation (LoadEditorBackend, in engine_backend.cc) wraps engine::GenerateSgmdDance; core
// tests may supply a labelled test double.
//
// Usage:
//   ASSIGN_OR_RETURN(std::unique_ptr<EditorBackend> editor, LoadEditorBackend("models/sgmd.dncw"));
//   ASSIGN_OR_RETURN(EditOutput out, editor->Edit(config, [](const EditProgress& p) { return true; }));
//
// Thread safety: an EditorBackend is immutable after creation; Edit may run concurrently on several
// threads (each call uses the calling thread only).
#ifndef DANCE_SERVER_CORE_EDITOR_PORT_H_
#define DANCE_SERVER_CORE_EDITOR_PORT_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "server/core/engine_port.h"

namespace dance::server {

struct EditConfig {
  std::string audio;       // an encoded audio file's bytes
  std::string audio_name;  // for messages
  StyleMix style;          // empty = "none"
  uint64_t seed = 0;
  int steps = 0;           // 0 = the model's default
  float guidance = 0.0f;   // 0 = the model's default
  double overlap_s = 0.0;  // 0 = the model's default
  bool foot_lock = true;
  ControlSpec controls;
};

struct EditProgress {
  int64_t steps_done = 0;
  int64_t steps_total = 0;
};

struct EditOutput {
  std::vector<FrameData> frames;
  int windows = 0;
  int steps = 0;
  float guidance = 1.0f;
  double overlap_s = 0.0;
  double audio_s = 0.0;
};

struct EditorDescription {
  std::string model_id;
  std::vector<std::string> styles;
  int default_steps = 50;
  float default_guidance = 1.0f;
  double default_overlap_s = 2.5;
  double window_s = 5.0;
  std::vector<std::string> joint_names;  // kNumJoints
  std::vector<int> parents;
  std::vector<float> rest_offsets;       // kNumJoints * 3
};

class EditorBackend {
 public:
  virtual ~EditorBackend() = default;
  virtual const EditorDescription& Describe() const = 0;
  // Decodes the audio, checks the request and makes the dance on the calling thread. `progress` is called
  // after every denoising step; returning false cancels (CANCELLED). INVALID_ARGUMENT naming the field for
  // bad input; audio longer than `max_audio_s` is INVALID_ARGUMENT too.
  virtual absl::StatusOr<EditOutput> Edit(const EditConfig& config, double max_audio_s,
                                          const std::function<bool(const EditProgress&)>& progress) const = 0;
};

// Loads an SGMD model file. Errors: whatever the engine's loader returns.
absl::StatusOr<std::unique_ptr<EditorBackend>> LoadEditorBackend(const std::string& model_path);

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_EDITOR_PORT_H_
