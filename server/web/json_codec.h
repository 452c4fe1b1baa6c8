// The web transport's encoding: the browser's JSON (docs/protocol.md sections 2 and 3) to and from the
// core's types (server/core/), with no proto in between. Requests are decoded here (type errors name the
// JSON key) and validated by the core's rules (stream_request.h), the same rules the gRPC transport uses.
// Pure functions; thread-safe.
//
// Usage:
//   ASSIGN_OR_RETURN(StreamRequest r, StreamRequestFromJson(start));   // {"type": "start", ...}
//   ASSIGN_OR_RETURN(ValidatedStream v, ValidateStream(r, hub.model(), limits));
//   std::string scratch;
//   ws.SendText(UpdateToJson(*update, /*with_rotations=*/true, dropped_before, &scratch));
#ifndef DANCE_SERVER_WEB_JSON_CODEC_H_
#define DANCE_SERVER_WEB_JSON_CODEC_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "nlohmann/json.hpp"
#include "server/core/edit_jobs.h"
#include "server/core/engine_port.h"
#include "server/core/live_session.h"
#include "server/core/stream_request.h"
#include "server/core/update.h"

namespace dance::server {

// ---- in ----
// {"type": "start", "sample_rate", "channels", "seed", "style", sampling keys, "client_name",
// "omit_rotations", "raw_feet", "controls"}: float32 PCM. INVALID_ARGUMENT for a key of the wrong type.
absl::StatusOr<StreamRequest> StreamRequestFromJson(const nlohmann::json& start);
// {"type": "control", "style", sampling keys, "controls", "steer"}.
absl::StatusOr<ControlRequest> ControlRequestFromJson(const nlohmann::json& control);
// "controls": {"seed"|"given_upper"|"given_lower"|"keyframes"|"inpaint": {"positions", "file", "start_ms",
// "times_ms"}, "inpaint_known": [{"start_ms", "end_ms", "joints"}], "trajectory": [{"t_ms", "x", "z",
// "facing"}]} (dance.v1.MotionControls; "file" is the file's text).
absl::StatusOr<ControlSpec> ControlsFromJson(const nlohmann::json& controls);
// "steer": {"point": {"t_ms", "x", "z", "facing"}} or {"velocity": {"x", "z", "facing", "hold_ms"}}.
absl::StatusOr<SteerTarget> SteerFromJson(const nlohmann::json& steer);
// {"type": "poses", "poses": [{"time_ms", "positions": [72 numbers], "part": "upper"|"lower"|"all"}]}.
absl::StatusOr<std::vector<PoseRequest>> PosesFromJson(const nlohmann::json& poses);

// {"type": "edit", "audio_name", "style", "seed", "steps", "guidance", "overlap_s", "controls", "raw_feet"}
// (the song comes in the next, binary, message): the EditConfig without its audio. INVALID_ARGUMENT for a
// key of the wrong type; the numbers are checked by ValidateEditConfig.
absl::StatusOr<EditConfig> EditConfigFromJson(const nlohmann::json& edit);

// ---- out ----
// The update as its JSON text message. For dropped_before == 0 the text is built once per update and
// rotations choice and kept on the update (update.h), shared by every socket that sends it; the view stays
// valid while the update lives. A frame with dropped_before > 0 is written into *scratch for its viewer.
absl::string_view UpdateToJson(const Update& update, bool with_rotations, int64_t dropped_before,
                               std::string* scratch);
// {"type": "error", "code": "INVALID_ARGUMENT", "message": ...}
std::string ErrorToJson(const absl::Status& status);
nlohmann::json ModelToJson(const ModelDescription& model);
nlohmann::json SummaryToJson(const SessionSummary& summary);
// {"type": "queued", "position"} / {"type": "progress", "steps_done", "steps_total"} / {"type": "result",
// "model_id", "fps", "windows", "steps", "guidance", "overlap_s", "audio_ms", "compute_ms", "skeleton":
// {"joint_names", "parents", "rest_offsets"}, "frames": [{"index", "time_ms", "positions", "rotations"}]}.
std::string EditEventToJson(const EditEvent& event, const EditorDescription& editor, bool with_rotations);
nlohmann::json EditorToJson(const EditJobs& jobs);

}  // namespace dance::server

#endif  // DANCE_SERVER_WEB_JSON_CODEC_H_
