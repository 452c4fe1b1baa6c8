#include "engine/vq/vq_decoder.h"

#include <cstring>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

absl::Status BadOps(const std::string& part, const std::string& what) {
  return absl::InvalidArgumentError(absl::StrCat("weights metadata: vq.", part, ".decoder_ops: ", what));
}

// Tensor name for `key` of part `part`: metadata may name it explicitly, else the exporter's default.
std::string TensorName(const nlohmann::json& meta, const std::string& part, const std::string& key) {
  if (meta.contains(key) && meta[key].is_string()) return meta[key].get<std::string>();
  return absl::StrCat("vq.", part, ".", key);
}

}  // namespace

absl::StatusOr<VqDecoder> VqDecoder::Load(const WeightsFile& file, const std::string& part) {
  const nlohmann::json& md = file.metadata();
  if (!md.contains("vq") || !md["vq"].contains(part) || !md["vq"][part].is_object()) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: no vq.", part, " object"));
  }
  const nlohmann::json& meta = md["vq"][part];
  if (!meta.contains("decoder_ops") || !meta["decoder_ops"].is_array()) return BadOps(part, "missing");
  const Tensor* codebook = file.Find(TensorName(meta, part, "codebook"));
  if (codebook == nullptr || codebook->shape.size() != 2) {
    return absl::NotFoundError(absl::StrCat("weights file: missing 2-D tensor '",
                                            TensorName(meta, part, "codebook"), "'"));
  }
  VqDecoder dec;
  DANCE_ASSIGN_OR_RETURN(dec.codebook_, LoadMatrix(file, codebook->name, codebook->shape[0], codebook->shape[1]));
  int channels = static_cast<int>(codebook->shape[1]);
  int frames = 1;
  std::vector<int> res_stack;
  for (const nlohmann::json& jop : meta["decoder_ops"]) {
    if (!jop.is_object() || !jop.contains("op") || !jop["op"].is_string()) return BadOps(part, "op without \"op\"");
    const std::string kind = jop["op"].get<std::string>();
    Op op;
    if (kind == "embed_codes") {
      if (!dec.ops_.empty()) return BadOps(part, "embed_codes must come first");
      op.kind = OpKind::kEmbed;
    } else if (dec.ops_.empty()) {
      return BadOps(part, "the first op must be embed_codes");
    } else if (kind == "conv") {
      if (!jop.contains("w") || !jop["w"].is_string() || !jop.contains("b") || !jop["b"].is_string()) {
        return BadOps(part, "conv without \"w\"/\"b\" tensor names");
      }
      const int dilation = jop.value("dilation", 1);
      if (dilation < 1 || dilation > 1024) return BadOps(part, "conv dilation out of range");
      const Tensor* w = file.Find(jop["w"].get<std::string>());
      if (w == nullptr) return absl::NotFoundError(absl::StrCat("weights file: missing tensor ", jop["w"].dump()));
      if (w->shape.size() != 3 || w->shape[1] != channels) {
        return absl::InvalidArgumentError(absl::StrCat("weights file: conv '", w->name, "' has shape ",
                                                       ShapeToString(w->shape), ", expected [out, ", channels,
                                                       ", k]"));
      }
      const int out = static_cast<int>(w->shape[0]), in = channels, k = static_cast<int>(w->shape[2]);
      Conv conv;
      conv.in = in;
      conv.k = k;
      conv.dilation = dilation;
      conv.history = (k - 1) * dilation;
      conv.weight.resize(out, static_cast<Eigen::Index>(k) * in);
      for (int o = 0; o < out; ++o) {
        for (int j = 0; j < k; ++j) {
          for (int i = 0; i < in; ++i) conv.weight(o, j * in + i) = w->data[(static_cast<size_t>(o) * in + i) * k + j];
        }
      }
      DANCE_ASSIGN_OR_RETURN(conv.bias, LoadVector(file, jop["b"].get<std::string>(), out));
      op.kind = OpKind::kConv;
      op.conv = static_cast<int>(dec.convs_.size());
      dec.convs_.push_back(std::move(conv));
      channels = out;
    } else if (kind == "relu") {
      op.kind = OpKind::kRelu;
    } else if (kind == "res_begin") {
      op.kind = OpKind::kResBegin;
      res_stack.push_back(static_cast<int>(dec.ops_.size()));
    } else if (kind == "res_end") {
      if (res_stack.empty()) return BadOps(part, "res_end without res_begin");
      op.kind = OpKind::kResEnd;
      op.partner = res_stack.back();
      res_stack.pop_back();
      const Op& begin = dec.ops_[op.partner];
      if (begin.channels != channels || begin.frames != frames) {
        return BadOps(part, "residual body changes the shape");
      }
    } else if (kind == "upsample2") {
      op.kind = OpKind::kUpsample2;
      frames *= 2;
      if (frames > 64) return BadOps(part, "too many upsample2 ops");
    } else {
      return BadOps(part, absl::StrCat("unknown op '", kind, "'"));
    }
    op.channels = channels;
    op.frames = frames;
    dec.ops_.push_back(op);
  }
  if (dec.ops_.empty()) return BadOps(part, "empty");
  if (!res_stack.empty()) return BadOps(part, "res_begin without res_end");
  dec.out_dim_ = channels;
  dec.frames_per_code_ = frames;
  DANCE_ASSIGN_OR_RETURN(dec.pose_mean_, LoadVector(file, TensorName(meta, part, "pose_mean"), channels));
  DANCE_ASSIGN_OR_RETURN(dec.pose_std_, LoadVector(file, TensorName(meta, part, "pose_std"), channels));
  return dec;
}

VqDecoderState VqDecoder::NewState() const {
  VqDecoderState s;
  for (const Op& op : ops_) {
    if (op.kind != OpKind::kConv) continue;
    const Conv& c = convs_[op.conv];
    s.history.push_back(Eigen::MatrixXf::Zero(c.in, c.history));
  }
  return s;
}

VqDecoderScratch VqDecoder::NewScratch(int lanes) const {
  VqDecoderScratch s;
  s.capacity = lanes;
  int in_frames = 1;
  for (const Op& op : ops_) {
    s.outputs.push_back(Eigen::MatrixXf::Zero(op.channels, static_cast<Eigen::Index>(op.frames) * lanes));
    if (op.kind == OpKind::kConv) {
      const Conv& c = convs_[op.conv];
      s.columns.push_back(Eigen::MatrixXf::Zero(static_cast<Eigen::Index>(c.k) * c.in,
                                                static_cast<Eigen::Index>(in_frames) * lanes));
    }
    in_frames = op.frames;
  }
  return s;
}

bool VqDecoder::Fits(const VqDecoderScratch& scratch, int lanes) const {
  if (lanes > scratch.capacity || scratch.outputs.size() != ops_.size() ||
      scratch.columns.size() != convs_.size()) {
    return false;
  }
  for (size_t i = 0; i < ops_.size(); ++i) {
    if (scratch.outputs[i].rows() != ops_[i].channels) return false;
  }
  return true;
}

VqDecoder::FramesView VqDecoder::Decode(int code, VqDecoderState& state,
                                                      VqDecoderScratch& scratch) const {
  VqDecoderState* states[1] = {&state};
  return DecodeBatch(absl::MakeConstSpan(&code, 1), states, scratch);
}

VqDecoder::FramesView VqDecoder::DecodeBatch(absl::Span<const int> codes,
                                                           absl::Span<VqDecoderState* const> states,
                                                           VqDecoderScratch& scratch) const {
  const int lanes = static_cast<int>(codes.size());
  if (!Fits(scratch, lanes)) scratch = NewScratch(std::max(lanes, scratch.capacity));
  int conv_index = 0;
  for (size_t i = 0; i < ops_.size(); ++i) {
    const Op& op = ops_[i];
    auto out = scratch.outputs[i].leftCols(static_cast<Eigen::Index>(op.frames) * lanes);
    const int t = i > 0 ? ops_[i - 1].frames : 1;  // input frames per lane
    auto in = i > 0 ? scratch.outputs[i - 1].leftCols(static_cast<Eigen::Index>(t) * lanes)
                    : scratch.outputs[0].leftCols(lanes);
    switch (op.kind) {
      case OpKind::kEmbed:
        for (int b = 0; b < lanes; ++b) out.col(b) = codebook_.row(codes[b]).transpose();
        break;
      case OpKind::kConv: {
        // im2col over [history | input] per lane, then one GEMM for all taps and lanes.
        const Conv& c = convs_[op.conv];
        auto cols = scratch.columns[conv_index].leftCols(static_cast<Eigen::Index>(t) * lanes);
        for (int b = 0; b < lanes; ++b) {
          Eigen::MatrixXf& hist = states[b]->history[conv_index];
          const auto x = in.middleCols(static_cast<Eigen::Index>(b) * t, t);
          for (int j = 0; j < c.k; ++j) {
            // Output frame f reads padded column f + j * dilation; padded = [hist (H) | x (t)].
            for (int f = 0; f < t; ++f) {
              const int p = f + j * c.dilation;
              auto dst = cols.block(static_cast<Eigen::Index>(j) * c.in, static_cast<Eigen::Index>(b) * t + f, c.in, 1);
              if (p < c.history) {
                dst = hist.col(p);
              } else {
                dst = x.col(p - c.history);
              }
            }
          }
          // New history: the last H columns of [hist | x].
          if (c.history > 0) {
            if (t >= c.history) {
              hist = x.rightCols(c.history);
            } else {
              for (int f = 0; f < c.history - t; ++f) hist.col(f) = hist.col(f + t);
              hist.rightCols(t) = x;
            }
          }
        }
        MatMul(c.weight, cols, out);
        out.colwise() += c.bias;
        ++conv_index;
        break;
      }
      case OpKind::kRelu:
        out = in.cwiseMax(0.0f);
        break;
      case OpKind::kResBegin:
        out = in;
        break;
      case OpKind::kResEnd:
        out = in + scratch.outputs[op.partner].leftCols(static_cast<Eigen::Index>(op.frames) * lanes);
        break;
      case OpKind::kUpsample2:
        for (Eigen::Index f = 0; f < in.cols(); ++f) {
          out.col(2 * f) = in.col(f);
          out.col(2 * f + 1) = in.col(f);
        }
        break;
    }
  }
  const Eigen::Index n = static_cast<Eigen::Index>(frames_per_code_) * lanes;
  auto y = scratch.outputs.back().leftCols(n);
  y = (y.array().colwise() * pose_std_.array()).colwise() + pose_mean_.array();
  return static_cast<const Eigen::MatrixXf&>(scratch.outputs.back()).leftCols(n);
}

}  // namespace dance::engine
