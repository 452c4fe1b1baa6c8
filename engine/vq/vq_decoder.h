// Streaming causal VQ-VAE decoder of one body part (docs/model.md section 7), run as data from the op
// list in the weights file's metadata (`vq.<part>.decoder_ops`): one code in, 4 normalised-then-
// denormalised pose frames out. Every conv is causal, so the decoder keeps, per conv, its last
// (k - 1) * dilation inputs (VqDecoderState), exactly like training/model/vqvae.py DecoderStream.
//
// Usage:
//   absl::StatusOr<VqDecoder> dec = VqDecoder::Load(weights, "upper");
//   VqDecoderState state = dec->NewState();
//   VqDecoderScratch scratch = dec->NewScratch();
//   const Eigen::MatrixXf& frames = dec->Decode(code, state, scratch);   // (out_dim, 4) pose features
//
// Thread safety: the decoder is immutable after Load and shareable; state and scratch belong to one
// caller. Decode does not allocate.
#ifndef DANCE_ENGINE_VQ_VQ_DECODER_H_
#define DANCE_ENGINE_VQ_VQ_DECODER_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "engine/nn/layers.h"
#include "engine/nn/weights_file.h"

namespace dance::engine {

// Per-conv input history, oldest column first; copyable (snapshot = copy).
struct VqDecoderState {
  std::vector<Eigen::MatrixXf> history;  // per conv: (in_channels, (k - 1) * dilation)
  void Clear() {
    for (Eigen::MatrixXf& h : history) h.setZero();
  }
  int64_t Bytes() const {
    int64_t n = 0;
    for (const Eigen::MatrixXf& h : history) n += h.size();
    return n * static_cast<int64_t>(sizeof(float));
  }
};

// Preallocated activations for up to `capacity` lanes: per op (channels, frames at that op x lanes), lane b
// in columns [b * frames, (b + 1) * frames); per conv an im2col matrix (k * in_channels, frames x lanes).
struct VqDecoderScratch {
  int capacity = 0;
  std::vector<Eigen::MatrixXf> outputs;
  std::vector<Eigen::MatrixXf> columns;
};

class VqDecoder {
 public:
  // Columns of the scratch's output, valid until the scratch is used again.
  using FramesView = Eigen::Block<const Eigen::MatrixXf, Eigen::Dynamic, Eigen::Dynamic, true>;

  // Loads part `part` ("upper" or "lower") from metadata["vq"][part] and its tensors.
  static absl::StatusOr<VqDecoder> Load(const WeightsFile& file, const std::string& part);

  VqDecoderState NewState() const;
  // Scratch for batches of up to `lanes` codes (grows on demand in DecodeBatch).
  VqDecoderScratch NewScratch(int lanes = 1) const;

  // Decodes one code in [0, codebook_size) into frames_per_code() denormalised pose feature frames,
  // (out_dim, frames_per_code), valid until the next call with the same scratch.
  FramesView Decode(int code, VqDecoderState& state, VqDecoderScratch& scratch) const;
  // Decodes one code per lane with one GEMM per conv over all lanes. Lane b's frames are columns
  // [b * frames_per_code, (b + 1) * frames_per_code) of the result, (out_dim, frames_per_code * L).
  // Allocates only when the batch exceeds the scratch's capacity (or the scratch is another decoder's).
  FramesView DecodeBatch(absl::Span<const int> codes,
                                                  absl::Span<VqDecoderState* const> states,
                                                  VqDecoderScratch& scratch) const;

  int out_dim() const { return out_dim_; }
  int codebook_size() const { return static_cast<int>(codebook_.rows()); }
  // The codebook, (K, code_dim).
  const RowMatrix& codebook() const { return codebook_; }
  int frames_per_code() const { return frames_per_code_; }

 private:
  enum class OpKind { kEmbed, kConv, kRelu, kResBegin, kResEnd, kUpsample2 };
  struct Conv {
    RowMatrix weight;     // (out, k * in): column block j (tap j) multiplies input t - (k - 1 - j) * dilation
    Eigen::VectorXf bias; // (out)
    int in = 0, k = 0;
    int dilation = 1;
    int history = 0;      // (k - 1) * dilation
  };
  struct Op {
    OpKind kind;
    int conv = -1;      // index into convs_ for kConv
    int partner = -1;   // for kResEnd: the op index of its kResBegin
    int channels = 0;   // output rows
    int frames = 0;     // output columns
  };

  // Whether `scratch` was made by this decoder for at least `lanes` lanes.
  bool Fits(const VqDecoderScratch& scratch, int lanes) const;

  std::vector<Op> ops_;
  std::vector<Conv> convs_;
  RowMatrix codebook_;         // (K, code_dim)
  Eigen::VectorXf pose_mean_;  // (out_dim)
  Eigen::VectorXf pose_std_;   // (out_dim)
  int out_dim_ = 0;
  int frames_per_code_ = 0;
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_VQ_VQ_DECODER_H_
