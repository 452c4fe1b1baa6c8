// VmcRelay: plays a live stream of frames out through a VmcSender at the stream's own pace. Frames arrive
// in bursts (one model step = 4 frames every 133 ms, faster than real time when a file is streamed as
// fast as the server takes it); the relay keeps them in a queue and a thread sends, on a fixed tick, the
// pose at the playout time: `delay_s` behind the first frame's arrival, then real time. At out_fps = 0 the
// tick is the stream's rate and each frame is sent as it is; at out_fps > 0 (60: the usual avatar rate)
// the pose is interpolated between the two frames around the playout time (root position linearly,
// rotations by slerp). When the playout time passes the newest frame, the newest is held (an underrun);
// when it falls more than `max_lag_s` behind the newest frame (a stalled receiver of a live stream), it
// jumps forward to `delay_s` behind it.
//
// Usage:
//   auto sender = VmcSender::Create(target, skeleton, {});
//   VmcRelay relay(*std::move(sender), {.out_fps = 60});
//   relay.Push(frame_time_s, root, rotations);      // from any thread, frames in time order
//   relay.Finish();                                  // plays out what is queued, then stops the thread
//
// Thread safety: Push, Finish and the counters may be called from any thread.
#ifndef DANCE_CLIENT_VMC_RELAY_H_
#define DANCE_CLIENT_VMC_RELAY_H_

#include <cstdint>
#include <deque>
#include <memory>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "client/export/motion_clip.h"
#include "client/vmc_sender.h"

namespace dance::client {

struct VmcRelayOptions {
  double out_fps = 0.0;      // 0 = the stream's rate (each frame as is), else interpolated to this rate
  double stream_fps = 30.0;  // the frames' rate
  double delay_s = 0.2;      // playout time behind the first frame's arrival (one step + jitter)
  double max_lag_s = 1.0;    // catch up when the playout falls this far behind the newest frame
                             // (live streams; a replayed file sets it to infinity)
};

class VmcRelay {
 public:
  VmcRelay(std::unique_ptr<VmcSender> sender, VmcRelayOptions options);
  ~VmcRelay();  // Finish()
  VmcRelay(const VmcRelay&) = delete;
  VmcRelay& operator=(const VmcRelay&) = delete;

  // Queues a frame: its audio time, the root's world position and J local rotations (w, x, y, z).
  void Push(double time_s, const Vec3& root, const Quat* rotations);
  // Sends what is queued (in real time), then stops. Idempotent.
  void Finish();

  int64_t poses_sent() const;
  int64_t underruns() const;
  // The first send error, if any (the relay keeps going: UDP losses are not fatal).
  absl::Status first_error() const;

 private:
  struct Frame {
    double time_s;
    Vec3 root;
    std::vector<Quat> rotations;
  };
  void Run();

  std::unique_ptr<VmcSender> sender_;
  const VmcRelayOptions options_;
  mutable absl::Mutex mu_;
  std::deque<Frame> queue_ ABSL_GUARDED_BY(mu_);
  bool finishing_ ABSL_GUARDED_BY(mu_) = false;
  int64_t poses_sent_ ABSL_GUARDED_BY(mu_) = 0;
  int64_t underruns_ ABSL_GUARDED_BY(mu_) = 0;
  absl::Status first_error_ ABSL_GUARDED_BY(mu_);
  std::thread thread_;
};

}  // namespace dance::client

#endif  // DANCE_CLIENT_VMC_RELAY_H_
