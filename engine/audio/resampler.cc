#include "engine/audio/resampler.h"

#include <soxr.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <numeric>

#include "absl/base/internal/raw_logging.h"
#include "absl/strings/str_cat.h"
#include "engine/audio/decoder.h"
#include "engine/audio/feature_layout.h"
#include "engine/audio/flush_denormals.h"

namespace dance::engine::audio {

void Resampler::SoxrDeleter::operator()(void* p) const { soxr_delete(static_cast<soxr_t>(p)); }

namespace {

soxr_t NewSoxr(int input_rate, soxr_error_t* error) {
  const soxr_io_spec_t io = soxr_io_spec(SOXR_FLOAT32_I, SOXR_FLOAT32_I);
  const soxr_quality_spec_t quality = soxr_quality_spec(SOXR_HQ, SOXR_MINIMUM_PHASE);
  const soxr_runtime_spec_t runtime = soxr_runtime_spec(1);
  return soxr_create(input_rate, kSampleRate, 1, error, &io, &quality, &runtime);
}

// soxr aligns its output on the filter's peak, so even its minimum-phase filters respond a little
// before an input sample's time. Measured once per rate: impulses at several sub-sample phases; the
// earliest response above 1e-6 (FFT round-off lies below) gives the pre-response length in output
// samples.
int MeasurePreResponse(int input_rate) {
  static std::mutex mu;
  static std::map<int, int>* cache = new std::map<int, int>;
  std::lock_guard<std::mutex> lock(mu);
  if (auto it = cache->find(input_rate); it != cache->end()) return it->second;
  double worst = 0.0;
  for (int probe = 0; probe < 4; ++probe) {
    soxr_error_t error = nullptr;
    soxr_t s = NewSoxr(input_rate, &error);
    if (s == nullptr || error != nullptr) return 0;
    const int n = input_rate / 2;
    const int t0 = input_rate / 4 + probe * 7;
    std::vector<float> in(n, 0.0f), out(kSampleRate);
    in[t0] = 1.0f;
    size_t consumed = 0, produced = 0, tail = 0;
    soxr_process(s, in.data(), n, &consumed, out.data(), out.size(), &produced);
    soxr_process(s, nullptr, 0, &consumed, out.data() + produced, out.size() - produced, &tail);
    soxr_delete(s);
    const double t_out = static_cast<double>(t0) * kSampleRate / input_rate;
    for (size_t i = 0; i < produced + tail; ++i) {
      if (std::fabs(out[i]) > 1e-6f) {
        worst = std::max(worst, t_out - static_cast<double>(i));
        break;
      }
    }
  }
  const int samples = static_cast<int>(std::ceil(worst)) + 2;
  (*cache)[input_rate] = samples;
  return samples;
}

}  // namespace

absl::StatusOr<std::unique_ptr<Resampler>> Resampler::Create(int input_rate) {
  if (input_rate < kMinInputRate || input_rate > kMaxInputRate) {
    return absl::InvalidArgumentError(absl::StrCat("sample rate ", input_rate,
                                                   " Hz is not supported (", kMinInputRate, "..",
                                                   kMaxInputRate, " Hz)"));
  }
  std::unique_ptr<Resampler> r(new Resampler(input_rate));
  if (absl::Status s = r->Open(); !s.ok()) return s;
  return r;
}

Resampler::Resampler(int input_rate)
    : input_rate_(input_rate), passthrough_(input_rate == kSampleRate) {
  // Smallest block that is a whole number of output samples, grown to at least 10 ms.
  const int unit = input_rate / std::gcd(input_rate, kSampleRate);
  block_ = unit * std::max(1, (input_rate / 100 + unit - 1) / unit);
  history_blocks_ = std::max(1, (input_rate / 10 + block_ - 1) / block_);
  pending_.reserve(block_);
  history_.assign(static_cast<size_t>(history_blocks_) * block_, 0.0f);
  scratch_.resize(static_cast<size_t>(block_) * kSampleRate / input_rate + 4096);
  delay_ = passthrough_ ? 0 : MeasurePreResponse(input_rate);
}

Resampler::~Resampler() = default;

absl::Status Resampler::Open() {
  if (passthrough_) return absl::OkStatus();
  soxr_error_t error = nullptr;
  soxr_t s = NewSoxr(input_rate_, &error);
  if (error != nullptr || s == nullptr) {
    return absl::InternalError(absl::StrCat("soxr_create failed: ", error ? error : "unknown"));
  }
  soxr_.reset(s);
  return absl::OkStatus();
}

void Resampler::FeedBlock(const float* block, int length, std::vector<float>* out) {
  // The filter state decays into subnormals on silence: 10x slower without this (flush_denormals.h).
  ScopedFlushDenormals flush_denormals;
  auto* s = static_cast<soxr_t>(soxr_.get());
  if (!delay_emitted_) {
    // The output starts with delay_ zeros: output sample j then depends on input up to time j only.
    out->insert(out->end(), static_cast<size_t>(delay_), 0.0f);
    delay_emitted_ = true;
  }
  size_t consumed_total = 0;
  while (true) {
    size_t consumed = 0, produced = 0;
    const soxr_error_t e = soxr_process(s, block ? block + consumed_total : nullptr,
                                        block ? length - consumed_total : 0, &consumed,
                                        scratch_.data(), scratch_.size(), &produced);
    ABSL_RAW_CHECK(e == nullptr, "soxr_process failed");
    out->insert(out->end(), scratch_.begin(), scratch_.begin() + produced);
    consumed_total += consumed;
    if (block != nullptr && consumed_total >= static_cast<size_t>(length) &&
        produced < scratch_.size())
      break;
    if (block == nullptr && produced == 0) break;
  }
}

void Resampler::Push(absl::Span<const float> input, std::vector<float>* out) {
  if (passthrough_) {
    out->insert(out->end(), input.begin(), input.end());
    return;
  }
  size_t i = 0;
  while (i < input.size()) {
    const size_t take = std::min<size_t>(block_ - pending_.size(), input.size() - i);
    pending_.insert(pending_.end(), input.begin() + i, input.begin() + i + take);
    i += take;
    if (static_cast<int>(pending_.size()) == block_) {
      FeedBlock(pending_.data(), block_, out);
      std::copy(pending_.begin(), pending_.end(),
                history_.begin() + (blocks_fed_ % history_blocks_) * block_);
      ++blocks_fed_;
      pending_.clear();
    }
  }
}

void Resampler::Flush(std::vector<float>* out) {
  if (passthrough_) return;
  if (!pending_.empty()) FeedBlock(pending_.data(), static_cast<int>(pending_.size()), out);
  pending_.clear();
  FeedBlock(nullptr, 0, out);
}

void Resampler::Reset() {
  pending_.clear();
  delay_emitted_ = false;
  blocks_fed_ = 0;
  std::fill(history_.begin(), history_.end(), 0.0f);
  if (!passthrough_) ABSL_RAW_CHECK(Open().ok(), "soxr_create failed on reset");
}

ResamplerSnapshot Resampler::Snapshot() const {
  ResamplerSnapshot snap;
  snap.input_rate = input_rate_;
  snap.pending = pending_;
  snap.blocks_fed = blocks_fed_;
  const int64_t kept = std::min<int64_t>(blocks_fed_, history_blocks_);
  for (int64_t b = blocks_fed_ - kept; b < blocks_fed_; ++b) {
    const auto begin = history_.begin() + (b % history_blocks_) * block_;
    snap.history.insert(snap.history.end(), begin, begin + block_);
  }
  return snap;
}

absl::Status Resampler::Restore(const ResamplerSnapshot& snap) {
  if (snap.input_rate != input_rate_ ||
      snap.pending.size() >= static_cast<size_t>(std::max(block_, 1)) ||
      snap.history.size() % block_ != 0 ||
      static_cast<int64_t>(snap.history.size() / block_) >
          std::min<int64_t>(snap.blocks_fed, history_blocks_)) {
    return absl::InvalidArgumentError("resampler snapshot does not match this resampler");
  }
  Reset();
  if (passthrough_) return absl::OkStatus();
  // Replay the history into a fresh soxr, discarding its output: the filter then holds the same
  // past. Blocks are whole numbers of output samples, so the fresh instance's output stays
  // sample-aligned with the original's; the continuation differs only by FFT round-off inside soxr
  // (~1e-7).
  std::vector<float> discard;
  const int blocks = static_cast<int>(snap.history.size() / block_);
  for (int b = 0; b < blocks; ++b) {
    FeedBlock(snap.history.data() + static_cast<size_t>(b) * block_, block_, &discard);
    std::copy(snap.history.begin() + static_cast<size_t>(b) * block_,
              snap.history.begin() + static_cast<size_t>(b + 1) * block_,
              history_.begin() + ((snap.blocks_fed - blocks + b) % history_blocks_) * block_);
  }
  blocks_fed_ = snap.blocks_fed;
  pending_ = snap.pending;
  delay_emitted_ = snap.blocks_fed > 0;
  return absl::OkStatus();
}

}  // namespace dance::engine::audio
