// cellcal's key filter (components/common/key_filter.hpp) on the CDR payloads of every keyed cellcal type, against a
// plain reference: the sample's key, from the deserialized sample, in the filter's set.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <set>

#include <fastdds/dds/core/LoanableSequence.hpp>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/key_filter.hpp"
#include "test_support.hpp"

namespace cellcal::components {
namespace {

template <class M>
eprosima::fastrtps::rtps::SerializedPayload_t serialize(M& m) {
  typename TopicOf<M>::PubSub t;
  eprosima::fastrtps::rtps::SerializedPayload_t p(t.getSerializedSizeProvider(&m)());
  EXPECT_TRUE(t.serialize(&m, &p));
  return p;
}

std::string randomKey(std::mt19937_64& rng) {
  std::string k(1 + rng() % 63, 'a');
  for (auto& c : k) c = static_cast<char>('a' + rng() % 26);
  return k;
}

template <class M>
void checkType(std::mt19937_64& rng) {
  std::vector<std::string> pool;
  for (int i = 0; i < 6; ++i) pool.push_back(randomKey(rng));
  std::set<std::string> chosen(pool.begin(), pool.begin() + 3);
  KeyFilterFactory& factory = KeyFilterFactory::instance();
  std::vector<const char*> quoted_c;
  std::vector<std::string> quoted;
  for (const auto& k : chosen) quoted.push_back("'" + k + "'");
  for (const auto& q : quoted) quoted_c.push_back(q.c_str());
  using Size = eprosima::fastdds::dds::LoanableCollection::size_type;
  eprosima::fastdds::dds::LoanableSequence<const char*> params(static_cast<Size>(quoted_c.size()));
  params.length(static_cast<Size>(quoted_c.size()));
  for (std::size_t i = 0; i < quoted_c.size(); ++i) params[static_cast<Size>(i)] = quoted_c[i];
  eprosima::fastdds::dds::IContentFilter* f = nullptr;
  ASSERT_EQ(factory.create_content_filter(kKeyFilterClass, "", nullptr, "key = %0", params, f),
            eprosima::fastrtps::types::ReturnCode_t::RETCODE_OK);
  for (int trial = 0; trial < 50; ++trial) {
    M m;
    const std::string key = pool[rng() % pool.size()];
    if constexpr (std::is_same_v<M, msg::TrackerPose>) m.target_id(key);
    else m.robot_id(key);
    m.source_stamp_ns(rng());
    auto p = serialize(m);
    const bool want = chosen.count(key) > 0;  // the reference
    EXPECT_EQ(f->evaluate(p, {}, {}), want) << key;
  }
  // A payload it cannot read passes (the reader's deserializer names what is wrong).
  eprosima::fastrtps::rtps::SerializedPayload_t bad(8);
  bad.length = 6;
  EXPECT_TRUE(f->evaluate(bad, {}, {}));
  factory.delete_content_filter(kKeyFilterClass, f);
}

TEST(KeyFilter, PassesExactlyTheSamplesOfItsKeys) {
  std::mt19937_64 rng(test::testSeed());
  checkType<msg::JointState>(rng);
  checkType<msg::TrackerPose>(rng);
  checkType<msg::CalibrationState>(rng);
  checkType<msg::CalibrationDiagnostics>(rng);
  checkType<msg::TargetPose>(rng);
  checkType<msg::CompensatedTarget>(rng);
  checkType<sim::RobotTruth>(rng);
}

TEST(KeyFilter, ReadsBigEndianPayloads) {
  // CDR_BE: encapsulation 00 00, then the length 00 00 00 03 and "r1\0".
  const unsigned char bytes[] = {0, 0, 0, 0, 0, 0, 0, 3, 'r', '1', 0, 0};
  eprosima::fastrtps::rtps::SerializedPayload_t p(sizeof bytes);
  std::memcpy(p.data, bytes, sizeof bytes);
  p.length = sizeof bytes;
  EXPECT_TRUE(KeyFilter({"r1"}).evaluate(p, {}, {}));
  EXPECT_FALSE(KeyFilter({"r2"}).evaluate(p, {}, {}));
}

}  // namespace
}  // namespace cellcal::components
