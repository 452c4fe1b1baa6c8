// The port's defaults for engines without controls (test doubles).
#include "server/core/engine_port.h"

namespace dance::server {

absl::Status EngineStream::SetControls(const ControlSpec& controls) {
  if (controls.empty()) return absl::OkStatus();
  return absl::UnimplementedError("this engine takes no motion controls");
}

absl::Status EngineStream::Steer(const SteerTarget&) {
  return absl::UnimplementedError("this engine takes no steering");
}

absl::Status EngineStream::PushPoses(absl::Span<const LivePose>) {
  return absl::UnimplementedError("this engine takes no live poses");
}

}  // namespace dance::server
