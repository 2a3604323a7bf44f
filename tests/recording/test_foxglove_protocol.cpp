// The Foxglove WebSocket protocol messages (recording/foxglove/protocol.hpp) against plain references: the Message
// Data frame byte by byte, client requests as a client would write them, and subscription rules against a model.
#include <gtest/gtest.h>

#include <map>
#include <random>
#include <set>

#include "cellcal/foxglove/protocol.hpp"
#include "test_support.hpp"

namespace cellcal::foxglove {
namespace {

using nlohmann::json;

TEST(FoxgloveProtocol, MessageDataFrameIsOpcodeThenLittleEndianIdsThenPayload) {
  std::mt19937_64 rng(test::testSeed());
  for (int trial = 0; trial < 200; ++trial) {
    const auto sub = static_cast<std::uint32_t>(rng());
    const std::uint64_t t = rng();
    std::string payload(rng() % 300, '\0');
    for (auto& c : payload) c = static_cast<char>(rng());
    const std::string f = messageDataFrame(sub, t, payload);
    // The reference: the spec's table, one byte at a time.
    std::string want(1, '\x01');
    for (int i = 0; i < 4; ++i) want.push_back(static_cast<char>((sub >> (8 * i)) & 0xff));
    for (int i = 0; i < 8; ++i) want.push_back(static_cast<char>((t >> (8 * i)) & 0xff));
    want += payload;
    ASSERT_EQ(f, want);
    std::uint32_t sub2 = 0;
    std::uint64_t t2 = 0;
    std::string p2;
    ASSERT_TRUE(parseMessageDataFrame(f, &sub2, &t2, &p2));
    EXPECT_EQ(sub2, sub);
    EXPECT_EQ(t2, t);
    EXPECT_EQ(p2, payload);
  }
  std::uint32_t s;
  std::uint64_t t;
  std::string p;
  EXPECT_FALSE(parseMessageDataFrame(std::string("\x01\x00\x00", 3), &s, &t, &p));
  EXPECT_FALSE(parseMessageDataFrame(std::string(13, '\x02'), &s, &t, &p));
}

TEST(FoxgloveProtocol, ServerInfoAndAdvertiseCarryWhatTheSpecAsks) {
  const json info = json::parse(serverInfoJson("cellcal", {{"domain_id", "7"}}, "42"));
  EXPECT_EQ(info["op"], "serverInfo");
  EXPECT_EQ(info["name"], "cellcal");
  EXPECT_TRUE(info["capabilities"].is_array() && info["capabilities"].empty());
  EXPECT_EQ(info["metadata"]["domain_id"], "7");
  EXPECT_EQ(info["sessionId"], "42");
  const json adv = json::parse(advertiseJson({{3, "cellcal/joint_state", "cdr", "cellcal::msg::JointState", "module x {};", "omgidl"},
                                              {4, "t", "json", "T", "{}", ""}}));
  ASSERT_EQ(adv["op"], "advertise");
  ASSERT_EQ(adv["channels"].size(), 2u);
  EXPECT_EQ(adv["channels"][0]["id"], 3);
  EXPECT_EQ(adv["channels"][0]["topic"], "cellcal/joint_state");
  EXPECT_EQ(adv["channels"][0]["encoding"], "cdr");
  EXPECT_EQ(adv["channels"][0]["schemaName"], "cellcal::msg::JointState");
  EXPECT_EQ(adv["channels"][0]["schema"], "module x {};");
  EXPECT_EQ(adv["channels"][0]["schemaEncoding"], "omgidl");
  EXPECT_FALSE(adv["channels"][1].contains("schemaEncoding"));  // optional: left out when not set
  const json st = json::parse(statusJson(StatusLevel::kWarning, "w"));
  EXPECT_EQ(st["op"], "status");
  EXPECT_EQ(st["level"], 1);
  EXPECT_EQ(st["message"], "w");
}

TEST(FoxgloveProtocol, ClientRequestsParsedOrRefusedNamingTheField) {
  std::mt19937_64 rng(test::testSeed());
  for (int trial = 0; trial < 50; ++trial) {
    json subs = json::array();
    std::vector<std::pair<std::uint32_t, std::uint32_t>> want;
    for (std::size_t i = rng() % 6; i > 0; --i) {
      const auto id = static_cast<std::uint32_t>(rng()), ch = static_cast<std::uint32_t>(rng());
      subs.push_back({{"id", id}, {"channelId", ch}});
      want.emplace_back(id, ch);
    }
    const ClientRequest r = parseClientText(json{{"op", "subscribe"}, {"subscriptions", subs}}.dump());
    ASSERT_EQ(r.kind, ClientRequest::kSubscribe) << r.error;
    EXPECT_EQ(r.subscribe, want);
  }
  const ClientRequest u = parseClientText(R"({"op":"unsubscribe","subscriptionIds":[4,5]})");
  ASSERT_EQ(u.kind, ClientRequest::kUnsubscribe);
  EXPECT_EQ(u.unsubscribe, (std::vector<std::uint32_t>{4, 5}));
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"", "not a JSON object"},
      {"[1,2]", "not a JSON object"},
      {R"({"subscriptions":[]})", "no \"op\""},
      {R"({"op":"subscribe"})", "\"subscriptions\" array"},
      {R"({"op":"subscribe","subscriptions":[{"id":1}]})", "subscriptions[0].channelId"},
      {R"({"op":"subscribe","subscriptions":[{"id":1,"channelId":2},{"id":-3,"channelId":2}]})", "subscriptions[1].id"},
      {R"({"op":"subscribe","subscriptions":[{"id":4294967296,"channelId":2}]})", "subscriptions[0].id"},
      {R"({"op":"subscribe","subscriptions":[{"id":1.5,"channelId":2}]})", "subscriptions[0].id"},
      {R"({"op":"unsubscribe","subscriptionIds":[1,"2"]})", "subscriptionIds[1]"},
  };
  for (const auto& [text, says] : bad) {
    const ClientRequest r = parseClientText(text);
    EXPECT_EQ(r.kind, ClientRequest::kInvalid) << text;
    EXPECT_NE(r.error.find(says), std::string::npos) << text << " -> " << r.error;
  }
  const ClientRequest p = parseClientText(R"({"op":"setParameters","parameters":[]})");
  EXPECT_EQ(p.kind, ClientRequest::kUnsupported);
  EXPECT_NE(p.error.find("setParameters"), std::string::npos);
}

// Random subscribe/unsubscribe sequences against a plain model of the spec's rules.
TEST(FoxgloveProtocol, SubscriptionsFollowTheRulesOfAPlainModel) {
  std::mt19937_64 rng(test::testSeed());
  const std::vector<Channel> advertised = {{1, "a", "cdr", "A", "", ""}, {2, "b", "cdr", "B", "", ""}, {5, "c", "cdr", "C", "", ""}};
  for (int trial = 0; trial < 100; ++trial) {
    Subscriptions s;
    std::map<std::uint32_t, std::uint32_t> model;  // subscription -> channel
    for (int step = 0; step < 30; ++step) {
      if (rng() % 3) {
        std::vector<std::pair<std::uint32_t, std::uint32_t>> req;
        for (std::size_t i = 1 + rng() % 3; i > 0; --i)
          req.emplace_back(static_cast<std::uint32_t>(rng() % 6), static_cast<std::uint32_t>(rng() % 7));
        std::size_t refused_model = 0;
        for (const auto& [id, ch] : req) {
          const bool known = ch == 1 || ch == 2 || ch == 5;
          bool channel_taken = false;
          for (const auto& [mid, mch] : model) channel_taken |= mch == ch;
          if (!known || model.count(id) || channel_taken) ++refused_model;
          else model[id] = ch;
        }
        EXPECT_EQ(s.subscribe(req, advertised).size(), refused_model);
      } else {
        std::vector<std::uint32_t> ids;
        for (std::size_t i = 1 + rng() % 2; i > 0; --i) ids.push_back(static_cast<std::uint32_t>(rng() % 6));
        std::size_t refused_model = 0;
        for (auto id : ids) refused_model += model.erase(id) ? 0 : 1;
        EXPECT_EQ(s.unsubscribe(ids).size(), refused_model);
      }
      ASSERT_EQ(s.size(), model.size());
      for (std::uint32_t ch : {1u, 2u, 5u, 3u}) {
        std::uint32_t got = 0;
        const bool has = s.subscriptionOf(ch, &got);
        std::uint32_t want = 0;
        bool model_has = false;
        for (const auto& [mid, mch] : model) {
          if (mch != ch) continue;
          model_has = true;
          want = mid;
        }
        ASSERT_EQ(has, model_has) << "channel " << ch;
        if (has) {
          EXPECT_EQ(got, want);
        }
      }
    }
  }
}

}  // namespace
}  // namespace cellcal::foxglove
