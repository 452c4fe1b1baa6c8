// End to end through the dance-generate binary: chunking invariance of the written dance, BVH shape,
// and clear errors for bad settings.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/engine/runtime/testing/tiny_model.h"

namespace dance::engine {
namespace {

std::string Tmp(const std::string& name) { return ::testing::TempDir() + "/" + name; }

std::string Binary() {
  const char* dir = std::getenv("DANCE_BINARY_DIR");
  return absl::StrCat(dir != nullptr ? dir : "build", "/bin/dance-generate");
}

// 16-bit PCM WAV, written by hand (mono or stereo).
void WriteWav(const std::string& path, const std::vector<float>& interleaved, int rate, int channels) {
  std::ofstream f(path, std::ios::binary);
  auto u32 = [&](uint32_t v) { f.write(reinterpret_cast<const char*>(&v), 4); };
  auto u16 = [&](uint16_t v) { f.write(reinterpret_cast<const char*>(&v), 2); };
  const uint32_t bytes = static_cast<uint32_t>(interleaved.size() * 2);
  f.write("RIFF", 4);
  u32(36 + bytes);
  f.write("WAVEfmt ", 8);
  u32(16);
  u16(1);
  u16(static_cast<uint16_t>(channels));
  u32(static_cast<uint32_t>(rate));
  u32(static_cast<uint32_t>(rate * channels * 2));
  u16(static_cast<uint16_t>(channels * 2));
  u16(16);
  f.write("data", 4);
  u32(bytes);
  for (float v : interleaved) {
    const int16_t s = static_cast<int16_t>(std::lround(std::clamp(v, -1.0f, 1.0f) * 32767.0f));
    f.write(reinterpret_cast<const char*>(&s), 2);
  }
}

struct Result {
  int exit_code;
  std::string output;
};

Result RunTool(const std::string& args) {
  const std::string log = Tmp("generate.log");
  const int rc = std::system((Binary() + " " + args + " > " + log + " 2>&1").c_str());
  std::ifstream f(log);
  std::stringstream ss;
  ss << f.rdbuf();
  return {WEXITSTATUS(rc), ss.str()};
}

nlohmann::json ReadJson(const std::string& path) {
  std::ifstream f(path);
  return nlohmann::json::parse(f);
}

class DanceGenerate : public ::testing::Test {
 protected:
  void SetUp() override {
    model_ = Tmp("gen-tiny.dncw");
    ASSERT_TRUE(testing::TinyModelWriter({}).WriteFile(model_).ok());
    audio_ = Tmp("gen.wav");
    std::vector<float> mono = testing::TestAudio(3.0, 22050), stereo;
    for (float v : mono) {
      stereo.push_back(v);
      stereo.push_back(-v);
    }
    WriteWav(audio_, stereo, 22050, 2);
  }
  std::string model_, audio_;
};

TEST_F(DanceGenerate, ChunkSizeDoesNotChangeTheDance) {
  nlohmann::json first;
  for (int chunk : {4096, 1, 777, 100000}) {
    const std::string out = Tmp(absl::StrCat("dance-", chunk, ".json"));
    Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", out, " --model ", model_,
                                    " --seed 3 --temperature 0.8 --chunk-samples ", chunk));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    nlohmann::json doc = ReadJson(out);
    if (first.is_null()) {
      first = doc;
      continue;
    }
    EXPECT_EQ(doc["positions"], first["positions"]) << "chunk " << chunk;
    EXPECT_EQ(doc["upper_codes"], first["upper_codes"]);
  }
  EXPECT_EQ(first["format"], "dance-motion/v1");
  EXPECT_EQ(first["fps"], 30.0);
  EXPECT_EQ(first["joint_names"].size(), 24u);
  EXPECT_NEAR(first["audio_offset_s"].get<double>(), 4.0 / 30.0, 1e-9);
  // 3 s of audio: frames 4..89 (frames at or past 3.0 s are dropped).
  EXPECT_EQ(first["positions"].size(), 86u);
  EXPECT_EQ(first["positions"][0].size(), 24u);
  EXPECT_EQ(first["seed"], 3);
}

TEST_F(DanceGenerate, WritesBvhWithAllFramesAndJoints) {
  const std::string bvh = Tmp("dance.bvh");
  Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", Tmp("d.json"), " --model ", model_,
                                  " --bvh ", bvh, " --quiet"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream f(bvh);
  std::string line;
  int joints = 0, end_sites = 0, frames = -1, motion_lines = 0;
  bool in_motion = false;
  while (std::getline(f, line)) {
    if (absl::StrContains(line, "ROOT ") || absl::StrContains(line, "JOINT ")) ++joints;
    if (absl::StrContains(line, "End Site")) ++end_sites;
    if (absl::StartsWith(line, "Frames: ")) frames = std::stoi(line.substr(8));
    if (in_motion) {
      std::vector<std::string> v = absl::StrSplit(line, ' ', absl::SkipEmpty());
      EXPECT_EQ(v.size(), 6u + 3u * 23u);
      ++motion_lines;
    }
    if (absl::StartsWith(line, "Frame Time:")) in_motion = true;
  }
  EXPECT_EQ(joints, 24);
  EXPECT_EQ(end_sites, 5);  // both feet, head, both hands
  EXPECT_EQ(frames, 86);
  EXPECT_EQ(motion_lines, 86);
}

TEST_F(DanceGenerate, BadSettingsFailClearly) {
  Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", Tmp("x.json"), " --model ", model_,
                                  " --style polka"));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(absl::StrContains(r.output, "unknown style 'polka'")) << r.output;
  r = RunTool(absl::StrCat("--audio ", audio_, " --out ", Tmp("x.json"), " --model ", model_,
                           " --temperature -1"));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(absl::StrContains(r.output, "temperature")) << r.output;
  r = RunTool(absl::StrCat("--audio ", audio_, " --out ", Tmp("x.json"), " --model /nonexistent.dncw"));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(absl::StrContains(r.output, "nonexistent.dncw")) << r.output;
  r = RunTool("--out x.json");
  EXPECT_EQ(r.exit_code, 2);
}


// The diffusion backend (docs/diffusion.md) on the repository's tiny SGMD model (random weights).
class DanceGenerateDiffusion : public DanceGenerate {
 protected:
  std::string Editor() const { return "models/sgmd-tiny.dncw"; }
};

TEST_F(DanceGenerateDiffusion, DancesTheWholeSongFromFrameZero) {
  const std::string out = Tmp("sgmd.json");
  Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", out, " --model ", Editor(), " --seed 2 --steps 5"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("\"backend\":\"diffusion\""), std::string::npos) << r.output;
  nlohmann::json doc = ReadJson(out);
  EXPECT_EQ(doc["format"], "dance-motion/v1");
  EXPECT_EQ(doc["positions"].size(), 90u);  // 3 s, frames 0..89
  EXPECT_NEAR(doc["audio_offset_s"].get<double>(), 0.0, 1e-9);
  EXPECT_EQ(doc["backend"], "diffusion");
  EXPECT_EQ(doc["steps"], 5);
  EXPECT_EQ(doc["model_id"], "sgmd-tiny");
  // The same seed gives the same dance; --backend diffusion picks the same path.
  const std::string again = Tmp("sgmd-again.json");
  r = RunTool(absl::StrCat("--audio ", audio_, " --out ", again, " --backend diffusion --model ", Editor(),
                           " --seed 2 --steps 5"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(ReadJson(again)["positions"], doc["positions"]);
}

TEST_F(DanceGenerateDiffusion, KeepsASeedMotionExactly) {
  // The seed: the first second of a free dance, moved 2 m along +X.
  const std::string free_out = Tmp("sgmd-free.json");
  Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", free_out, " --model ", Editor(), " --steps 4"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  nlohmann::json seed = ReadJson(free_out);
  nlohmann::json frames = nlohmann::json::array();
  for (int i = 0; i < 30; ++i) {
    nlohmann::json f = seed["positions"][i];
    for (auto& p : f) p[0] = p[0].get<double>() + 2.0;
    frames.push_back(f);
  }
  const std::string seed_path = Tmp("sgmd-seed.json");
  std::ofstream(seed_path) << nlohmann::json{{"format", "dance-motion/v1"}, {"fps", 30}, {"positions", frames},
                                             {"audio_offset_s", 0.0}}.dump();
  const std::string out = Tmp("sgmd-seeded.json");
  r = RunTool(absl::StrCat("--audio ", audio_, " --out ", out, " --model ", Editor(), " --steps 4 --seed-motion ",
                           seed_path));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  nlohmann::json doc = ReadJson(out);
  double worst = 0.0;
  for (int i = 0; i < 30; ++i) {
    for (int j = 0; j < 24; ++j) {
      for (int k = 0; k < 3; ++k) {
        worst = std::max(worst, std::abs(doc["positions"][i][j][k].get<double>() - frames[i][j][k].get<double>()));
      }
    }
  }
  EXPECT_LT(worst, 1e-4) << "the seed's joints moved by " << worst << " m";
}

TEST_F(DanceGenerateDiffusion, BadSettingsFailClearly) {
  const std::string out = Tmp("sgmd-bad.json");
  struct Case {
    std::string flags, want;
  };
  for (const Case& c : std::vector<Case>{
           {"--steps 0", "bad value for --steps"},
           {"--steps 5000", "steps must be 1..1000"},
           {"--overlap-s 9", "overlap must be below the window"},
           {"--guidance -1", "guidance must be > 0"},
           {"--codes-out x.npy", "--codes-out needs the token model"},
           {"--style polka", "unknown style 'polka'"},
       }) {
    Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", out, " --model ", Editor(), " ", c.flags));
    EXPECT_NE(r.exit_code, 0) << c.flags;
    EXPECT_NE(r.output.find(c.want), std::string::npos) << c.flags << ": " << r.output;
  }
  // The diffusion flags on the token model.
  Result r = RunTool(absl::StrCat("--audio ", audio_, " --out ", out, " --model ", model_, " --steps 10"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("for the diffusion backend"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace dance::engine
