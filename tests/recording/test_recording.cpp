// Recordings (recording/recording.hpp): every topic type survives a file, schemas carry the IDL, payloads cut short
// or of another encoding are errors with a reason, topic lists name what they do not know.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "cellcal/recording/recording.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

using namespace cellcal::components;
using namespace cellcal::recording;

template <class M>
M randomSample(std::mt19937_64& rng) {
  M m;
  m.source_stamp_ns(rng());
  m.sequence_number(rng());
  if constexpr (std::is_same_v<M, msg::JointState>) {
    m.robot_id("robot_" + std::to_string(rng() % 100));
    for (int k = 0, n = 1 + static_cast<int>(rng() % 16); k < n; ++k)
      m.position_rad().push_back(std::uniform_real_distribution<double>(-3, 3)(rng));
  }
  if constexpr (std::is_same_v<M, msg::CalibrationState>) {
    for (int k = 0, n = static_cast<int>(rng() % 50); k < n; ++k) {
      m.parameter_names().push_back("p" + std::to_string(k) + "_m");
      m.parameter_values().push_back(std::uniform_real_distribution<double>(-1, 1)(rng));
    }
    m.model_extensions().push_back("joint_compliance:" + std::to_string(1 + rng() % 6));
  }
  return m;
}

TEST(Recording, EveryTopicTypeSurvivesAFileWithItsSchema) {
  std::mt19937_64 rng(test::testSeed());
  const std::string path = (std::filesystem::temp_directory_path() / ("cellcal_rec_" + std::to_string(::getpid()) + ".mcap")).string();
  std::vector<std::pair<std::string, std::string>> written;  // topic, payload
  {
    RecordingWriter w(path, 200 + rng() % 4000);
    std::uint64_t t = 1'700'000'000'000'000'000ULL;
    for (int i = 0; i < 200; ++i) {
      forEachTopicType([&](auto tag) {
        using M = typename decltype(tag)::type;
        if (rng() % 3) return;
        const M m = randomSample<M>(rng);
        t += 1 + rng() % 1'000'000;
        w.write(m, t, m.source_stamp_ns(), static_cast<std::uint32_t>(i));
        written.emplace_back(TopicOf<M>::name, encodeCdr(m));
        M back;
        std::string error;
        ASSERT_TRUE(decodeCdr(written.back().second, &back, &error)) << error;
        EXPECT_TRUE(back == m) << TopicOf<M>::name;
      });
    }
    w.file().close();
  }
  const Recording r = readRecording(path, /*tolerate_truncation=*/false);
  ASSERT_TRUE(r.file.complete) << r.file.problem;
  ASSERT_EQ(r.in_log_order.size(), written.size());
  for (size_t i = 0; i < written.size(); ++i) {
    EXPECT_EQ(*r.in_log_order[i].topic, written[i].first);
    EXPECT_EQ(r.in_log_order[i].message->data, written[i].second) << i;
  }
  for (const auto& s : r.file.schemas) {
    EXPECT_EQ(s.encoding, "omgidl");
    EXPECT_EQ(s.data, msgsIdlText());
    const std::string struct_name = s.name.substr(s.name.rfind(':') + 1);
    EXPECT_NE(s.data.find("struct " + struct_name + " {"), std::string::npos) << s.name;
  }
  for (const auto& c : r.file.channels) {
    EXPECT_EQ(c.message_encoding, "cdr");
    EXPECT_TRUE(c.metadata.count("dds_type") && c.metadata.count("qos_profile")) << c.topic;
  }
  std::filesystem::remove(path);
}

TEST(Recording, APayloadCutShortOrOfAnotherEncodingIsAnError) {
  std::mt19937_64 rng(test::testSeed());
  const std::string full = encodeCdr(randomSample<msg::CalibrationState>(rng));
  msg::CalibrationState out;
  std::string error;
  for (int k = 0; k < 20; ++k) {
    const size_t cut = rng() % (full.size() - 8);
    EXPECT_FALSE(decodeCdr(full.substr(0, cut), &out, &error)) << "cut at " << cut << " of " << full.size();
    EXPECT_FALSE(error.empty());
  }
  std::string xcdr2 = full;
  xcdr2[1] = 0x07;  // PL_CDR2_LE: not what cellcal writes
  error.clear();
  EXPECT_FALSE(decodeCdr(xcdr2, &out, &error));
  EXPECT_NE(error.find("encapsulation"), std::string::npos) << error;
}

TEST(Recording, TopicListsNameWhatTheyDoNotKnow) {
  EXPECT_EQ(parseTopicList("all").size(), cellTopics().size());
  const auto inputs = parseTopicList("inputs");
  EXPECT_EQ(inputs, (std::vector<std::string>{"cellcal/joint_state", "cellcal/tracker_pose", "cellcal/target_pose"}));
  EXPECT_EQ(parseTopicList("cellcal/tracker_pose,cellcal/joint_state,cellcal/tracker_pose").size(), 2u);
  try {
    parseTopicList("cellcal/joint_state,cellcal/joint_states");
    FAIL() << "an unknown topic was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("'cellcal/joint_states'"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace cellcal
