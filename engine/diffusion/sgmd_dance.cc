#include "engine/diffusion/sgmd_dance.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "Eigen/Geometry"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "engine/diffusion/ddim.h"
#include "engine/diffusion/motion_vector.h"
#include "engine/nn/status_macros.h"
#include "engine/vq/foot_lock.h"
#include "engine/vq/pose_reconstructor.h"

namespace dance::engine {
namespace {

using audio::FeatureFrames;

constexpr int kPelvis = 0;

// The floor path's point at audio time t (linear between points); false outside its span.
bool PathAt(const std::vector<TrajectoryPoint>& path, double t_s, double* x, double* z) {
  if (path.size() < 2 || t_s < path.front().t_s || t_s > path.back().t_s) return false;
  const auto it = std::upper_bound(path.begin(), path.end(), t_s,
                                   [](double t, const TrajectoryPoint& p) { return t < p.t_s; });
  if (it == path.end()) {
    *x = path.back().x;
    *z = path.back().z;
    return true;
  }
  const TrajectoryPoint& b = *it;
  const TrajectoryPoint& a = *(it - 1);
  const double w = (t_s - a.t_s) / (b.t_s - a.t_s);
  *x = a.x + w * (b.x - a.x);
  *z = a.z + w * (b.z - a.z);
  return true;
}

// The music input of the window starting at frame `start` (music_dim, n): per token its frames'
// normalised features then PRE; frames past the song repeat its last frame.
Eigen::MatrixXf WindowMusic(const SgmdModel& model, const FeatureFrames& song, int64_t start) {
  const SgmdConfig& c = model.config();
  const int f_dim = c.feature_dim, p_dim = c.pre_dim, k = c.frames_per_token;
  Eigen::MatrixXf m(c.music_dim(), c.tokens());
  const int64_t last = song.frames() - 1;
  for (int i = 0; i < c.tokens(); ++i) {
    for (int j = 0; j < k; ++j) {
      const int64_t n = std::min<int64_t>(start + int64_t{k} * i + j, last);
      float* col = m.col(i).data() + j * (f_dim + p_dim);
      const float* f = song.features.data() + n * f_dim;
      const float* p = song.pre.data() + n * p_dim;
      for (int d = 0; d < f_dim; ++d) col[d] = (f[d] - model.music_mean()(d)) / model.music_std()(d);
      for (int d = 0; d < p_dim; ++d) col[f_dim + d] = p[d];
    }
  }
  return m;
}

// The window's canonical frame when nothing before it is known: the first frame's given pelvis and facing,
// else the path's point there (facing +Z), else the world's.
CanonicalFrame FirstFrame(const Controls& controls, int64_t m) {
  if (controls.motion.KnownAt(m) != 0) {
    return FrameOf(controls.motion.positions[m - controls.motion.first_frame]);
  }
  CanonicalFrame f;
  double x = 0.0, z = 0.0;
  if (PathAt(controls.trajectory, m / 30.0, &x, &z)) {
    f.x = x;
    f.z = z;
  }
  return f;
}

// Known values (denormalised) and mask of one window from the controls (docs/diffusion.md section 6), for
// its frames at or after `from` (the frames before come from the previous window).
void ControlKnown(const Controls& controls, const CanonicalFrame& frame, int64_t start, int n_frames, int from,
                  Eigen::MatrixXf& values, Eigen::MatrixXf& mask) {
  const double cy = std::cos(frame.yaw), sy = std::sin(frame.yaw);
  for (int i = from; i < n_frames; ++i) {
    const int64_t m = start + i;
    const JointMask known = controls.motion.KnownAt(m);
    if (known != 0) {
      const JointPositions local = ToFrame(controls.motion.positions[m - controls.motion.first_frame], frame);
      const Eigen::VectorXf v = PoseVector(local);
      // Any given joint gives the pelvis and facing too: local dims are relative to the pelvis, so given
      // joints are exact in the world only on the given pose's pelvis (a given upper body carries its root).
      values.col(i).segment(kMotionRoot, 5) = v.segment(kMotionRoot, 5);
      mask.col(i).segment(kMotionRoot, 5).setOnes();
      for (int j = 1; j < kNumJoints; ++j) {
        if (!(known & (JointMask{1} << j))) continue;
        const int d = kMotionLocal + 3 * (j - 1);
        values.col(i).segment(d, 3) = v.segment(d, 3);
        mask.col(i).segment(d, 3).setOnes();
      }
    }
    if (controls.trajectory.empty() || known != 0) continue;
    double x = 0.0, z = 0.0;
    if (PathAt(controls.trajectory, m / 30.0, &x, &z)) {
      // p' = R_y(-yaw) (p - o); R_y(a) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
      const double dx = x - frame.x, dz = z - frame.z;
      values(kMotionRoot + 0, i) = static_cast<float>(cy * dx - sy * dz);
      values(kMotionRoot + 2, i) = static_cast<float>(sy * dx + cy * dz);
      mask(kMotionRoot + 0, i) = 1.0f;
      mask(kMotionRoot + 2, i) = 1.0f;
    }
  }
  // Facings on the frames nearest the path's points that give one (where no given pelvis speaks).
  for (const TrajectoryPoint& p : controls.trajectory) {
    if (!p.facing) continue;
    const int64_t i = static_cast<int64_t>(std::llround(p.t_s * 30.0)) - start;
    if (i < from || i >= n_frames) continue;
    if (controls.motion.KnownAt(start + i) != 0) continue;
    const double a = *p.facing - frame.yaw;
    values(kMotionHeading + 0, i) = static_cast<float>(std::sin(a));
    values(kMotionHeading + 1, i) = static_cast<float>(std::cos(a));
    mask(kMotionHeading + 0, i) = 1.0f;
    mask(kMotionHeading + 1, i) = 1.0f;
  }
}

// Whether frame m's lower body is given (the foot lock leaves it alone).
bool LowerGiven(const Controls& controls, int64_t m) {
  return (controls.motion.KnownAt(m) & LowerMask()) != 0;
}

// 1 at u = 0 down to 0 at u = 1, flat at both ends.
double FadeOut(double u) { return 1.0 - u * u * (3.0 - 2.0 * u); }

// The seam blend (SgmdDanceOptions::seam_blend_frames): per joint, at every frame where generated motion
// starts after motion it did not make (a window's first new frame, the end of a given span) or ends before
// a given frame, the offset between the generated frame and the constant-velocity continuation of the
// other side is removed there and faded out over `k` generated frames. Given joints stay exactly given.
void BlendSeams(const Controls& controls, const std::vector<int64_t>& window_seams, int k,
                std::vector<JointPositions>& world, int64_t total) {
  if (k <= 0 || total < 2) return;
  auto given = [&](int64_t m, int j) { return (controls.motion.KnownAt(m) & (JointMask{1} << j)) != 0; };
  // Frames b.. after a boundary (forward) or ..b before one (backward, dir -1): remove `offset` faded.
  auto fade = [&](int64_t b, int dir, int j, const Eigen::Vector3f& offset) {
    for (int i = 0; i < k; ++i) {
      const int64_t m = b + dir * i;
      if (m < 0 || m >= total || given(m, j)) break;
      world[m][j] -= static_cast<float>(FadeOut(static_cast<double>(i) / k)) * offset;
    }
  };
  // The continuation of frames a (the last one of the other side) and a - dir (the one before, if it is
  // on the same side) into a + dir.
  auto continuation = [&](int64_t a, int dir, int j, bool same_side) {
    const int64_t before = a - dir;
    if (same_side && before >= 0 && before < total) return Eigen::Vector3f(2.0f * world[a][j] - world[before][j]);
    return world[a][j];
  };
  std::vector<int64_t> seams = window_seams;
  std::sort(seams.begin(), seams.end());
  size_t next_seam = 0;
  for (int64_t m = 1; m < total; ++m) {
    const bool window_seam = next_seam < seams.size() && seams[next_seam] == m;
    if (window_seam) ++next_seam;
    for (int j = 0; j < kNumJoints; ++j) {
      const bool g0 = given(m - 1, j), g1 = given(m, j);
      if (!g1 && (g0 || window_seam)) {
        // Generated from m on, after frames it did not make.
        const bool prev_same = m >= 2 && (window_seam || given(m - 2, j));
        fade(m, +1, j, world[m][j] - continuation(m - 1, +1, j, prev_same));
      } else if (!g0 && g1) {
        // Generated up to m - 1, before a given frame.
        const bool next_same = m + 1 < total && given(m + 1, j);
        fade(m - 1, -1, j, world[m - 1][j] - continuation(m, -1, j, next_same));
      }
    }
  }
}

}  // namespace

namespace sgmd_internal {

// The glitch repair (SgmdDanceOptions::glitch_max_frames): returns the frames replaced.
int64_t RepairGlitches(const Controls& controls, int max_run, std::vector<JointPositions>& world, int64_t total) {
  constexpr int kHalf = 8;                    // the median's window: 17 frames
  constexpr double kMaxOffset = 0.25;         // m on the floor
  constexpr double kMaxTurn = 60.0 * M_PI / 180.0;
  if (max_run <= 0 || total < 2 * kHalf + 1) return 0;
  // A frame with any given joint is never touched (moving its pelvis would move the given joints with it).
  auto any_given = [&](int64_t m) { return controls.motion.KnownAt(m) != 0; };
  std::vector<double> yaw(static_cast<size_t>(total));
  for (int64_t m = 0; m < total; ++m) yaw[m] = FrameOf(world[m]).yaw;
  std::vector<char> bad(static_cast<size_t>(total), 0);
  std::vector<double> xs, zs, ss, cs;
  for (int64_t m = 0; m < total; ++m) {
    if (any_given(m)) continue;
    xs.clear();
    zs.clear();
    ss.clear();
    cs.clear();
    for (int64_t k = std::max<int64_t>(0, m - kHalf); k <= std::min<int64_t>(total - 1, m + kHalf); ++k) {
      xs.push_back(world[k][kPelvis].x());
      zs.push_back(world[k][kPelvis].z());
      ss.push_back(std::sin(yaw[k]));
      cs.push_back(std::cos(yaw[k]));
    }
    auto median = [](std::vector<double>& v) {
      std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
      return v[v.size() / 2];
    };
    const double mx = median(xs), mz = median(zs), my = std::atan2(median(ss), median(cs));
    const double off = std::hypot(world[m][kPelvis].x() - mx, world[m][kPelvis].z() - mz);
    const double turn = std::abs(std::remainder(yaw[m] - my, 2.0 * M_PI));
    bad[m] = off > kMaxOffset || turn > kMaxTurn;
  }
  int64_t repaired = 0;
  for (int64_t a = 0; a < total;) {
    if (!bad[a]) {
      ++a;
      continue;
    }
    int64_t b = a;
    while (b + 1 < total && bad[b + 1]) ++b;
    // [a, b] is a run; good frames a - 1 and b + 1 around it (or one side at the ends of the dance).
    if (b - a + 1 <= max_run && (a > 0 || b + 1 < total)) {
      const int64_t lo = a - 1, hi = b + 1;
      for (int64_t m = a; m <= b; ++m) {
        const double w = lo < 0 ? 1.0 : hi >= total ? 0.0 : static_cast<double>(m - lo) / static_cast<double>(hi - lo);
        const JointPositions& p = lo < 0 ? world[hi] : world[lo];
        const JointPositions& q = hi >= total ? world[lo] : world[hi];
        for (int j = 0; j < kNumJoints; ++j) {
          world[m][j] = ((1.0 - w) * p[j].cast<double>() + w * q[j].cast<double>()).cast<float>();
        }
      }
      repaired += b - a + 1;
    }
    a = b + 1;
  }
  return repaired;
}

int ReanchorSeams(const Controls& controls, const std::vector<int64_t>& window_seams, int search,
                  std::vector<JointPositions>& world, int64_t total) {
  constexpr double kMinBreak = 0.08;  // m (+ 0.5 m per radian of facing): smaller ones are the blend's
  if (search <= 0) return 0;
  // Frames with any given joint stay where they are (and so do the frames the re-anchoring would move
  // past them).
  auto any_given = [&](int64_t m) { return controls.motion.KnownAt(m) != 0; };
  auto on_path = [&](int64_t m) {
    return !controls.trajectory.empty() && m / 30.0 >= controls.trajectory.front().t_s &&
           m / 30.0 <= controls.trajectory.back().t_s;
  };
  auto yaw = [&](int64_t m) { return FrameOf(world[m]).yaw; };
  auto floor = [&](int64_t m) { return Eigen::Vector3f(world[m][kPelvis].x(), 0.0f, world[m][kPelvis].z()); };
  int moved = 0;
  for (int64_t seam : window_seams) {
    if (seam < 2) continue;
    double worst = 0.0, turn = 0.0;
    int64_t at = -1;
    Eigen::Vector3f target = Eigen::Vector3f::Zero();
    if (any_given(seam - 1) || any_given(seam - 2)) continue;
    // The continuation of the two frames before the seam, k frames on.
    const double yaw_step = std::remainder(yaw(seam - 1) - yaw(seam - 2), 2.0 * M_PI);
    const Eigen::Vector3f step = floor(seam - 1) - floor(seam - 2);
    for (int64_t i = seam; i < std::min(total, seam + search); ++i) {
      if (any_given(i) || on_path(i)) break;
      const double k = static_cast<double>(i - seam + 1);
      const double yaw_next = yaw(seam - 1) + k * yaw_step;
      const Eigen::Vector3f next = floor(seam - 1) + static_cast<float>(k) * step;
      const double d_yaw = std::remainder(yaw_next - yaw(i), 2.0 * M_PI);
      const double e = (floor(i) - next).norm() + 0.5 * std::abs(d_yaw);
      if (e > worst) {
        worst = e;
        at = i;
        turn = d_yaw;
        target = next;
      }
    }
    if (at < 0 || worst <= kMinBreak) continue;
    // The rest of the dance (up to a frame with a given joint, or the path) turns about frame `at`'s pelvis and moves
    // it onto the continuation; later windows were made from these frames, so they move with them.
    const Eigen::Matrix3f r = Eigen::AngleAxisf(static_cast<float>(turn), Eigen::Vector3f::UnitY()).toRotationMatrix();
    const Eigen::Vector3f pivot = floor(at);
    for (int64_t m = at; m < total && !any_given(m) && !on_path(m); ++m) {
      for (Eigen::Vector3f& q : world[m]) q = r * (q - pivot) + target;
    }
    ++moved;
  }
  return moved;
}

}  // namespace sgmd_internal

absl::StatusOr<FeatureFrames> SongFeatures(const audio::DecodedAudio& audio) {
  return audio::ComputeSongFeatures(audio);
}

absl::StatusOr<Eigen::VectorXf> SgmdStyleWeights(const SgmdModel& model,
                                                 const std::vector<std::pair<std::string, float>>& mix) {
  const int n = static_cast<int>(model.styles().size());
  Eigen::VectorXf w = Eigen::VectorXf::Zero(n + 1);
  double total = 0.0;
  for (const auto& [name, weight] : mix) {
    if (!(weight >= 0.0f) || !std::isfinite(weight)) {
      return absl::InvalidArgumentError(absl::StrCat("style '", name, "': weight must be finite and >= 0, got ",
                                                     weight));
    }
    int row = -1;
    if (name == "none") row = n;
    for (int i = 0; i < n && row < 0; ++i) {
      if (model.styles()[i] == name) row = i;
    }
    if (row < 0) {
      return absl::NotFoundError(absl::StrCat("unknown style '", name, "' (known: ", absl::StrJoin(model.styles(), ", "),
                                              ", none)"));
    }
    w(row) += weight;
    total += weight;
  }
  if (mix.empty()) {
    w(n) = 1.0f;
    total = 1.0;
  }
  if (!(total > 0.0)) return absl::InvalidArgumentError("style weights sum to 0");
  w /= static_cast<float>(total);
  return w;
}

absl::StatusOr<SgmdDance> GenerateSgmdDance(const SgmdModel& model, const FeatureFrames& song,
                                            const SgmdDanceOptions& options) {
  const SgmdConfig& c = model.config();
  const SgmdSamplingDefaults& def = model.sampling_defaults();
  if (options.steps < 0) return absl::InvalidArgumentError(absl::StrCat("steps must be >= 1, got ", options.steps));
  if (options.guidance < 0.0f) {
    return absl::InvalidArgumentError(absl::StrCat("guidance must be > 0, got ", options.guidance));
  }
  if (options.reanchor_search_frames < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("re-anchoring must search >= 0 frames, got ", options.reanchor_search_frames));
  }
  if (options.glitch_max_frames < 0) {
    return absl::InvalidArgumentError(absl::StrCat("glitch repair must be >= 0 frames, got ", options.glitch_max_frames));
  }
  if (options.seam_blend_frames < 0) {
    return absl::InvalidArgumentError(absl::StrCat("seam blend must be >= 0 frames, got ", options.seam_blend_frames));
  }
  if (options.overlap_frames < -1) {
    return absl::InvalidArgumentError(absl::StrCat("overlap must be >= 0, got ", options.overlap_frames));
  }
  SgmdDance out;
  out.steps = options.steps > 0 ? options.steps : def.steps;
  out.guidance = options.guidance > 0.0f ? options.guidance : def.guidance;
  out.overlap_frames = options.overlap_frames >= 0 ? options.overlap_frames : def.overlap_frames;
  if (out.steps < 1 || out.steps > c.diffusion_steps) {
    return absl::InvalidArgumentError(absl::StrCat("steps must be 1..", c.diffusion_steps, ", got ", out.steps));
  }
  if (!(out.guidance > 0.0f) || !std::isfinite(out.guidance) || out.guidance > 100.0f) {
    return absl::InvalidArgumentError(absl::StrCat("guidance must be in (0, 100], got ", out.guidance));
  }
  if (out.overlap_frames >= c.frames) {
    return absl::InvalidArgumentError(absl::StrCat("overlap must be below the window (", c.frames,
                                                   " frames), got ", out.overlap_frames));
  }
  DANCE_RETURN_IF_ERROR(ValidateControls(options.controls));
  DANCE_ASSIGN_OR_RETURN(Eigen::VectorXf style_w, SgmdStyleWeights(model, options.style));
  const Eigen::VectorXf sv = model.StyleVector(style_w);
  const int64_t total = song.frames();
  if (total == 0) return out;
  if (song.pre.size() != static_cast<size_t>(total * c.pre_dim) || c.feature_dim != audio::kNumFeatures) {
    return absl::InvalidArgumentError("song features do not match the model's feature layout");
  }

  const int n = c.frames;
  std::vector<int64_t> starts = {0};
  while (starts.back() + n < total) starts.push_back(std::min<int64_t>(starts.back() + n - out.overlap_frames, total - n));
  out.windows = static_cast<int>(starts.size());
  const int64_t all_steps = static_cast<int64_t>(starts.size()) * out.steps;

  std::vector<JointPositions> world(static_cast<size_t>(std::max<int64_t>(total, n)));
  std::vector<int64_t> window_seams;  // each window's first new frame after the first window
  int64_t done = 0;
  std::mt19937_64 gen(options.seed);
  const SgmdModel::Context none = model.NullContext();
  bool cancelled = false;
  for (size_t w = 0; w < starts.size() && !cancelled; ++w) {
    const int64_t s = starts[w];
    const int shared = static_cast<int>(std::max<int64_t>(0, done - s));
    if (shared > 0 && done < total) window_seams.push_back(done);
    const CanonicalFrame frame = shared > 0 ? FrameOf(world[s]) : FirstFrame(options.controls, s);
    Eigen::MatrixXf values = Eigen::MatrixXf::Zero(c.pose_dim, n);
    Eigen::MatrixXf mask = Eigen::MatrixXf::Zero(c.pose_dim, n);
    if (shared > 0) {
      std::vector<JointPositions> prev(world.begin() + s, world.begin() + s + shared);
      values.leftCols(shared) = MotionVectors(ToFrame(prev, frame));
      mask.leftCols(shared).setOnes();
    }
    ControlKnown(options.controls, frame, s, n, shared, values, mask);
    WindowKnown known;
    if (mask.any()) {
      known.mask = mask;
      known.values = ((values.colwise() - model.pose_mean()).array().colwise() / model.pose_std().array()).matrix();
      known.values = (known.values.array() * mask.array()).matrix();
    }
    const SgmdModel::Context context = model.EncodeMusic(WindowMusic(model, song, s));
    Eigen::MatrixXf noise(c.pose_dim, n);
    FillStandardNormal(gen, &noise);
    const int64_t base = static_cast<int64_t>(w) * out.steps;
    const Eigen::MatrixXf x = SampleWindow(
        model, context, none, sv, noise, {.steps = out.steps, .guidance = out.guidance},
        known.empty() ? nullptr : &known, [&](int done_steps, int) {
          if (options.progress && !cancelled) cancelled = !options.progress(base + done_steps, all_steps);
        });
    if (cancelled) break;
    const Eigen::MatrixXf v = ((x.array().colwise() * model.pose_std().array()).colwise() +
                               model.pose_mean().array()).matrix();
    for (int i = std::max(shared, 0); i < n && s + i < static_cast<int64_t>(world.size()); ++i) {
      world[s + i] = FromFrame(PositionsOfVector(v.col(i)), frame);
    }
    done = s + n;
  }
  if (cancelled) return absl::CancelledError("the dance was cancelled");
  // Before the glitch repair: that smears a break it takes for a glitch over the frames around it.
  out.reanchored_seams =
      sgmd_internal::ReanchorSeams(options.controls, window_seams, options.reanchor_search_frames, world, total);
  out.repaired_frames = sgmd_internal::RepairGlitches(options.controls, options.glitch_max_frames, world, total);
  BlendSeams(options.controls, window_seams, options.seam_blend_frames, world, total);

  // Finish the frames as the token model's: bone lengths (frames without given joints), the foot lock
  // (frames whose lower body is free), rotations.
  const PoseReconstructor rec(model.skeleton());
  const FootLock lock(model.skeleton());
  FootLockState lock_state;
  out.frames.resize(static_cast<size_t>(total));
  for (int64_t m = 0; m < total; ++m) {
    PoseFrame& f = out.frames[m];
    f.index = m;
    f.time_s = m / 30.0;
    f.positions = world[m];
    if (options.controls.motion.KnownAt(m) == 0) rec.ProjectBoneLengths(f.positions);
    if (options.foot_lock && !LowerGiven(options.controls, m)) lock.Apply(lock_state, &f.positions);
    rec.JointRotations(f.positions, &f.rotations);
    f.upper_code = -1;
    f.lower_code = -1;
  }
  return out;
}

}  // namespace dance::engine
