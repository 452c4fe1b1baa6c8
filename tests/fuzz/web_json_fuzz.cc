// libFuzzer target for what browsers send the server as JSON (server/web/json_codec.h): the /ws/perform
// start, control and poses messages (with their "controls" and "steer"), and the /ws/edit request, each
// then checked by the core's validators as the server does (server/core/stream_request.h, edit_jobs.h).
//
// Byte 0 selects the message (mod 6: start, control, controls, steer, poses, edit); the rest is JSON text.
// Invariants: no crash or sanitizer report; what the validators accept is finite and within its documented
// ranges (poses within 100 m, a steering velocity at most 10 m/s), and validating it again gives the same.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "nlohmann/json.hpp"
#include "server/core/edit_jobs.h"
#include "server/core/stream_request.h"
#include "server/web/json_codec.h"

namespace {

using namespace dance::server;  // NOLINT: a fuzz target

// A description (ModelDescription or EditorDescription) with a 24-joint skeleton and these styles.
template <typename Description>
const Description* Describe(const char* id, std::vector<std::string> styles) {
  auto* d = new Description;
  d->model_id = id;
  d->styles = std::move(styles);
  d->joint_names.assign(24, "j");
  d->parents.assign(24, 0);
  d->parents[0] = -1;
  d->rest_offsets.assign(72, 0.1f);
  return d;
}

const ModelDescription& Model() {
  static const ModelDescription* m = Describe<ModelDescription>("fuzz", {"breaking", "cha-cha", "waltz"});
  return *m;
}

const EditorDescription& Editor() {
  static const EditorDescription* e = Describe<EditorDescription>("fuzz-editor", {"breaking", "waltz"});
  return *e;
}

void Check(bool ok) {
  if (!ok) std::abort();
}

void CheckControls(const ControlSpec& c) {
  const absl::Status first = ValidateControlSpec(c);
  Check(ValidateControlSpec(c).code() == first.code());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1 || size > (1 << 20)) return 0;
  const nlohmann::json j = nlohmann::json::parse(data + 1, data + size, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return 0;
  switch (data[0] % 6) {
    case 0: {
      absl::StatusOr<StreamRequest> r = StreamRequestFromJson(j);
      if (!r.ok()) break;
      absl::StatusOr<ValidatedStream> v = ValidateStream(*r, Model(), StreamLimits{});
      if (v.ok()) CheckControls(r->controls);
      break;
    }
    case 1: {
      absl::StatusOr<ControlRequest> r = ControlRequestFromJson(j);
      if (!r.ok()) break;
      absl::StatusOr<ValidatedControl> v = ValidateControl(*r, Model());
      if (v.ok() && v->controls) CheckControls(*v->controls);
      if (v.ok() && v->steer) (void)ValidateSteer(*v->steer);
      break;
    }
    case 2: {
      absl::StatusOr<ControlSpec> c = ControlsFromJson(j);
      if (c.ok()) CheckControls(*c);
      break;
    }
    case 3: {
      absl::StatusOr<SteerTarget> s = SteerFromJson(j);
      if (s.ok() && ValidateSteer(*s).ok() && s->kind == SteerTarget::Kind::kVelocity) {
        Check(std::isfinite(s->x) && std::isfinite(s->z) && std::hypot(s->x, s->z) <= 10.0 + 1e-4);
      }
      break;
    }
    case 4: {
      absl::StatusOr<std::vector<PoseRequest>> poses = PosesFromJson(j);
      if (!poses.ok()) break;
      for (const PoseRequest& p : *poses) {
        absl::StatusOr<LivePose> v = ValidatePose(p);
        if (!v.ok()) continue;
        for (float q : v->positions) Check(std::isfinite(q) && std::abs(q) <= 100.0f);
      }
      break;
    }
    case 5: {
      absl::StatusOr<EditConfig> e = EditConfigFromJson(j);
      if (!e.ok()) break;
      const absl::Status first = ValidateEditConfig(*e, Editor());
      Check(ValidateEditConfig(*e, Editor()).code() == first.code());
      break;
    }
  }
  return 0;
}
