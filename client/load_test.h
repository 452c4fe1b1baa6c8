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

#include <memory>
#include <ostream>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "client/audio_source.h"

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
};

struct LoadReport {
  int streams = 0;
  double duration_s = 0.0;            // wall time from the first start to the last end
  double frames_per_s = 0.0;          // all streams together
  int64_t frames = 0;
  int errors = 0;                     // sessions that did not end OK
  int64_t dropped_frames = 0;         // performer frames missing (index gaps + frames the server made but we lacked)
  double p50_ms = 0.0, p95_ms = 0.0, p99_ms = 0.0, max_ms = 0.0;
  double max_skew_ms = 0.0;
  std::string first_error;
};

absl::StatusOr<LoadReport> RunLoad(const LoadOptions& options, std::shared_ptr<const AudioClip> clip,
                                   std::ostream& progress);
std::string LoadReportJson(const LoadReport& report);

}  // namespace dance::client

#endif  // DANCE_CLIENT_LOAD_TEST_H_
