#include "client/load_test.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "client/perform_stream.h"
#include "nlohmann/json.hpp"

namespace dance::client {
namespace {

double Percentile(std::vector<float>& v, double q) {
  if (v.empty()) return 0.0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(std::ceil(q * static_cast<double>(v.size()))) - 1);
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

}  // namespace

int64_t FramesForAudio(int64_t audio_frames, int sample_rate_hz, double fps, int frames_per_step) {
  if (audio_frames <= 0 || sample_rate_hz <= 0 || fps <= 0) return 0;
  // Exact in integers for the usual rates (e.g. 44100 Hz x 30 fps); a tiny epsilon guards the rest.
  const double frames = static_cast<double>(audio_frames) * fps / static_cast<double>(sample_rate_hz);
  const int64_t whole = static_cast<int64_t>(std::floor(frames + 1e-9));
  return std::max<int64_t>(0, whole - std::max(0, frames_per_step));
}

int64_t StreamExpectedFrames(const StreamTally& t) {
  const int64_t from_audio = FramesForAudio(t.audio_frames_sent, t.sample_rate_hz, t.fps, t.frames_per_step);
  return t.got_end ? std::max(t.end_frames, from_audio) : from_audio;
}

int64_t StreamMissingFrames(const StreamTally& t) {
  return std::max({int64_t{0}, StreamExpectedFrames(t) - t.received, t.gaps});
}

absl::StatusOr<LoadReport> RunLoad(const LoadOptions& o, std::shared_ptr<const AudioClip> clip,
                                   std::ostream& progress) {
  if (o.streams < 1) return absl::InvalidArgumentError("--streams must be >= 1");
  auto creds = o.credentials ? o.credentials : grpc::InsecureChannelCredentials();
  const int n_channels = (o.streams + o.streams_per_channel - 1) / o.streams_per_channel;
  std::vector<std::unique_ptr<dance::v1::DanceService::Stub>> stubs;
  for (int c = 0; c < n_channels; ++c) {
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    args.SetInt("dance.load_channel", c);  // a distinct connection per channel
    args.SetMaxReceiveMessageSize(16 << 20);
    stubs.push_back(dance::v1::DanceService::NewStub(grpc::CreateCustomChannel(o.target, creds, args)));
  }
  std::vector<std::unique_ptr<PerformStream>> streams;
  for (int i = 0; i < o.streams; ++i) {
    PerformOptions po;
    po.chunk_ms = o.chunk_ms;
    po.keep_frames = false;
    po.auth_token = o.auth_token;
    po.header.set_seed(o.seed + static_cast<uint64_t>(i));
    po.header.set_client_name(absl::StrFormat("load-%d", i));
    po.header.set_omit_rotations(true);
    for (const auto& [name, weight] : o.style) {
      dance::v1::StyleWeight* w = po.header.add_style();
      w->set_name(name);
      w->set_weight(weight);
    }
    if (o.guidance != 0.0f) {  // a Sampling has no field presence: temperature 1 as without one
      po.header.mutable_sampling()->set_temperature(1.0f);
      po.header.mutable_sampling()->set_guidance(o.guidance);
    }
    if (o.music_guidance >= 0.0f) {
      po.header.mutable_sampling()->set_temperature(1.0f);
      po.header.mutable_sampling()->set_music_guidance(o.music_guidance);
    }
    if (o.controls.ByteSizeLong() > 0) *po.header.mutable_controls() = o.controls;
    streams.push_back(std::make_unique<PerformStream>(
        stubs[static_cast<size_t>(i / o.streams_per_channel)].get(),
        std::make_unique<ClipSource>(clip, o.realtime, o.duration_s), po));
  }
  const absl::Time t0 = absl::Now();
  std::vector<absl::Time> start_at(streams.size());
  std::vector<bool> started(streams.size(), false);
  for (size_t i = 0; i < streams.size(); ++i) {
    start_at[i] = t0 + absl::Seconds(o.stagger_s * static_cast<double>(i) / static_cast<double>(streams.size()));
  }
  absl::Time next_report = t0 + absl::Seconds(1);
  int64_t last_frames = 0;
  while (true) {
    const absl::Time now = absl::Now();
    int live = 0;
    for (size_t i = 0; i < streams.size(); ++i) {
      if (!started[i]) {
        if (now < start_at[i]) {
          ++live;
          continue;
        }
        streams[i]->Start(now);
        started[i] = true;
        start_at[i] = now;  // the actual start: slow frames' arrival times count from it
      }
      if (!streams[i]->done()) {
        ++live;
        streams[i]->Pump(now);
      }
    }
    if (now >= next_report) {
      int64_t frames = 0;
      for (auto& s : streams) frames += s->frames_received();
      progress << absl::StrFormat("[%5.1fs] streams live %d, frames/s %lld\n", absl::ToDoubleSeconds(now - t0),
                                  live, static_cast<long long>(frames - last_frames));
      last_frames = frames;
      next_report += absl::Seconds(1);
    }
    if (live == 0) break;
    absl::SleepFor(absl::Milliseconds(5));
  }
  const absl::Time t1 = absl::Now();
  LoadReport r;
  r.streams = o.streams;
  r.duration_s = absl::ToDoubleSeconds(t1 - t0);
  std::vector<float> lat;
  std::vector<float> server_share;
  // Streams that never got a SessionInfo (e.g. refused) use the model's rates from one that did.
  double fps = 30.0;
  int frames_per_step = 4;
  for (auto& s : streams) {
    (void)s->Wait();
    if (s->got_info() && s->info().fps() > 0) {
      fps = s->info().fps();
      frames_per_step = s->info().frames_per_step();
      break;
    }
  }
  for (size_t i = 0; i < streams.size(); ++i) {
    PerformStream* s = streams[i].get();
    absl::Status st = s->Wait();
    const FrameStats& fs = s->stats();
    r.slow_frames += static_cast<int64_t>(fs.slow.size());
    r.slow_streams += fs.slow.empty() ? 0 : 1;
    const double offset_s = absl::ToDoubleSeconds(start_at[i] - t0);
    for (const FrameStats::Slow& f : fs.slow) {
      ++r.slow_by_stream_second[static_cast<int>(f.at_s)];
      ++r.slow_by_run_second[static_cast<int>(offset_s + f.at_s)];
      server_share.push_back(f.server_ms / f.latency_ms);
    }
    r.frames += fs.frames;
    StreamTally t;
    t.received = fs.frames;
    t.gaps = fs.gaps;
    t.audio_frames_sent = s->audio_frames_sent();
    t.sample_rate_hz = clip->sample_rate;
    t.got_end = st.ok() && s->got_end();
    t.end_frames = s->end().frames();
    t.fps = s->got_info() && s->info().fps() > 0 ? s->info().fps() : fps;
    t.frames_per_step = s->got_info() && s->info().fps() > 0 ? s->info().frames_per_step() : frames_per_step;
    r.expected_frames += StreamExpectedFrames(t);
    r.dropped_frames += StreamMissingFrames(t);
    if (!st.ok()) {
      ++r.errors;
      if (r.first_error.empty()) r.first_error = st.ToString();
    }
    lat.insert(lat.end(), fs.latency_ms.begin(), fs.latency_ms.end());
    r.max_skew_ms = std::max(r.max_skew_ms, fs.max_skew_ms);
  }
  r.frames_per_s = r.duration_s > 0 ? static_cast<double>(r.frames) / r.duration_s : 0.0;
  r.p50_ms = Percentile(lat, 0.50);
  r.p95_ms = Percentile(lat, 0.95);
  r.p99_ms = Percentile(lat, 0.99);
  r.max_ms = lat.empty() ? 0.0 : *std::max_element(lat.begin(), lat.end());
  r.slow_server_share_p50 = Percentile(server_share, 0.5);
  return r;
}

std::string SlowFramesSummary(const LoadReport& r) {
  if (r.slow_frames == 0) return absl::StrFormat("slow frames (>= %.0f ms): none", kSlowFrameMs);
  auto buckets = [](const std::map<int, int64_t>& m) {
    std::string out;
    for (const auto& [sec, n] : m) absl::StrAppendFormat(&out, " %ds:%lld", sec, static_cast<long long>(n));
    return out;
  };
  return absl::StrFormat("slow frames (>= %.0f ms): %lld in %d streams; median share of their latency spent "
                         "before the server produced them %.2f\n  by second into the stream:%s\n"
                         "  by second of the run:%s",
                         kSlowFrameMs, static_cast<long long>(r.slow_frames), r.slow_streams,
                         r.slow_server_share_p50,
                         buckets(r.slow_by_stream_second), buckets(r.slow_by_run_second));
}

std::string LoadReportJson(const LoadReport& r) {
  auto round3 = [](double v) { return std::round(v * 1000.0) / 1000.0; };
  nlohmann::json j = {{"streams", r.streams},
                      {"duration_s", round3(r.duration_s)},
                      {"frames_per_s", round3(r.frames_per_s)},
                      {"errors", r.errors},
                      {"dropped_frames", r.dropped_frames},
                      {"expected_frames", r.expected_frames},
                      {"p50_ms", round3(r.p50_ms)},
                      {"p95_ms", round3(r.p95_ms)},
                      {"p99_ms", round3(r.p99_ms)},
                      {"max_skew_ms", round3(r.max_skew_ms)},
                      {"frames", r.frames},
                      {"max_ms", round3(r.max_ms)},
                      {"slow_frames", r.slow_frames}};
  if (!r.first_error.empty()) j["first_error"] = r.first_error;
  return j.dump();
}

}  // namespace dance::client
