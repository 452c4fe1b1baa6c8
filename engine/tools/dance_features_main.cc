// dance-features: decodes an audio file and writes the engine's causal features as .npy arrays.
//
//   dance-features AUDIO --out FEATURES.npy [--pre PRE.npy] [--pre-input PRE_INPUT.npy]
//                  [--clock CLOCK.npy [--tempo-ref BPM] [--bar-beats B] [--fold-tempo] [--clock-starts STARTS.npy]]
//                  [--chunk-samples N] [--summary]
//
// FEATURES.npy: float32 (frames, 108); FEATURES.npy.json: the layout (names, index ranges, units).
// PRE.npy: float32 (frames, 128). PRE_INPUT.npy: float32 (frames, 4), PRE's input channels (for the
// Python batch reference). --chunk-samples feeds the stream in chunks of N input frames (default
// 4096; the output does not depend on it). --summary prints one JSON line to stdout.
// CLOCK.npy: float32 (warped frames, 2): for each frame j of the tempo-normalised timeline at
// --tempo-ref BPM (default 105; engine/audio/tempo_clock.h), its source feature frame and its continuous
// real frame position; training resamples features and motion with it. With --bar-beats B (1..16) it
// has 4 columns: also (cos, sin) of the bar clock's phase at B beats per bar (audio::BarClockPhase).
// --fold-tempo appends 49 columns: the warped frame's `tempogram` (48) and `tempo` features folded to
// the reference tempo with its source frame's clock rate (audio::FoldTempoFeatures), as a session of a
// model with time_base.fold_tempo sees them. --clock-starts STARTS.npy: float32 (frames, 2), per real frame n
// the warped position W_n where it starts and its clock rate r_n (warped frames per real frame): what a
// session plays real frame n back from (training.eval.engine_parity compares the engine's dances with it).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "engine/audio/audio_front_end.h"
#include "engine/audio/decoder.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/npy_writer.h"
#include "engine/audio/tempo_clock.h"
#include "nlohmann/json.hpp"

namespace {

using namespace dance::engine::audio;  // NOLINT: a tool's main

struct Flags {
  std::string audio, out, pre, pre_input, clock, clock_starts;
  double tempo_ref_bpm = 105.0;
  int bar_beats = 0;
  bool fold_tempo = false;
  int64_t chunk_samples = 4096;
  bool summary = false;
};

constexpr char kUsage[] =
    "usage: dance-features AUDIO --out FEATURES.npy [--pre PRE.npy] [--pre-input PRE_INPUT.npy]\n"
    "                      [--clock CLOCK.npy [--tempo-ref BPM] [--bar-beats B] [--fold-tempo]\n"
    "                      [--clock-starts STARTS.npy]] [--chunk-samples N] [--summary]\n";

absl::Status ParseFlags(int argc, char** argv, Flags* flags) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&](std::string* dst) -> absl::Status {
      if (i + 1 >= argc) return absl::InvalidArgumentError(absl::StrCat(arg, " needs a value"));
      *dst = argv[++i];
      return absl::OkStatus();
    };
    absl::Status s;
    if (arg == "--out") {
      s = value(&flags->out);
    } else if (arg == "--pre") {
      s = value(&flags->pre);
    } else if (arg == "--pre-input") {
      s = value(&flags->pre_input);
    } else if (arg == "--clock") {
      s = value(&flags->clock);
    } else if (arg == "--clock-starts") {
      s = value(&flags->clock_starts);
    } else if (arg == "--tempo-ref") {
      std::string v;
      s = value(&v);
      if (s.ok() && (!absl::SimpleAtod(v, &flags->tempo_ref_bpm) || !(flags->tempo_ref_bpm >= 30.0) ||
                     !(flags->tempo_ref_bpm <= 300.0))) {
        s = absl::InvalidArgumentError(absl::StrCat("--tempo-ref must be a tempo in 30..300 BPM, got '", v, "'"));
      }
    } else if (arg == "--bar-beats") {
      std::string v;
      s = value(&v);
      if (s.ok() && (!absl::SimpleAtoi(v, &flags->bar_beats) || flags->bar_beats < 1 || flags->bar_beats > 16)) {
        s = absl::InvalidArgumentError(absl::StrCat("--bar-beats must be an integer in 1..16, got '", v, "'"));
      }
    } else if (arg == "--chunk-samples") {
      std::string v;
      s = value(&v);
      if (s.ok() && (!absl::SimpleAtoi(v, &flags->chunk_samples) || flags->chunk_samples < 1)) {
        s = absl::InvalidArgumentError(
            absl::StrCat("--chunk-samples must be a positive integer, got '", v, "'"));
      }
    } else if (arg == "--fold-tempo") {
      flags->fold_tempo = true;
    } else if (arg == "--summary") {
      flags->summary = true;
    } else if (arg == "-h" || arg == "--help") {
      return absl::CancelledError("help");
    } else if (!arg.empty() && arg[0] == '-') {
      s = absl::InvalidArgumentError(absl::StrCat("unknown flag ", arg));
    } else if (flags->audio.empty()) {
      flags->audio = arg;
    } else {
      s = absl::InvalidArgumentError(absl::StrCat("unexpected argument ", arg));
    }
    if (!s.ok()) return s;
  }
  if (flags->audio.empty()) return absl::InvalidArgumentError("no AUDIO file given");
  if (flags->out.empty() && !flags->summary && flags->pre.empty() && flags->pre_input.empty() &&
      flags->clock.empty()) {
    return absl::InvalidArgumentError("nothing to do: give --out, --pre, --pre-input, --clock or --summary");
  }
  if (!flags->clock_starts.empty() && flags->clock.empty()) {
    return absl::InvalidArgumentError("--clock-starts needs --clock");
  }
  if (flags->fold_tempo && flags->clock.empty()) {
    return absl::InvalidArgumentError("--fold-tempo needs --clock (it adds columns to the clock)");
  }
  return absl::OkStatus();
}

nlohmann::json LayoutJson() {
  nlohmann::json f = nlohmann::json::array();
  auto add = [&](const char* name, int begin, int count, const char* unit) {
    f.push_back({{"name", name}, {"begin", begin}, {"end", begin + count}, {"unit", unit}});
  };
  add("mfcc", kMfccBegin, kNumMfcc, "DCT-II (ortho) of 64-band log-mel in dB");
  add("delta_mfcc", kDeltaMfccBegin, kNumMfcc, "mfcc[n] - mfcc[n-1], dB");
  add("chroma", kChromaBegin, kNumChroma, "C..B, max-normalised, [0, 1]");
  add("onset_strength", kOnsetIndex, 1, "mean positive log-mel increase, dB");
  add("rms_db", kRmsDbIndex, 1, "dBFS, floor -100");
  add("tempogram", kTempogramBegin, kNumTempogram,
      "normalised autocorrelation, 60..240 BPM log-spaced");
  add("beat_phase", kBeatPhaseCosIndex, 2, "(cos, sin) of 2 pi x beat fraction");
  add("tempo", kTempoIndex, 1, "log2(bpm / 120)");
  add("bar_phase", kBarPhaseCosIndex, 2, "(cos, sin) of 2 pi x bar fraction (4 beats)");
  add("beat_confidence", kBeatConfidenceIndex, 1, "[0, 1]");
  return {
      {"format", "dance-features/v1"},
      {"sample_rate", kSampleRate},
      {"hop_samples", kHopSamples},
      {"window_samples", kWindowSamples},
      {"fps", kFrameRate},
      {"lookahead_samples", AudioFrontEnd::LookaheadSamples()},
      {"dims", kNumFeatures},
      {"features", f},
      {"pre",
       {{"dims", kPreDims},
        {"channels", kPreChannels},
        {"window_frames", kPreWindow},
        {"bins", {kPreFirstBin, kPreFirstBin + kPreNumBins - 1}},
        {"layout", "[channel][bin][cos, sin]"},
        {"epsilon", kPreEpsilon},
        {"channel_names", {"onset_strength", "rms_db/10", "low_band_db/10", "high_band_flux"}}}}};
}

absl::Status Run(const Flags& flags) {
  absl::StatusOr<DecodedAudio> audio = DecodeAudioFile(flags.audio);
  if (!audio.ok()) return audio.status();
  int64_t sanitized = 0;
  absl::StatusOr<FeatureFrames> song = ComputeSongFeatures(*audio, flags.chunk_samples, &sanitized);
  if (!song.ok()) return song.status();
  const FeatureFrames& all = *song;
  const int64_t frames = all.frames();

  if (!flags.out.empty()) {
    if (absl::Status s = WriteNpyFloat32(flags.out, all.features, frames, kNumFeatures); !s.ok())
      return s;
    std::ofstream meta(flags.out + ".json");
    meta << LayoutJson().dump(1) << "\n";
    if (!meta) return absl::UnavailableError(absl::StrCat("cannot write ", flags.out, ".json"));
  }
  if (!flags.pre.empty()) {
    if (absl::Status s = WriteNpyFloat32(flags.pre, all.pre, frames, kPreDims); !s.ok()) return s;
  }
  if (!flags.pre_input.empty()) {
    if (absl::Status s = WriteNpyFloat32(flags.pre_input, all.pre_input, frames, kPreChannels);
        !s.ok()) {
      return s;
    }
  }
  if (!flags.clock.empty()) {
    TempoClock clock({.reference_bpm = flags.tempo_ref_bpm});
    const double bar_frames = flags.bar_beats > 0 ? BarClockFrames(flags.bar_beats, flags.tempo_ref_bpm) : 0.0;
    std::vector<float> rows, starts;
    std::array<float, kNumFeatures> row;
    for (int64_t n = 0; n < frames; ++n) {
      const float* source = all.features.data() + n * kNumFeatures;
      const TempoClock::Span span = clock.PushFeatures(source);
      starts.push_back(static_cast<float>(span.begin));
      starts.push_back(static_cast<float>(span.rate));
      for (int64_t j = span.first_warped; j < span.end_warped; ++j) {
        rows.push_back(static_cast<float>(n));
        rows.push_back(static_cast<float>(span.RealPosition(j)));
        WarpedFeatureRow(source, span.rate, j, flags.fold_tempo, bar_frames, row.data());
        if (flags.bar_beats > 0) {
          rows.push_back(row[kBarPhaseCosIndex]);
          rows.push_back(row[kBarPhaseSinIndex]);
        }
        if (flags.fold_tempo) {
          rows.insert(rows.end(), row.begin() + kTempogramBegin, row.begin() + kTempogramBegin + kNumTempogram);
          rows.push_back(row[kTempoIndex]);
        }
      }
    }
    const int cols = (flags.bar_beats > 0 ? 4 : 2) + (flags.fold_tempo ? kNumTempogram + 1 : 0);
    if (absl::Status s = WriteNpyFloat32(flags.clock, rows, static_cast<int64_t>(rows.size() / cols), cols);
        !s.ok()) {
      return s;
    }
    if (!flags.clock_starts.empty()) {
      if (absl::Status s = WriteNpyFloat32(flags.clock_starts, starts, frames, 2); !s.ok()) return s;
    }
  }
  if (flags.summary) {
    const double tempo =
        frames > 0 ? 120.0 * std::exp2(all.features[(frames - 1) * kNumFeatures + kTempoIndex])
                   : 0.0;
    // Song-level tempo: median of the running tempo after the first 10 s (the tracker's warm-up).
    std::vector<float> running;
    for (int64_t n = std::min<int64_t>(300, frames / 2); n < frames; ++n) {
      running.push_back(all.features[n * kNumFeatures + kTempoIndex]);
    }
    double median = 0.0;
    if (!running.empty()) {
      std::nth_element(running.begin(), running.begin() + running.size() / 2, running.end());
      median = 120.0 * std::exp2(running[running.size() / 2]);
    }
    nlohmann::json beats = nlohmann::json::array();
    for (double t : all.beat_times_s) beats.push_back(std::round(t * 1000.0) / 1000.0);
    nlohmann::json summary = {{"audio", flags.audio},
                              {"sample_rate", audio->sample_rate},
                              {"channels", audio->channels},
                              {"duration_s", audio->duration_s()},
                              {"frames", frames},
                              {"dims", kNumFeatures},
                              {"pre_dims", kPreDims},
                              {"tempo_bpm", std::round(tempo * 100.0) / 100.0},
                              {"tempo_median_bpm", std::round(median * 100.0) / 100.0},
                              {"sanitized_samples", sanitized},
                              {"beats_s", beats}};
    std::cout << summary.dump() << std::endl;
  }
  return absl::OkStatus();
}

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  absl::Status s = ParseFlags(argc, argv, &flags);
  if (absl::IsCancelled(s)) {
    std::cout << kUsage;
    return 0;
  }
  if (!s.ok()) {
    std::cerr << "dance-features: " << s.message() << "\n" << kUsage;
    return 2;
  }
  s = Run(flags);
  if (!s.ok()) {
    std::cerr << "dance-features: " << s << "\n";
    return 1;
  }
  return 0;
}
