#include "client/vmc_relay.h"

#include <algorithm>
#include <cmath>

#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace dance::client {

VmcRelay::VmcRelay(std::unique_ptr<VmcSender> sender, VmcRelayOptions options)
    : sender_(std::move(sender)), options_(options) {
  thread_ = std::thread([this] { Run(); });
}

VmcRelay::~VmcRelay() { Finish(); }

void VmcRelay::Push(double time_s, const Vec3& root, const Quat* rotations) {
  Frame f{time_s, root, std::vector<Quat>(rotations, rotations + sender_->num_joints())};
  absl::MutexLock lock(&mu_);
  if (!queue_.empty() && time_s <= queue_.back().time_s) return;  // out of order or repeated
  queue_.push_back(std::move(f));
}

void VmcRelay::Finish() {
  {
    absl::MutexLock lock(&mu_);
    finishing_ = true;
  }
  if (thread_.joinable()) thread_.join();
}

int64_t VmcRelay::poses_sent() const {
  absl::MutexLock lock(&mu_);
  return poses_sent_;
}

int64_t VmcRelay::underruns() const {
  absl::MutexLock lock(&mu_);
  return underruns_;
}

absl::Status VmcRelay::first_error() const {
  absl::MutexLock lock(&mu_);
  return first_error_;
}

void VmcRelay::Run() {
  const bool interpolate = options_.out_fps > 0.0;
  const absl::Duration tick = absl::Seconds(1.0 / (interpolate ? options_.out_fps : options_.stream_fps));
  const double frame_period = 1.0 / options_.stream_fps;
  bool started = false;
  absl::Time origin;        // wall time at which the playout time is `origin_time`
  double origin_time = 0.0;
  double last_sent = -1e300;  // stream-rate mode: time of the last frame sent
  absl::Time next = absl::Now();
  Frame pose;
  for (;;) {
    bool send = false, done = false;
    {
      absl::MutexLock lock(&mu_);
      const absl::Time now = absl::Now();
      if (queue_.empty()) {
        if (finishing_) break;
      } else {
        if (!started) {
          started = true;
          origin = now + absl::Seconds(options_.delay_s);
          origin_time = queue_.front().time_s;
        }
        double play = origin_time + absl::ToDoubleSeconds(now - origin);
        if (queue_.back().time_s - play > options_.max_lag_s + options_.delay_s) {  // catch up
          origin_time = queue_.back().time_s - options_.delay_s;
          origin = now;
          play = origin_time;
          last_sent = std::max(last_sent, play - 0.5 * frame_period);  // stream rate: skip the backlog
        }
        if (interpolate) {
          while (queue_.size() >= 2 && queue_[1].time_s <= play) queue_.pop_front();
          const Frame& a = queue_.front();
          if (play >= a.time_s) {
            send = true;
            if (queue_.size() >= 2) {
              const Frame& b = queue_[1];
              const float u = static_cast<float>((play - a.time_s) / (b.time_s - a.time_s));
              pose.time_s = play;
              pose.rotations.resize(a.rotations.size());
              for (int k = 0; k < 3; ++k) pose.root[k] = a.root[k] + u * (b.root[k] - a.root[k]);
              for (size_t j = 0; j < a.rotations.size(); ++j) {
                pose.rotations[j] = QuatSlerp(a.rotations[j], b.rotations[j], u);
              }
            } else {
              pose = a;  // the newest frame, held
              if (finishing_) {
                done = true;
              } else if (play > a.time_s + frame_period) {
                ++underruns_;
              }
            }
          }
        } else {
          while (!queue_.empty() && queue_.front().time_s <= last_sent) queue_.pop_front();
          if (!queue_.empty() && queue_.front().time_s <= play) {
            pose = queue_.front();
            last_sent = pose.time_s;
            send = true;
            done = finishing_ && queue_.size() == 1;
          } else if (queue_.empty() && finishing_) {
            break;
          } else if (queue_.empty() && play > last_sent + 2 * frame_period) {
            ++underruns_;
          }
        }
      }
    }
    if (send) {
      absl::Status s = sender_->Send(pose.root, pose.rotations.data(), pose.time_s);
      absl::MutexLock lock(&mu_);
      ++poses_sent_;
      if (!s.ok() && first_error_.ok()) first_error_ = s;
    }
    if (done) break;
    next += tick;
    const absl::Time now = absl::Now();
    if (next < now - tick) next = now;  // overslept: keep the cadence from here
    absl::SleepFor(next - now);
  }
}

}  // namespace dance::client
