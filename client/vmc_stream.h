// VmcStreamOut: the glue between a dance stream (SessionInfo, then PoseFrames, as gRPC delivers them) and
// VMC egress (VmcSender + VmcRelay): `dance-client watch --vmc`, `perform --vmc` (which watches its own
// session on a second call) and `play --in DANCE.json --vmc` use it.
//
// Usage:
//   VmcStreamOut vmc("127.0.0.1:39539", {.bundle = true}, {.out_fps = 60});
//   vmc.OnInfo(info);                     // creates the sender; error for a bad address or skeleton
//   for (...) vmc.OnFrame(frame);         // queued, played out in real time by the relay's thread
//   vmc.Finish();                         // plays out the queue, then prints nothing and returns
//
//   // Or forward a live session by watching it (returns when the session ends or `context` is cancelled):
//   absl::Status s = ForwardSessionToVmc(stub, session_id, token, &vmc, &context);
//
// Thread safety: OnInfo/OnFrame/Finish from one thread (the relay sends from its own).
#ifndef DANCE_CLIENT_VMC_STREAM_H_
#define DANCE_CLIENT_VMC_STREAM_H_

#include <memory>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "client/vmc_relay.h"
#include "client/vmc_sender.h"
#include "dance/v1/dance.grpc.pb.h"

namespace dance::client {

class VmcStreamOut {
 public:
  VmcStreamOut(std::string target, VmcOptions options, VmcRelayOptions relay_options);
  absl::Status OnInfo(const dance::v1::SessionInfo& info);
  // Ignored before OnInfo succeeded and for frames without rotations.
  void OnFrame(const dance::v1::PoseFrame& frame);
  void Finish();
  const VmcRelay* relay() const { return relay_.get(); }

 private:
  const std::string target_;
  const VmcOptions options_;
  VmcRelayOptions relay_options_;
  int joints_ = 0;
  std::unique_ptr<VmcRelay> relay_;
  std::vector<Quat> scratch_;
};

absl::Status ForwardSessionToVmc(dance::v1::DanceService::Stub* stub, const std::string& session_id,
                                 const std::string& token, VmcStreamOut* out, grpc::ClientContext* context);

}  // namespace dance::client

#endif  // DANCE_CLIENT_VMC_STREAM_H_
