#include "client/vmc_stream.h"

#include "client/dance_file.h"

namespace dance::client {

VmcStreamOut::VmcStreamOut(std::string target, VmcOptions options, VmcRelayOptions relay_options)
    : target_(std::move(target)), options_(options), relay_options_(relay_options) {}

absl::Status VmcStreamOut::OnInfo(const dance::v1::SessionInfo& info) {
  if (relay_ != nullptr) return absl::OkStatus();
  const MotionClip skeleton = ClipFromStream(info, {});
  absl::StatusOr<std::unique_ptr<VmcSender>> sender = VmcSender::Create(target_, skeleton, options_);
  if (!sender.ok()) return sender.status();
  joints_ = skeleton.num_joints();
  scratch_.resize(joints_);
  if (info.fps() > 0) relay_options_.stream_fps = info.fps();
  relay_ = std::make_unique<VmcRelay>(*std::move(sender), relay_options_);
  return absl::OkStatus();
}

void VmcStreamOut::OnFrame(const dance::v1::PoseFrame& f) {
  if (relay_ == nullptr || f.rotations_size() < 4 * joints_ || f.positions_size() < 3) return;
  for (int j = 0; j < joints_; ++j) {
    scratch_[j] = {f.rotations(4 * j), f.rotations(4 * j + 1), f.rotations(4 * j + 2), f.rotations(4 * j + 3)};
  }
  relay_->Push(f.time_ms() / 1000.0, {f.positions(0), f.positions(1), f.positions(2)}, scratch_.data());
}

void VmcStreamOut::Finish() {
  if (relay_ != nullptr) relay_->Finish();
}

absl::Status ForwardSessionToVmc(dance::v1::DanceService::Stub* stub, const std::string& session_id,
                                 const std::string& token, VmcStreamOut* out, grpc::ClientContext* context) {
  if (!token.empty()) context->AddMetadata("authorization", "Bearer " + token);
  dance::v1::WatchRequest req;
  req.set_session_id(session_id);
  auto reader = stub->Watch(context, req);
  dance::v1::DanceUpdate u;
  absl::Status status;
  while (reader->Read(&u)) {
    if (u.has_info() && status.ok()) status = out->OnInfo(u.info());
    if (u.has_frame()) out->OnFrame(u.frame());
  }
  grpc::Status st = reader->Finish();
  if (!status.ok()) return status;
  if (!st.ok() && st.error_code() != grpc::StatusCode::CANCELLED) {
    return absl::Status(static_cast<absl::StatusCode>(st.error_code()), st.error_message());
  }
  return absl::OkStatus();
}

}  // namespace dance::client
