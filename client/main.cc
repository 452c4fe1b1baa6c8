// dance-client: streams audio to dance-server and saves the dance; watches live sessions; load-tests.
//
//   dance-client --server HOST:P --audio FILE --out DANCE.json [--bvh DANCE.bvh] [--realtime] [--play]
//   dance-client --server HOST:P --mic --mic-seconds 30 --out DANCE.json
//   dance-client watch --server HOST:P --session ID [--out DANCE.json] [--frames N]
//   dance-client load --server HOST:P --audio FILE --streams N --duration S [--style S] [--guidance W] [--music-guidance M]
//   dance-client info --server HOST:P          (model info and live sessions)
//   dance-client play --in DANCE.json [--vmc HOST[:PORT]] [--out DANCE.glb]   (replay over VMC; convert)
// --out picks the format by extension: .json (dance-motion/v1), .bvh, .glb / .gltf (glTF 2.0 skinned
// skeleton + animation), .vrma (VRM Animation). --vmc HOST[:PORT] (perform, watch, play) sends the dance
// live over the VMC protocol (default port 39539; client/vmc_sender.h), --vmc-fps 60 interpolated or 0 at
// the stream's rate, --vmc-bundle=false one OSC message per datagram.
// Exit status: 0 on success, 1 on an RPC error (the status is printed), 2 on bad usage.
#include <algorithm>
#include <atomic>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/flags/flag.h"
#include "absl/flags/parse.h"
#include "absl/flags/usage.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "client/audio_source.h"
#include "client/dance_file.h"
#include "client/load_test.h"
#include "client/perform_stream.h"
#include "client/vmc_stream.h"
#include "dance/v1/dance.grpc.pb.h"

ABSL_FLAG(std::string, server, "localhost:50051", "Server address host:port.");
ABSL_FLAG(std::string, audio, "", "Audio file to stream (WAV, FLAC, Ogg/Vorbis, ...).");
ABSL_FLAG(bool, mic, false, "Stream the default microphone instead of a file (PortAudio).");
ABSL_FLAG(double, mic_seconds, 30.0, "Microphone recording length, s.");
ABSL_FLAG(int, mic_rate, 48000, "Microphone sample rate, Hz.");
ABSL_FLAG(std::string, out, "", "Save the dance here: .json (dance-motion/v1), .bvh, .glb, .gltf or .vrma.");
ABSL_FLAG(std::string, bvh, "", "Save the dance as BVH here.");
ABSL_FLAG(bool, realtime, false, "Pace the file in real time (default: as fast as the server takes it).");
ABSL_FLAG(bool, play, false, "Play the file on the default audio output while streaming (implies --realtime).");
ABSL_FLAG(std::string, style, "", "Style mix: name or name:weight,name:weight.");
ABSL_FLAG(uint64_t, seed, 0, "Sampling seed.");
ABSL_FLAG(double, temperature, 1.0, "Sampling temperature (0 = greedy).");
ABSL_FLAG(int, top_k, 0, "Top-k cut (0 = off).");
ABSL_FLAG(double, top_p, 0.0, "Nucleus cut (1 = off; 0 = the model's default).");
ABSL_FLAG(double, guidance, 0.0, "Style guidance weight (1 = off; 0 = the model's default). Also for load.");
ABSL_FLAG(double, music_guidance, -1.0,
          "Music guidance weight (1 = off; negative = the model's default; docs/model.md section 6). Also for load.");
ABSL_FLAG(double, period_lock, -1.0, "Period lock weight (0 = off; negative = the model's default).");
ABSL_FLAG(bool, raw_feet, false, "Foot lock off: legs and feet exactly as decoded (StreamHeader.raw_feet).");
ABSL_FLAG(int, chunk_ms, 40, "Audio per message, ms.");
ABSL_FLAG(std::string, token, "", "Bearer token (server --auth-token).");
ABSL_FLAG(std::string, ca_cert, "", "PEM CA certificate: connect with TLS.");
ABSL_FLAG(std::string, session, "", "watch: the session id.");
ABSL_FLAG(int, frames, 0, "watch: stop after this many frames (0 = until the session ends).");
ABSL_FLAG(int, streams, 1, "load: concurrent sessions.");
ABSL_FLAG(double, duration, 10.0, "load: seconds of audio per session (the file is looped).");
ABSL_FLAG(double, stagger, 1.0, "load: spread session starts over this many seconds.");
ABSL_FLAG(bool, quiet, false, "Less progress output.");
ABSL_FLAG(std::string, vmc, "", "Send the dance over the VMC protocol (OSC/UDP) to HOST[:PORT] (default port 39539).");
ABSL_FLAG(double, vmc_fps, 60.0, "VMC send rate: interpolated to this many poses/s; 0 = the stream's rate.");
ABSL_FLAG(bool, vmc_bundle, true, "VMC: one OSC bundle per pose (false: one message per datagram).");
ABSL_FLAG(std::string, seed_motion, "", "perform and load: start the dance from this clip (dance-motion/v1 JSON or BVH).");
ABSL_FLAG(std::string, given_upper, "", "perform and load: the upper body exactly as in this file; the legs danced.");
ABSL_FLAG(std::string, given_lower, "", "perform and load: the lower body (and root) exactly as in this file.");
ABSL_FLAG(std::string, keyframes, "", "perform and load: key poses to hit (dance-motion/v1 with \"times_s\").");
ABSL_FLAG(std::string, inpaint, "", "perform and load: a recorded dance to re-dance where --mask does not keep it.");
ABSL_FLAG(std::string, mask, "", "perform and load: the dance-mask/v1 of --inpaint.");
ABSL_FLAG(std::string, trajectory, "", "perform and load: a floor path to follow (dance-trajectory/v1).");
ABSL_FLAG(std::vector<std::string>, steer, {},
          "perform: AT:T:X:Z,... once the audio reaches AT s, be at (X, Z) m at T s (Control.steer).");
ABSL_FLAG(std::vector<std::string>, handover, {},
          "perform: AT:FILE,... once the audio reaches AT s, go on from the clip FILE (a seed mid-stream).");
ABSL_FLAG(std::string, in, "", "play: a dance-motion/v1 JSON file.");

namespace {

using dance::client::PerformStream;

std::shared_ptr<grpc::Channel> MakeChannel() {
  std::shared_ptr<grpc::ChannelCredentials> creds = grpc::InsecureChannelCredentials();
  if (!absl::GetFlag(FLAGS_ca_cert).empty()) {
    grpc::SslCredentialsOptions ssl;
    std::ifstream in(absl::GetFlag(FLAGS_ca_cert));
    ssl.pem_root_certs.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    creds = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(16 << 20);
  return grpc::CreateCustomChannel(absl::GetFlag(FLAGS_server), creds, args);
}

bool ParseStyle(const std::string& text, dance::v1::StreamHeader* h) {
  if (text.empty()) return true;
  for (absl::string_view part : absl::StrSplit(text, ',', absl::SkipEmpty())) {
    std::vector<std::string> nw = absl::StrSplit(part, ':');
    dance::v1::StyleWeight* w = h->add_style();
    w->set_name(nw[0]);
    w->set_weight(nw.size() > 1 ? std::stof(nw[1]) : 1.0f);
  }
  return true;
}

int Fail(const absl::Status& s) {
  std::cerr << "dance-client: " << s << "\n";
  return 1;
}

// The VMC output the flags ask for, or null. A live stream catches up when its receiver falls behind;
// a replayed file (all frames queued at once) plays every frame.
std::unique_ptr<dance::client::VmcStreamOut> MakeVmc(bool live = true) {
  if (absl::GetFlag(FLAGS_vmc).empty()) return nullptr;
  dance::client::VmcRelayOptions relay;
  relay.out_fps = std::max(0.0, absl::GetFlag(FLAGS_vmc_fps));
  if (!live) relay.max_lag_s = std::numeric_limits<double>::infinity();
  return std::make_unique<dance::client::VmcStreamOut>(
      absl::GetFlag(FLAGS_vmc), dance::client::VmcOptions{.bundle = absl::GetFlag(FLAGS_vmc_bundle)}, relay);
}

// The header controls the flags name (--seed-motion, --given-upper, ..., --trajectory): empty if none.
absl::Status ControlsFromFlags(dance::v1::MotionControls* out) {
  dance::client::ControlFiles files{absl::GetFlag(FLAGS_seed_motion), absl::GetFlag(FLAGS_given_upper),
                                    absl::GetFlag(FLAGS_given_lower),  absl::GetFlag(FLAGS_keyframes),
                                    absl::GetFlag(FLAGS_inpaint),      absl::GetFlag(FLAGS_mask),
                                    absl::GetFlag(FLAGS_trajectory)};
  if (files.empty()) return absl::OkStatus();
  absl::StatusOr<dance::v1::MotionControls> controls = dance::client::ControlsFromFiles(files);
  if (!controls.ok()) return controls.status();
  *out = *std::move(controls);
  return absl::OkStatus();
}

int Perform() {
  std::unique_ptr<dance::client::SampleSource> source;
  std::shared_ptr<const dance::client::AudioClip> clip;
  // --vmc watches the session live, so the audio must go at the music's pace.
  const bool realtime = absl::GetFlag(FLAGS_realtime) || absl::GetFlag(FLAGS_play) || !absl::GetFlag(FLAGS_vmc).empty();
  if (absl::GetFlag(FLAGS_mic)) {
    auto mic = dance::client::MicSource::Open(absl::GetFlag(FLAGS_mic_rate), absl::GetFlag(FLAGS_mic_seconds));
    if (!mic.ok()) return Fail(mic.status());
    source = *std::move(mic);
  } else {
    if (absl::GetFlag(FLAGS_audio).empty()) {
      std::cerr << "dance-client: give --audio FILE or --mic\n";
      return 2;
    }
    auto c = dance::client::ReadAudioFile(absl::GetFlag(FLAGS_audio));
    if (!c.ok()) return Fail(c.status());
    clip = *c;
    source = std::make_unique<dance::client::ClipSource>(clip, realtime, 0.0);
  }
  auto channel = MakeChannel();
  auto stub = dance::v1::DanceService::NewStub(channel);
  dance::client::PerformOptions po;
  po.chunk_ms = absl::GetFlag(FLAGS_chunk_ms);
  po.auth_token = absl::GetFlag(FLAGS_token);
  po.header.set_seed(absl::GetFlag(FLAGS_seed));
  po.header.set_client_name("dance-client");
  po.header.mutable_sampling()->set_temperature(static_cast<float>(absl::GetFlag(FLAGS_temperature)));
  po.header.mutable_sampling()->set_top_k(absl::GetFlag(FLAGS_top_k));
  po.header.mutable_sampling()->set_top_p(static_cast<float>(absl::GetFlag(FLAGS_top_p)));
  po.header.mutable_sampling()->set_guidance(static_cast<float>(absl::GetFlag(FLAGS_guidance)));
  if (absl::GetFlag(FLAGS_music_guidance) >= 0.0) {
    po.header.mutable_sampling()->set_music_guidance(static_cast<float>(absl::GetFlag(FLAGS_music_guidance)));
  }
  if (absl::GetFlag(FLAGS_period_lock) >= 0.0) {
    po.header.mutable_sampling()->set_period_lock(static_cast<float>(absl::GetFlag(FLAGS_period_lock)));
  }
  po.header.set_raw_feet(absl::GetFlag(FLAGS_raw_feet));
  ParseStyle(absl::GetFlag(FLAGS_style), &po.header);
  if (absl::Status st = ControlsFromFlags(po.header.mutable_controls()); !st.ok()) return Fail(st);
  for (const std::string& s : absl::GetFlag(FLAGS_steer)) {
    auto t = dance::client::ParseSteerFlag(s);
    if (!t.ok()) return Fail(t.status());
    po.controls.push_back(*std::move(t));
  }
  for (const std::string& s : absl::GetFlag(FLAGS_handover)) {
    auto t = dance::client::ParseHandoverFlag(s);
    if (!t.ok()) return Fail(t.status());
    po.controls.push_back(*std::move(t));
  }
  std::stable_sort(po.controls.begin(), po.controls.end(),
                   [](const auto& a, const auto& b) { return a.at_s < b.at_s; });
  const int64_t total_frames = source->Total();
  const int rate = source->sample_rate();
  PerformStream stream(stub.get(), std::move(source), po);
  std::unique_ptr<dance::client::Playback> playback;
  if (absl::GetFlag(FLAGS_play) && clip) {
    auto p = dance::client::Playback::Start(clip);
    if (p.ok()) {
      playback = *std::move(p);
    } else {
      std::cerr << "dance-client: playback unavailable: " << p.status() << "\n";
    }
  }
  std::unique_ptr<dance::client::VmcStreamOut> vmc = MakeVmc();
  grpc::ClientContext vmc_context;
  absl::Status vmc_status;
  std::thread vmc_thread;
  const absl::Time t0 = absl::Now();
  stream.Start(t0);
  absl::Time next_print = t0 + absl::Seconds(1);
  bool announced = false;
  while (!stream.done()) {
    const absl::Time now = absl::Now();
    stream.Pump(now);
    if (!announced && !stream.session_id().empty()) {
      const std::string id = stream.session_id();
      std::cout << "session " << id << " (watch: dance-client watch --session " << id << ")" << std::endl;
      announced = true;
      if (vmc) {  // VMC from a second call that watches this session (PerformStream keeps frames to the end)
        vmc_thread = std::thread([&, id] {
          vmc_status = dance::client::ForwardSessionToVmc(stub.get(), id, absl::GetFlag(FLAGS_token), vmc.get(),
                                                          &vmc_context);
        });
      }
    }
    if (!absl::GetFlag(FLAGS_quiet) && now >= next_print) {
      std::cerr << absl::StrFormat("\r[%6.1fs] frames %lld", absl::ToDoubleSeconds(now - t0),
                                   static_cast<long long>(stream.frames_received()));
      if (total_frames > 0) std::cerr << absl::StrFormat(" of ~%lld", static_cast<long long>(total_frames * 30 / rate));
      next_print += absl::Seconds(1);
    }
    absl::SleepFor(absl::Milliseconds(realtime ? 5 : 20));
  }
  absl::Status st = stream.Wait();
  if (vmc_thread.joinable()) {
    if (!st.ok()) vmc_context.TryCancel();
    vmc_thread.join();
    vmc->Finish();
    if (!vmc_status.ok()) std::cerr << "dance-client: VMC: " << vmc_status << "\n";
  }
  if (!absl::GetFlag(FLAGS_quiet)) std::cerr << "\n";
  for (const dance::v1::Event& e : stream.events()) {
    // A refused control or pose, a pose input that stopped: said, not lost.
    if (e.kind() == dance::v1::Event::KIND_WARNING) {
      std::cerr << absl::StrFormat("dance-client: server warning at %.2f s: %s\n", e.time_ms() / 1000.0, e.message());
    }
  }
  if (!st.ok()) return Fail(st);
  const auto& fs = stream.stats();
  std::vector<float> lat = fs.latency_ms;
  std::sort(lat.begin(), lat.end());
  auto pct = [&lat](double q) { return lat.empty() ? 0.0 : lat[std::min(lat.size() - 1, static_cast<size_t>(q * lat.size()))]; };
  std::cout << absl::StrFormat("frames %lld (%.1f s of dance), latency p50 %.1f ms p99 %.1f ms, gaps %lld\n",
                               static_cast<long long>(fs.frames), fs.frames / 30.0, pct(0.5), pct(0.99),
                               static_cast<long long>(fs.gaps));
  if (!absl::GetFlag(FLAGS_out).empty()) {
    absl::Status w = dance::client::WriteDanceFile(absl::GetFlag(FLAGS_out), stream.info(), stream.frames(),
                                                   absl::GetFlag(FLAGS_seed),
                                                   dance::client::BeatTimesOf(stream.events()));
    if (!w.ok()) return Fail(w);
    std::cout << "wrote " << absl::GetFlag(FLAGS_out) << "\n";
  }
  if (!absl::GetFlag(FLAGS_bvh).empty()) {
    absl::Status w = dance::client::WriteBvh(absl::GetFlag(FLAGS_bvh), stream.info(), stream.frames());
    if (!w.ok()) return Fail(w);
    std::cout << "wrote " << absl::GetFlag(FLAGS_bvh) << "\n";
  }
  return 0;
}

int Watch() {
  if (absl::GetFlag(FLAGS_session).empty()) {
    std::cerr << "dance-client watch: --session ID required\n";
    return 2;
  }
  auto stub = dance::v1::DanceService::NewStub(MakeChannel());
  grpc::ClientContext ctx;
  if (!absl::GetFlag(FLAGS_token).empty()) ctx.AddMetadata("authorization", "Bearer " + absl::GetFlag(FLAGS_token));
  dance::v1::WatchRequest req;
  req.set_session_id(absl::GetFlag(FLAGS_session));
  auto reader = stub->Watch(&ctx, req);
  dance::v1::DanceUpdate u;
  dance::v1::SessionInfo info;
  std::vector<dance::v1::PoseFrame> frames;
  std::vector<dance::v1::Event> events;
  int64_t dropped = 0;
  const int limit = absl::GetFlag(FLAGS_frames);
  std::unique_ptr<dance::client::VmcStreamOut> vmc = MakeVmc();
  while (reader->Read(&u)) {
    if (u.has_info()) {
      info = u.info();
      if (absl::Status v = vmc ? vmc->OnInfo(info) : absl::OkStatus(); !v.ok()) {
        ctx.TryCancel();
        reader->Finish();
        return Fail(v);
      }
    }
    if (u.has_event()) events.push_back(u.event());
    if (u.has_frame()) {
      if (vmc) vmc->OnFrame(u.frame());
      dropped += u.frame().dropped_before();
      frames.push_back(u.frame());
      if (!absl::GetFlag(FLAGS_quiet) && frames.size() % 30 == 0) {
        std::cerr << "\rframes " << frames.size() << " (dropped " << dropped << ")";
      }
      if (limit > 0 && static_cast<int>(frames.size()) >= limit) {
        ctx.TryCancel();
        break;
      }
    }
  }
  grpc::Status st = reader->Finish();
  if (vmc) vmc->Finish();
  std::cerr << "\n";
  if (!st.ok() && !(limit > 0 && st.error_code() == grpc::StatusCode::CANCELLED)) {
    return Fail(absl::Status(static_cast<absl::StatusCode>(st.error_code()), st.error_message()));
  }
  std::cout << "watched " << frames.size() << " frames, dropped " << dropped << "\n";
  if (!absl::GetFlag(FLAGS_out).empty()) {
    absl::Status w = dance::client::WriteDanceFile(absl::GetFlag(FLAGS_out), info, frames, 0,
                                                   dance::client::BeatTimesOf(events));
    if (!w.ok()) return Fail(w);
  }
  if (!absl::GetFlag(FLAGS_bvh).empty()) {
    absl::Status w = dance::client::WriteBvh(absl::GetFlag(FLAGS_bvh), info, frames);
    if (!w.ok()) return Fail(w);
  }
  return 0;
}

// Replays a saved dance over VMC in real time and/or converts it (--out by extension).
int Play() {
  if (absl::GetFlag(FLAGS_in).empty()) {
    std::cerr << "dance-client play: --in DANCE.json required\n";
    return 2;
  }
  dance::v1::SessionInfo info;
  std::vector<dance::v1::PoseFrame> frames;
  if (absl::Status s = dance::client::ReadDanceJson(absl::GetFlag(FLAGS_in), &info, &frames); !s.ok()) return Fail(s);
  if (!absl::GetFlag(FLAGS_out).empty()) {
    if (absl::Status w = dance::client::WriteDanceFile(absl::GetFlag(FLAGS_out), info, frames, 0); !w.ok()) return Fail(w);
    std::cout << "wrote " << absl::GetFlag(FLAGS_out) << "\n";
  }
  if (std::unique_ptr<dance::client::VmcStreamOut> vmc = MakeVmc(/*live=*/false)) {
    if (absl::Status v = vmc->OnInfo(info); !v.ok()) return Fail(v);
    for (const auto& f : frames) vmc->OnFrame(f);
    vmc->Finish();
    std::cout << "sent " << vmc->relay()->poses_sent() << " poses over VMC to " << absl::GetFlag(FLAGS_vmc) << "\n";
    if (!vmc->relay()->first_error().ok()) return Fail(vmc->relay()->first_error());
  }
  return 0;
}

int Load() {
  if (absl::GetFlag(FLAGS_audio).empty()) {
    std::cerr << "dance-client load: --audio FILE required\n";
    return 2;
  }
  auto clip = dance::client::ReadAudioFile(absl::GetFlag(FLAGS_audio));
  if (!clip.ok()) return Fail(clip.status());
  dance::client::LoadOptions o;
  o.target = absl::GetFlag(FLAGS_server);
  o.auth_token = absl::GetFlag(FLAGS_token);
  o.streams = absl::GetFlag(FLAGS_streams);
  o.duration_s = absl::GetFlag(FLAGS_duration);
  o.chunk_ms = absl::GetFlag(FLAGS_chunk_ms);
  o.stagger_s = absl::GetFlag(FLAGS_stagger);
  o.seed = absl::GetFlag(FLAGS_seed);
  o.guidance = static_cast<float>(absl::GetFlag(FLAGS_guidance));
  o.music_guidance = static_cast<float>(absl::GetFlag(FLAGS_music_guidance));
  if (absl::Status st = ControlsFromFlags(&o.controls); !st.ok()) return Fail(st);
  dance::v1::StreamHeader styled;
  ParseStyle(absl::GetFlag(FLAGS_style), &styled);
  for (const auto& w : styled.style()) o.style.emplace_back(w.name(), w.weight());
  auto r = dance::client::RunLoad(o, *clip, std::cerr);
  if (!r.ok()) return Fail(r.status());
  std::cout << absl::StrFormat(
      "streams %d, %.1f s: %.1f frames/s, errors %d, dropped %lld, latency p50 %.1f p95 %.1f p99 %.1f ms, "
      "max skew %.1f ms\n",
      r->streams, r->duration_s, r->frames_per_s, r->errors, static_cast<long long>(r->dropped_frames), r->p50_ms,
      r->p95_ms, r->p99_ms, r->max_skew_ms);
  if (!r->first_error.empty()) std::cout << "first error: " << r->first_error << "\n";
  std::cout << dance::client::SlowFramesSummary(*r) << "\n";
  std::cout << dance::client::LoadReportJson(*r) << std::endl;
  return r->errors == 0 ? 0 : 1;
}

int Info() {
  auto stub = dance::v1::DanceService::NewStub(MakeChannel());
  grpc::ClientContext ctx;
  if (!absl::GetFlag(FLAGS_token).empty()) ctx.AddMetadata("authorization", "Bearer " + absl::GetFlag(FLAGS_token));
  dance::v1::ModelInfo info;
  grpc::Status st = stub->GetModelInfo(&ctx, {}, &info);
  if (!st.ok()) return Fail(absl::Status(static_cast<absl::StatusCode>(st.error_code()), st.error_message()));
  std::cout << "model " << info.model_id() << ", latency " << info.latency_ms() << " ms, sessions "
            << info.active_sessions() << "/" << info.max_sessions() << ", styles:";
  for (const auto& s : info.styles()) std::cout << " " << s;
  std::cout << "\ndefaults: guidance " << info.default_guidance() << ", music guidance "
            << info.default_music_guidance() << ", top_p " << info.default_top_p()
            << ", period lock " << info.default_period_lock();
  // Styles whose period lock differs from the default (sorted: the proto map has no order).
  std::map<std::string, float> locks(info.style_period_lock().begin(), info.style_period_lock().end());
  for (const auto& [style, lock] : locks) {
    if (lock != info.default_period_lock()) std::cout << " (" << style << " " << lock << ")";
  }
  std::cout << "\n";
  grpc::ClientContext ctx2;
  if (!absl::GetFlag(FLAGS_token).empty()) ctx2.AddMetadata("authorization", "Bearer " + absl::GetFlag(FLAGS_token));
  dance::v1::ListSessionsResponse list;
  st = stub->ListSessions(&ctx2, {}, &list);
  if (!st.ok()) return Fail(absl::Status(static_cast<absl::StatusCode>(st.error_code()), st.error_message()));
  for (const auto& s : list.sessions()) {
    std::cout << s.session_id() << "  " << s.client_name() << "  frames " << s.frames() << "  viewers "
              << s.viewers() << "\n";
  }
  return 0;
}

// absl flags are spelled with underscores; accept the documented dashed spelling too (--http-port).
std::vector<std::string> DashesToUnderscores(int argc, char** argv) {
  std::vector<std::string> out(argv, argv + argc);
  for (size_t i = 1; i < out.size(); ++i) {
    std::string& a = out[i];
    if (a == "--") break;
    if (a.size() < 3 || a[0] != '-' || a[1] != '-') continue;
    const size_t end = std::min(a.find('='), a.size());
    for (size_t k = 2; k < end; ++k) {
      if (a[k] == '-') a[k] = '_';
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  absl::SetProgramUsageMessage(
      "dance-client [perform] --server HOST:P --audio FILE --out DANCE.json [--bvh F] [--realtime]\n"
      "  dance-client watch --session ID | load --audio FILE --streams N --duration S | info\n"
      "  dance-client play --in DANCE.json [--vmc HOST[:PORT]] [--out DANCE.glb]");
  std::vector<std::string> args = DashesToUnderscores(argc, argv);
  std::vector<char*> arg_ptrs;
  for (std::string& a : args) arg_ptrs.push_back(a.data());
  std::vector<char*> rest = absl::ParseCommandLine(static_cast<int>(arg_ptrs.size()), arg_ptrs.data());
  const std::string cmd = rest.size() > 1 ? rest[1] : "perform";
  if (cmd == "perform") return Perform();
  if (cmd == "watch") return Watch();
  if (cmd == "load") return Load();
  if (cmd == "info") return Info();
  if (cmd == "play") return Play();
  std::cerr << "dance-client: unknown command '" << cmd << "'\n";
  return 2;
}
