// The engine's public face (engine/engine.h): a program that includes only it can load a model, run a
// session over audio and write the dance; and nothing outside engine/ (the server, the client) includes
// any other engine header.
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "gtest/gtest.h"

namespace dance::engine {
namespace {

TEST(EngineApi, OneHeaderRunsADanceEndToEnd) {
  absl::StatusOr<std::shared_ptr<const Model>> model = LoadModel("models/test-tiny.dncw");
  ASSERT_TRUE(model.ok()) << model.status() << " (run from the source root)";
  SessionOptions options;
  options.input_sample_rate = 44100;
  options.input_channels = 2;
  options.style = {{"waltz", 1.0f}};
  absl::StatusOr<std::unique_ptr<Session>> session = Session::Create(*model, options);
  ASSERT_TRUE(session.ok()) << session.status();
  std::vector<float> pcm(2 * 44100 * 3);  // 3 s of a 2 Hz click, stereo
  for (size_t i = 0; i < pcm.size(); i += 2) {
    const double t = static_cast<double>(i / 2) / 44100.0;
    pcm[i] = pcm[i + 1] = std::fmod(t, 0.5) < 0.01 ? 0.8f : 0.0f;
  }
  ASSERT_TRUE((*session)->PushAudio(pcm).ok());
  (*session)->EndOfAudio();
  while ((*session)->StepsReady() > 0) ASSERT_TRUE((*session)->Step().ok());
  std::vector<PoseFrame> frames;
  (*session)->PopFrames(&frames);
  // 3 s at 30 fps = 90 frames = 22.5 periods of 4, padded to 24 periods; emitted from index 4.
  ASSERT_EQ(frames.size(), 24u * 4u - 4u);
  EXPECT_EQ(frames.front().index, 4);
  const std::string path = (std::filesystem::temp_directory_path() / "engine_api_test.json").string();
  ASSERT_TRUE(WriteDanceJson(path, (*model)->skeleton(), frames, DanceInfo{.model_id = (*model)->model_id()}).ok());
  EXPECT_GT(std::filesystem::file_size(path), 1000u);
  std::filesystem::remove(path);
  // Bad input is a Status, not a crash.
  options.input_sample_rate = 1000;
  EXPECT_EQ(Session::Create(*model, options).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(EngineApi, NothingOutsideTheEngineIncludesItsInternals) {
  const char* root = std::getenv("DANCE_SOURCE_DIR");
  const std::filesystem::path source = root != nullptr ? root : ".";
  const std::regex include(R"re(^\s*#\s*include\s*"(engine/[^"]+)")re");
  int files = 0;
  for (const char* dir : {"server", "client"}) {
    ASSERT_TRUE(std::filesystem::is_directory(source / dir)) << (source / dir);
    for (const auto& entry : std::filesystem::recursive_directory_iterator(source / dir)) {
      const std::string ext = entry.path().extension().string();
      if (ext != ".h" && ext != ".cc") continue;
      ++files;
      std::ifstream in(entry.path());
      std::string line;
      for (int n = 1; std::getline(in, line); ++n) {
        std::smatch m;
        if (std::regex_search(line, m, include)) {
          EXPECT_EQ(m[1].str(), "engine/engine.h") << entry.path() << ":" << n << " includes an engine internal";
        }
      }
    }
  }
  EXPECT_GT(files, 20);
}

}  // namespace
}  // namespace dance::engine
