#include "engine/vq/pose_encoder.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "engine/nn/status_macros.h"

namespace dance::engine {
namespace {

constexpr int kLeftHip = 1, kRightHip = 2, kLeftShoulder = 16, kRightShoulder = 17;

absl::Status BadOps(const std::string& part, const std::string& what) {
  return absl::InvalidArgumentError(absl::StrCat("weights metadata: vq.", part, ".encoder_ops: ", what));
}

}  // namespace

double WrapAngle(double a) { return M_PI - std::fmod(std::fmod(M_PI - a, 2 * M_PI) + 2 * M_PI, 2 * M_PI); }

double FacingYaw(const JointPositions& p) {
  const Eigen::Vector3d across = (p[kLeftHip] - p[kRightHip] + p[kLeftShoulder] - p[kRightShoulder]).cast<double>();
  return std::atan2(-across.z(), across.x());
}

PoseFeatures EncodePoseFeatures(const std::vector<JointPositions>& positions) {
  const int t = static_cast<int>(positions.size());
  PoseFeatures f;
  f.upper.resize(45, t);
  f.lower.resize(31, t);
  f.yaw.resize(t);
  f.root_xz.resize(t);
  for (int n = 0; n < t; ++n) {
    const JointPositions& p = positions[n];
    const double theta = FacingYaw(p);
    f.yaw[n] = theta;
    f.root_xz[n] = Eigen::Vector2d(p[0].x(), p[0].z());
    // local = R_y(-theta) (J - root_xz); R_y(-theta) = [[c, 0, -s], [0, 1, 0], [s, 0, c]].
    const double c = std::cos(theta), s = std::sin(theta);
    auto local = [&](int j) {
      const double x = p[j].x() - f.root_xz[n].x(), z = p[j].z() - f.root_xz[n].y();
      return Eigen::Vector3d(c * x - s * z, p[j].y(), s * x + c * z);
    };
    const Eigen::Vector3d pelvis = local(0);
    for (size_t i = 0; i < kUpperJoints.size(); ++i) {
      f.upper.block<3, 1>(3 * i, n) = (local(kUpperJoints[i]) - pelvis).cast<float>();
    }
    for (size_t i = 0; i < kLowerJoints.size(); ++i) {
      f.lower.block<3, 1>(3 * i, n) = (local(kLowerJoints[i]) - pelvis).cast<float>();
    }
    const double height = pelvis.y();
    f.lower.block<3, 1>(0, n) = Eigen::Vector3f(0.0f, static_cast<float>(height), 0.0f);
    double vx = 0.0, vz = 0.0, yaw_rate = 0.0;
    if (n > 0) {
      const double dx = f.root_xz[n].x() - f.root_xz[n - 1].x(), dz = f.root_xz[n].y() - f.root_xz[n - 1].y();
      vx = c * dx - s * dz;
      vz = s * dx + c * dz;
      yaw_rate = WrapAngle(theta - f.yaw[n - 1]);
    }
    f.lower(27, n) = static_cast<float>(vx);
    f.lower(28, n) = static_cast<float>(vz);
    f.lower(29, n) = static_cast<float>(yaw_rate);
    f.lower(30, n) = static_cast<float>(height);
  }
  return f;
}

absl::StatusOr<VqEncoder> VqEncoder::Load(const WeightsFile& file, const std::string& part,
                                          const RowMatrix& codebook) {
  const nlohmann::json& md = file.metadata();
  if (!md.contains("vq") || !md["vq"].contains(part) || !md["vq"][part].is_object()) {
    return absl::InvalidArgumentError(absl::StrCat("weights metadata: no vq.", part, " object"));
  }
  const nlohmann::json& meta = md["vq"][part];
  if (!meta.contains("encoder_ops") || !meta["encoder_ops"].is_array()) {
    return absl::NotFoundError(absl::StrCat("weights metadata: vq.", part,
                                            ".encoder_ops missing (a file exported before the encoder was)"));
  }
  VqEncoder enc;
  int channels = -1;
  int res_depth = 0;
  for (const nlohmann::json& jop : meta["encoder_ops"]) {
    if (!jop.is_object() || !jop.contains("op") || !jop["op"].is_string()) return BadOps(part, "op without \"op\"");
    const std::string kind = jop["op"].get<std::string>();
    Op op;
    if (kind == "conv") {
      if (!jop.contains("w") || !jop["w"].is_string() || !jop.contains("b") || !jop["b"].is_string()) {
        return BadOps(part, "conv without \"w\"/\"b\" tensor names");
      }
      Conv conv;
      for (const char* key : {"dilation", "stride", "pad"}) {
        if (jop.contains(key) && !jop[key].is_number_integer()) return BadOps(part, absl::StrCat("conv ", key, " is not an integer"));
      }
      conv.dilation = jop.value("dilation", 1);
      conv.stride = jop.value("stride", 1);
      conv.pad = jop.value("pad", 0);
      if (conv.dilation < 1 || conv.dilation > 1024 || conv.stride < 1 || conv.stride > 8 || conv.pad < 0 ||
          conv.pad > 4096) {
        return BadOps(part, "conv dilation, stride or pad out of range");
      }
      const Tensor* w = file.Find(jop["w"].get<std::string>());
      if (w == nullptr) return absl::NotFoundError(absl::StrCat("weights file: missing tensor ", jop["w"].dump()));
      if (w->shape.size() != 3 || (channels >= 0 && w->shape[1] != channels)) {
        return absl::InvalidArgumentError(absl::StrCat("weights file: conv '", w->name, "' has shape ",
                                                       ShapeToString(w->shape), ", expected [out, ", channels,
                                                       ", k]"));
      }
      const int out = static_cast<int>(w->shape[0]), in = static_cast<int>(w->shape[1]);
      const int k = static_cast<int>(w->shape[2]);
      if (channels < 0) enc.in_dim_ = in;
      for (int j = 0; j < k; ++j) {
        Eigen::MatrixXf tap(out, in);
        for (int o = 0; o < out; ++o) {
          for (int i = 0; i < in; ++i) tap(o, i) = w->data[(static_cast<size_t>(o) * in + i) * k + j];
        }
        conv.taps.push_back(std::move(tap));
      }
      DANCE_ASSIGN_OR_RETURN(conv.bias, LoadVector(file, jop["b"].get<std::string>(), out));
      // This conv reads dilation (k - 1) - pad of its input steps past its output's first, each
      // downsample_ frames so far.
      enc.lookahead_frames_ += std::max(0, conv.dilation * (k - 1) - conv.pad) * enc.downsample_;
      enc.downsample_ *= conv.stride;
      op.kind = OpKind::kConv;
      op.conv = static_cast<int>(enc.convs_.size());
      enc.convs_.push_back(std::move(conv));
      channels = out;
    } else if (kind == "relu") {
      op.kind = OpKind::kRelu;
    } else if (kind == "res_begin") {
      op.kind = OpKind::kResBegin;
      ++res_depth;
    } else if (kind == "res_end") {
      if (res_depth-- == 0) return BadOps(part, "res_end without res_begin");
      op.kind = OpKind::kResEnd;
    } else {
      return BadOps(part, absl::StrCat("unknown op '", kind, "'"));
    }
    enc.ops_.push_back(op);
  }
  if (enc.convs_.empty()) return BadOps(part, "no conv");
  if (res_depth != 0) return BadOps(part, "res_begin without res_end");
  if (channels != codebook.cols()) {
    return BadOps(part, absl::StrCat("output has ", channels, " channels, the codebook ", codebook.cols()));
  }
  enc.codebook_ = codebook;
  enc.code_norms_ = codebook.rowwise().squaredNorm();
  const std::string prefix = absl::StrCat("vq.", part, ".");
  const std::string mean = meta.contains("pose_mean") && meta["pose_mean"].is_string()
                               ? meta["pose_mean"].get<std::string>() : prefix + "pose_mean";
  const std::string std_name = meta.contains("pose_std") && meta["pose_std"].is_string()
                                   ? meta["pose_std"].get<std::string>() : prefix + "pose_std";
  DANCE_ASSIGN_OR_RETURN(enc.pose_mean_, LoadVector(file, mean, enc.in_dim_));
  DANCE_ASSIGN_OR_RETURN(enc.pose_std_, LoadVector(file, std_name, enc.in_dim_));
  return enc;
}

std::vector<int> VqEncoder::Encode(const Eigen::MatrixXf& features) const {
  const int t_in = static_cast<int>(features.cols());
  if (t_in == 0) return {};
  const int t = (t_in + downsample_ - 1) / downsample_ * downsample_;
  Eigen::MatrixXf h(in_dim_, t);
  for (int n = 0; n < t; ++n) {
    h.col(n) = ((features.col(std::min(n, t_in - 1)) - pose_mean_).array() / pose_std_.array()).matrix();
  }
  std::vector<Eigen::MatrixXf> stack;
  for (const Op& op : ops_) {
    switch (op.kind) {
      case OpKind::kConv: {
        const Conv& c = convs_[op.conv];
        const int k = static_cast<int>(c.taps.size());
        const int len = static_cast<int>(h.cols());
        const int out_len = (len + 2 * c.pad - c.dilation * (k - 1) - 1) / c.stride + 1;
        Eigen::MatrixXf out = c.bias.replicate(1, out_len);
        Eigen::MatrixXf gathered(h.rows(), out_len);
        for (int j = 0; j < k; ++j) {
          for (int o = 0; o < out_len; ++o) {
            const int src = o * c.stride + j * c.dilation - c.pad;  // zero padding outside [0, len)
            if (src >= 0 && src < len) {
              gathered.col(o) = h.col(src);
            } else {
              gathered.col(o).setZero();
            }
          }
          out.noalias() += c.taps[j] * gathered;
        }
        h = std::move(out);
        break;
      }
      case OpKind::kRelu:
        h = h.cwiseMax(0.0f);
        break;
      case OpKind::kResBegin:
        stack.push_back(h);
        break;
      case OpKind::kResEnd:
        h += stack.back();
        stack.pop_back();
        break;
    }
  }
  std::vector<int> codes(h.cols());
  for (Eigen::Index n = 0; n < h.cols(); ++n) {
    const Eigen::VectorXf d = code_norms_ - 2.0f * (codebook_ * h.col(n));
    Eigen::Index best = 0;
    d.minCoeff(&best);
    codes[n] = static_cast<int>(best);
  }
  return codes;
}

}  // namespace dance::engine
