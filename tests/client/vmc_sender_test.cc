// VMC egress against a real OSC receiver: a liblo server on a free loopback port receives what VmcSender
// and VmcRelay send; the test rebuilds the pose from the messages alone (bone names, local positions and
// rotations in Unity's frame) and compares it with the frame that was sent.
#include <lo/lo.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/export/humanoid.h"
#include "client/vmc_relay.h"
#include "client/vmc_sender.h"
#include "gtest/gtest.h"
#include "tests/client/smpl_test_clip.h"

namespace dance::client {
namespace {

struct BonePose {
  Vec3 p;                   // Unity frame, as received
  std::array<float, 4> q;   // (x, y, z, w), Unity frame
};

// One received pose: everything between two /VMC/Ext/T messages.
struct Received {
  std::vector<std::string> paths;  // in arrival order
  float time = -1.0f;
  std::vector<int> ok_args;
  std::string root_name;
  std::array<float, 7> root{};
  std::map<std::string, BonePose> bones;
  std::string bad_types;  // a message whose type tags are not what VMC specifies
};

// A liblo receiver on an OS-chosen port (lo_server_new(NULL, ...)), pumped by the test's thread.
// liblo's argument pointers point into the packet and need not be aligned for lo_arg: read by copy.
template <class T>
T ArgAs(const lo_arg* a) {
  T v;
  std::memcpy(&v, a, sizeof v);
  return v;
}

class Receiver {
 public:
  Receiver() {
    server_ = lo_server_new_with_proto(nullptr, LO_UDP, nullptr);
    EXPECT_NE(server_, nullptr);
    lo_server_add_method(server_, nullptr, nullptr, &Receiver::OnMessage, this);
    lo_server_add_bundle_handlers(server_, &Receiver::OnBundleStart, &Receiver::OnBundleEnd, this);
  }
  ~Receiver() { lo_server_free(server_); }
  std::string target() const { return absl::StrCat("127.0.0.1:", lo_server_get_port(server_)); }

  // Receives until `poses` poses are complete (the next /VMC/Ext/T, or `idle_ms` of silence).
  void Pump(size_t poses, int idle_ms = 1500) {
    while (true) {
      const int got = lo_server_recv_noblock(server_, idle_ms);
      if (got == 0) break;
      if (poses_.size() > poses) break;
    }
  }
  const std::vector<Received>& poses() const { return poses_; }
  int bundles() const { return bundles_; }
  int datagrams() const { return datagrams_; }

 private:
  static int OnMessage(const char* path, const char* types, lo_arg** argv, int argc, lo_message, void* self) {
    auto* r = static_cast<Receiver*>(self);
    if (!r->in_bundle_) ++r->datagrams_;
    const std::string p = path, t = types;
    if (p == "/VMC/Ext/OK") {
      r->poses_.emplace_back();  // OK opens a pose
      for (int i = 0; i < argc; ++i) r->poses_.back().ok_args.push_back(t[i] == 'i' ? ArgAs<int32_t>(argv[i]) : -1);
    }
    if (r->poses_.empty()) return 0;
    Received& cur = r->poses_.back();
    cur.paths.push_back(p);
    if (p == "/VMC/Ext/T") {
      if (t != "f") cur.bad_types = p + " " + t;
      cur.time = ArgAs<float>(argv[0]);
    } else if (p == "/VMC/Ext/Root/Pos" || p == "/VMC/Ext/Bone/Pos") {
      if (t != "sfffffff") {
        cur.bad_types = p + " " + t;
        return 0;
      }
      std::array<float, 7> v;
      for (int i = 0; i < 7; ++i) v[i] = ArgAs<float>(argv[1 + i]);
      if (p == "/VMC/Ext/Root/Pos") {
        cur.root_name = reinterpret_cast<const char*>(argv[0]);
        cur.root = v;
      } else {
        cur.bones[reinterpret_cast<const char*>(argv[0])] = BonePose{{v[0], v[1], v[2]}, {v[3], v[4], v[5], v[6]}};
      }
    }
    return 0;
  }
  static int OnBundleStart(lo_timetag, void* self) {
    auto* r = static_cast<Receiver*>(self);
    ++r->bundles_;
    ++r->datagrams_;
    r->in_bundle_ = true;
    return 0;
  }
  static int OnBundleEnd(void* self) {
    static_cast<Receiver*>(self)->in_bundle_ = false;
    return 0;
  }

  lo_server server_ = nullptr;
  std::vector<Received> poses_;
  int bundles_ = 0, datagrams_ = 0;
  bool in_bundle_ = false;
};

// The pose the messages describe, back in our frame: FK over the humanoid bones in Unity's frame (each
// bone's parent is its SMPL parent), then the mirror undone. Returns positions by joint index (only the
// humanoid joints are filled) and the local rotations (w, x, y, z).
void Rebuild(const Received& r, const MotionClip& sk, std::map<int, Vec3>* positions, std::map<int, Quat>* locals) {
  const std::vector<int> joint = HumanoidJointIndices(sk.joint_names);
  std::map<int, Quat> global_u;
  std::map<int, Vec3> pos_u;
  for (size_t b = 0; b < kHumanoidBones.size(); ++b) {  // parents come first
    auto it = r.bones.find(kHumanoidBones[b].unity_name);
    ASSERT_NE(it, r.bones.end()) << kHumanoidBones[b].unity_name;
    const int j = joint[b];
    const Quat q_u{it->second.q[3], it->second.q[0], it->second.q[1], it->second.q[2]};  // (w, x, y, z)
    const int p = sk.parents[j];
    if (p < 0) {
      global_u[j] = q_u;
      pos_u[j] = it->second.p;
    } else {
      ASSERT_TRUE(global_u.count(p)) << "parent of " << sk.joint_names[j] << " not rebuilt";
      global_u[j] = QuatMul(global_u[p], q_u);
      const Vec3 d = QuatRotate(global_u[p], it->second.p);
      pos_u[j] = {pos_u[p][0] + d[0], pos_u[p][1] + d[1], pos_u[p][2] + d[2]};
    }
    (*positions)[j] = {-pos_u[j][0], pos_u[j][1], pos_u[j][2]};
    (*locals)[j] = {q_u[0], q_u[1], -q_u[2], -q_u[3]};
  }
}

float QuatDistance(const Quat& a, const Quat& b) {  // 1 - |a.b|: 0 for the same rotation
  return 1.0f - std::abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]);
}

void ExpectPoseMatches(const Received& r, const MotionClip& clip, int64_t t, float tol_m, float tol_q) {
  std::map<int, Vec3> pos;
  std::map<int, Quat> loc;
  Rebuild(r, clip, &pos, &loc);
  ASSERT_EQ(pos.size(), kHumanoidBones.size());
  const std::vector<Vec3> want = GlobalPositions(clip, t);
  for (const auto& [j, p] : pos) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(p[k], want[j][k], tol_m) << clip.joint_names[j] << " axis " << k;
    EXPECT_LT(QuatDistance(loc[j], clip.rotation(t, j)), tol_q) << clip.joint_names[j];
  }
}

TEST(VmcSender, UnityConversionIsAMirrorInX) {
  // A quarter turn about +Y (yaw to the body's left in ours) is a quarter turn about -Y in Unity's frame
  // after the mirror: it must take the mirrored +Z to the mirrored image of where ours goes.
  const float s = std::sqrt(0.5f);
  const Quat q{s, 0, s, 0};
  const Vec3 v{0, 0, 1};
  const Vec3 ours = QuatRotate(q, v);                         // (1, 0, 0)
  const std::array<float, 4> u = ToUnityRotation(q);          // (x, y, z, w)
  const Vec3 theirs = QuatRotate({u[3], u[0], u[1], u[2]}, ToUnityPosition(v));
  const Vec3 mirrored = ToUnityPosition(ours);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(theirs[k], mirrored[k], 1e-6f);
  EXPECT_NEAR(mirrored[0], -1.0f, 1e-6f);
}

TEST(VmcSender, ParsesTargets) {
  std::string host;
  int port = 0;
  ASSERT_TRUE(ParseVmcTarget("10.0.0.2", &host, &port).ok());
  EXPECT_EQ(host, "10.0.0.2");
  EXPECT_EQ(port, 39539);
  ASSERT_TRUE(ParseVmcTarget("localhost:39540", &host, &port).ok());
  EXPECT_EQ(host, "localhost");
  EXPECT_EQ(port, 39540);
  ASSERT_TRUE(ParseVmcTarget("[::1]:9000", &host, &port).ok());
  EXPECT_EQ(host, "::1");
  EXPECT_EQ(port, 9000);
  EXPECT_FALSE(ParseVmcTarget("host:0", &host, &port).ok());
  EXPECT_FALSE(ParseVmcTarget("host:http", &host, &port).ok());
  EXPECT_FALSE(ParseVmcTarget(":39539", &host, &port).ok());
}

TEST(VmcSender, RefusesASkeletonWithoutPelvis) {
  MotionClip sk = testing::SmplSkeleton();
  sk.joint_names[0] = "root";
  EXPECT_FALSE(VmcSender::Create("127.0.0.1:39539", sk, {}).ok());
}

class VmcSenderModes : public ::testing::TestWithParam<bool> {};

TEST_P(VmcSenderModes, ReceiverRebuildsTheSentPose) {
  const bool bundle = GetParam();
  const MotionClip clip = testing::RandomDance(3, 11);
  Receiver rx;
  auto sender = VmcSender::Create(rx.target(), clip, {.bundle = bundle});
  ASSERT_TRUE(sender.ok()) << sender.status();
  EXPECT_EQ((*sender)->bones(), 22);
  for (int64_t t = 0; t < clip.num_frames(); ++t) {
    ASSERT_TRUE((*sender)->Send(clip.root_positions[t], &clip.rotations[t * clip.num_joints()], t / 30.0).ok());
  }
  rx.Pump(clip.num_frames());
  ASSERT_EQ(rx.poses().size(), static_cast<size_t>(clip.num_frames()));
  const int messages = 3 + 22;
  if (bundle) {
    EXPECT_EQ(rx.bundles(), clip.num_frames());
    EXPECT_EQ(rx.datagrams(), clip.num_frames());
  } else {
    EXPECT_EQ(rx.bundles(), 0);
    EXPECT_EQ(rx.datagrams(), clip.num_frames() * messages);
  }
  EXPECT_EQ((*sender)->datagrams_sent(), rx.datagrams());
  for (int64_t t = 0; t < clip.num_frames(); ++t) {
    const Received& r = rx.poses()[t];
    EXPECT_EQ(r.bad_types, "");
    ASSERT_EQ(r.paths.size(), static_cast<size_t>(messages));
    EXPECT_EQ(r.paths[1], "/VMC/Ext/T");
    EXPECT_EQ(r.paths[2], "/VMC/Ext/Root/Pos");
    EXPECT_EQ(r.ok_args, (std::vector<int>{1, 3, 0}));
    EXPECT_FLOAT_EQ(r.time, static_cast<float>(t / 30.0));
    EXPECT_EQ(r.root_name, "root");
    EXPECT_EQ(r.root, (std::array<float, 7>{0, 0, 0, 0, 0, 0, 1}));
    EXPECT_EQ(r.bones.size(), 22u);
    ExpectPoseMatches(r, clip, t, 1e-5f, 1e-6f);
  }
}

INSTANTIATE_TEST_SUITE_P(BundleOrMessages, VmcSenderModes, ::testing::Bool(),
                         [](const auto& p) { return p.param ? std::string("Bundle") : std::string("Messages"); });

// The relay at the stream's rate sends every frame exactly once, in order, unchanged.
TEST(VmcRelay, StreamRateSendsEveryFrameOnce) {
  const MotionClip clip = testing::RandomDance(12, 3);
  Receiver rx;
  auto sender = VmcSender::Create(rx.target(), clip, {});
  ASSERT_TRUE(sender.ok());
  std::thread pump([&] { rx.Pump(clip.num_frames(), 2000); });
  {
    VmcRelay relay(*std::move(sender), {.out_fps = 0, .delay_s = 0.05});
    for (int64_t t = 0; t < clip.num_frames(); ++t) {
      relay.Push(1.0 + t / 30.0, clip.root_positions[t], &clip.rotations[t * clip.num_joints()]);
    }
    relay.Finish();
    EXPECT_EQ(relay.poses_sent(), clip.num_frames());
    EXPECT_TRUE(relay.first_error().ok());
  }
  pump.join();
  ASSERT_EQ(rx.poses().size(), static_cast<size_t>(clip.num_frames()));
  for (int64_t t = 0; t < clip.num_frames(); ++t) {
    EXPECT_FLOAT_EQ(rx.poses()[t].time, static_cast<float>(1.0 + t / 30.0));
    ExpectPoseMatches(rx.poses()[t], clip, t, 1e-5f, 1e-6f);
  }
}

// At 60 fps every pose sent lies between the two frames around its time: root linear, rotations slerped.
TEST(VmcRelay, InterpolatesBetweenFrames) {
  const MotionClip clip = testing::RandomDance(15, 4);
  const int n = clip.num_joints();
  Receiver rx;
  auto sender = VmcSender::Create(rx.target(), clip, {});
  ASSERT_TRUE(sender.ok());
  std::thread pump([&] { rx.Pump(1000, 2000); });
  {
    VmcRelay relay(*std::move(sender), {.out_fps = 60, .delay_s = 0.05});
    for (int64_t t = 0; t < clip.num_frames(); ++t) {
      relay.Push(t / 30.0, clip.root_positions[t], &clip.rotations[t * n]);
    }
    relay.Finish();
  }
  pump.join();
  const auto& poses = rx.poses();
  // 14 frame periods at 60 poses/s: about 28 poses (fewer only if the machine stalls the thread).
  ASSERT_GE(poses.size(), 10u);
  float last_time = -1.0f;
  int interpolated = 0;
  for (const Received& r : poses) {
    EXPECT_GT(r.time, last_time);
    last_time = r.time;
    ASSERT_GE(r.time, 0.0f);
    ASSERT_LE(r.time, (clip.num_frames() - 1) / 30.0f + 1e-5f);
    // The expected pose at r.time, built from the clip's two frames around it.
    const double f = r.time * 30.0;
    const int64_t a = std::min<int64_t>(static_cast<int64_t>(std::floor(f)), clip.num_frames() - 1);
    const int64_t b = std::min<int64_t>(a + 1, clip.num_frames() - 1);
    const float u = static_cast<float>(f - a);
    MotionClip expected = testing::SmplSkeleton();
    expected.root_positions.push_back({});
    for (int k = 0; k < 3; ++k) {
      expected.root_positions[0][k] = clip.root_positions[a][k] + u * (clip.root_positions[b][k] - clip.root_positions[a][k]);
    }
    for (int j = 0; j < n; ++j) expected.rotations.push_back(QuatSlerp(clip.rotation(a, j), clip.rotation(b, j), u));
    if (u > 0.05f && u < 0.95f) ++interpolated;
    ExpectPoseMatches(r, expected, 0, 2e-4f, 1e-5f);  // float time: u is known to ~1e-6
  }
  EXPECT_GT(interpolated, 0);
  EXPECT_FLOAT_EQ(poses.back().time, (clip.num_frames() - 1) / 30.0f);  // ends on the last frame
}

}  // namespace
}  // namespace dance::client
