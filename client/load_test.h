// The load tester behind `dance-client load`: N real-time-paced Perform sessions of the same audio (looped
// to the duration), spread over several channels, one pacer thread; prints progress every second and
// returns the aggregate figures (the JSON line's fields).
//
// Usage:
//   LoadOptions o; o.target = "localhost:50051"; o.streams = 50; o.duration_s = 30;
//   ASSIGN_OR_RETURN(LoadReport r, RunLoad(o, clip, std::cerr));
//   std::cout << LoadReportJson(r) << "\n";
#ifndef DANCE_CLIENT_LOAD_TEST_H_
#define DANCE_CLIENT_LOAD_TEST_H_

#include <map>
#include <memory>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "client/audio_source.h"
#include "dance/v1/dance.pb.h"

namespace dance::client {

struct LoadOptions {
  std::string target;                 // host:port
  std::shared_ptr<grpc::ChannelCredentials> credentials;  // null = insecure
  std::string auth_token;
  int streams = 1;
  double duration_s = 10.0;
  int chunk_ms = 40;
  int streams_per_channel = 32;
  double stagger_s = 1.0;             // session starts spread evenly over this window
  bool realtime = true;
  uint64_t seed = 0;
  float guidance = 0.0f;              // Sampling.guidance of every session (0 = the model's default)
  float music_guidance = -1.0f;       // Sampling.music_guidance of every session (negative = the model's default)
  std::vector<std::pair<std::string, float>> style;  // every session's style mix (empty = "none")
  dance::v1::MotionControls controls;  // every session's header controls (empty = none): their live cost
};

struct LoadReport {
  int streams = 0;
  double duration_s = 0.0;            // wall time from the first start to the last end
  double frames_per_s = 0.0;          // all streams together
  int64_t frames = 0;
  int errors = 0;                     // sessions that did not end OK
  // Frames the audio sent called for (per stream: the server's StreamEnd count if it ended, else at least
  // the lower bound of FramesForAudio; see StreamExpectedFrames), summed over streams.
  int64_t expected_frames = 0;
  // Performer frames that never arrived: per stream max(expected - received, index gaps), summed. A session
  // that failed (no StreamEnd) counts everything its audio called for and it did not get.
  int64_t dropped_frames = 0;
  double p50_ms = 0.0, p95_ms = 0.0, p99_ms = 0.0, max_ms = 0.0;
  double max_skew_ms = 0.0;
  // Frames at least kSlowFrameMs late, and where they fell: seconds into their stream and seconds since the
  // run started (both floored), to tell start-up stalls from moments that hit every stream.
  int64_t slow_frames = 0;
  int slow_streams = 0;
  std::map<int, int64_t> slow_by_stream_second, slow_by_run_second;
  double slow_server_share_p50 = 0.0;  // median over slow frames of (server time - send) / latency
  std::string first_error;
};

// What one stream of a load run saw, for the frame accounting.
struct StreamTally {
  int64_t received = 0;          // frames received
  int64_t gaps = 0;              // missing indices between received frames
  int64_t audio_frames_sent = 0; // sample frames of audio sent
  int sample_rate_hz = 0;        // of that audio
  bool got_end = false;          // StreamEnd arrived (then end_frames is the server's count)
  int64_t end_frames = 0;
  double fps = 30.0;             // from SessionInfo
  int frames_per_step = 4;       // from SessionInfo
};
// A lower bound of the frames a server emits for `audio_frames` of audio (docs/life-of-a-stream.md: the
// dance covers every period the audio reaches into, the first period emits no frame): floor(seconds * fps)
// minus one step, at least 0.
int64_t FramesForAudio(int64_t audio_frames, int sample_rate_hz, double fps, int frames_per_step);
// max(server's StreamEnd count if any, FramesForAudio(audio sent)).
int64_t StreamExpectedFrames(const StreamTally& t);
// Frames that never arrived: max(expected - received, gaps).
int64_t StreamMissingFrames(const StreamTally& t);

absl::StatusOr<LoadReport> RunLoad(const LoadOptions& options, std::shared_ptr<const AudioClip> clip,
                                   std::ostream& progress);
std::string LoadReportJson(const LoadReport& report);
// Human-readable lines on the slow frames (count, and where in time they fell).
std::string SlowFramesSummary(const LoadReport& report);

}  // namespace dance::client

#endif  // DANCE_CLIENT_LOAD_TEST_H_
