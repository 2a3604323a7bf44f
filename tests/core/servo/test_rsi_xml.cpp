// KUKA RSI's packets (rsi_xml.hpp): a controller's <Rob> as RSI sends it, read; what cellcal writes read back bit for
// bit; every cut of a packet, every fault the reader names, and random corruptions refused without a crash and without
// a value taken from them; no allocation while reading or writing (this binary's counting malloc,
// test_realtime_compensator.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <random>
#include <string>

#include "cellcal/core/servo/rsi_xml.hpp"
#include "test_support.hpp"

namespace cellcal {
long allocationsInRsi(const std::function<void()>& f);  // test_realtime_compensator.cpp
namespace {

const std::string kRob =
    "<Rob Type=\"KUKA\">\n"
    "  <RIst X=\"445.0\" Y=\"-0.01\" Z=\"895.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\n"
    "  <RSol X=\"445.0\" Y=\"0.0\" Z=\"895.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\n"
    "  <AIPos A1=\"0.0012\" A2=\"-90.0\" A3=\"90.00\" A4=\"0.0\" A5=\"90.0\" A6=\"-12.5\"/>\n"
    "  <ASPos A1='0.0' A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"-12.5\"/>\n"
    "  <Delay D=\"0\"/>\n"
    "  <Digin>0</Digin>\n"
    "  <IPOC>4208163</IPOC>\n"
    "</Rob>\n";

RsiError rob(const std::string& text, RsiRob* out = nullptr) {
  RsiRob r;
  const RsiError e = parseRsiRob(text.data(), text.size(), r);
  if (out) *out = r;
  return e;
}

TEST(RsiXml, AControllersPacketIsRead) {
  RsiRob r;
  ASSERT_EQ(rob(kRob, &r), RsiError::kNone);
  EXPECT_EQ(r.ipoc, 4208163u);
  EXPECT_EQ(r.axes, 6);
  EXPECT_TRUE(r.has_actual);
  const double set[6] = {0.0, -90.0, 90.0, 0.0, 90.0, -12.5}, act[6] = {0.0012, -90.0, 90.0, 0.0, 90.0, -12.5};
  for (int k = 0; k < 6; ++k) {
    EXPECT_EQ(r.setpoint_deg[static_cast<size_t>(k)], set[k]);
    EXPECT_EQ(r.actual_deg[static_cast<size_t>(k)], act[k]);
  }
  // With an XML declaration, without AIPos, with seven axes.
  ASSERT_EQ(rob("<?xml version=\"1.0\"?><Rob><ASPos A1=\"1\" A2=\"2\" A3=\"3\" A4=\"4\" A5=\"5\" A6=\"6\" A7=\"7\"/>"
                "<IPOC> 12 </IPOC></Rob>",
                &r),
            RsiError::kNone);
  EXPECT_EQ(r.axes, 7);
  EXPECT_FALSE(r.has_actual);
  EXPECT_EQ(r.ipoc, 12u);
}

TEST(RsiXml, WhatIsWrittenReadsBackBitForBit) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-185, 185);
  char buf[kMaxRsiPacketBytes];
  for (int trial = 0; trial < 1000; ++trial) {
    const int axes = 1 + static_cast<int>(rng() % kMaxServoJoints);
    double a[kMaxServoJoints], s[kMaxServoJoints], c[kMaxServoJoints];
    for (int k = 0; k < axes; ++k) a[k] = u(rng), s[k] = u(rng), c[k] = u(rng) * 1e-4;
    const std::uint64_t ipoc = rng();
    std::size_t n = 0;
    RsiRob r;
    RsiSen sen;
    RsiError e1 = RsiError::kBadAxis, e2 = RsiError::kBadAxis;
    const long allocations = allocationsInRsi([&] {
      n = writeRsiRob(buf, sizeof buf, a, s, axes, ipoc);
      e1 = parseRsiRob(buf, n, r);
      n = writeRsiSen(buf, sizeof buf, "ImFree", c, axes, ipoc, trial % 2 == 1);
      e2 = parseRsiSen(buf, n, sen);
    });
    ASSERT_EQ(allocations, 0);
    ASSERT_EQ(e1, RsiError::kNone);
    ASSERT_EQ(e2, RsiError::kNone) << std::string(buf, n);
    ASSERT_EQ(r.axes, axes);
    ASSERT_EQ(sen.axes, axes);
    EXPECT_EQ(r.ipoc, ipoc);
    EXPECT_EQ(sen.ipoc, ipoc);
    EXPECT_EQ(sen.stop, trial % 2 == 1);
    for (int k = 0; k < axes; ++k) {
      ASSERT_EQ(r.actual_deg[static_cast<size_t>(k)], a[k]);
      ASSERT_EQ(r.setpoint_deg[static_cast<size_t>(k)], s[k]);
      ASSERT_EQ(sen.correction_deg[static_cast<size_t>(k)], c[k]);
    }
  }
  const double c[6] = {1, 2, 3, 4, 5, 6};
  EXPECT_EQ(writeRsiSen(buf, 40, "ImFree", c, 6, 1, false), 0u) << "a packet that does not fit is not written";
  EXPECT_EQ(writeRsiSen(buf, sizeof buf, "ImFree", c, 8, 1, false), 0u);
}

// Each fault named; nothing of a refused packet is taken (the output keeps what it held).
TEST(RsiXml, FaultsAreNamed) {
  auto with = [](const std::string& from, const std::string& to) {
    std::string t = kRob;
    const std::size_t p = t.find(from);
    EXPECT_NE(p, std::string::npos) << from;
    return t.replace(p, from.size(), to);
  };
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A3=\"nan\"")), RsiError::kNotFinite);
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A3=\"inf\"")), RsiError::kNotFinite);
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A3=\"90.0x\"")), RsiError::kBadAxis);
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A3=\"\"")), RsiError::kBadAxis);
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A9=\"90.0\"")), RsiError::kBadAxis);   // a gap, and an eighth axis
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A2=\"90.0\"")), RsiError::kBadAxis);   // twice
  EXPECT_EQ(rob(with("A3=\"90.0\"", "A3=\"90.0")), RsiError::kBadAxis);  // the open quote takes in " A4="
  EXPECT_EQ(rob(with("<ASPos", "<ASPosition")), RsiError::kMissingAxes);
  EXPECT_EQ(rob(with(" A6=\"-12.5\"/>\n  <Delay", "/>\n  <Delay")), RsiError::kAxesDisagree);
  EXPECT_EQ(rob(with("<IPOC>4208163</IPOC>", "")), RsiError::kMissingIpoc);
  EXPECT_EQ(rob(with("4208163", "-4208163")), RsiError::kBadIpoc);
  EXPECT_EQ(rob(with("4208163", "42O8163")), RsiError::kBadIpoc);
  EXPECT_EQ(rob(with("4208163", "99999999999999999999999")), RsiError::kBadIpoc);
  EXPECT_EQ(rob(kRob + "<Rob/>"), RsiError::kNotThisElement);
  EXPECT_EQ(rob("<Sen Type=\"ImFree\"><AK A1=\"0\"/><IPOC>1</IPOC></Sen>"), RsiError::kNotThisElement);
  EXPECT_EQ(rob(kRob + std::string(kMaxRsiPacketBytes, ' ')), RsiError::kTooLong);
  EXPECT_EQ(rob(""), RsiError::kTruncated);
  RsiSen s;
  const std::string sen = "<Sen Type=\"ImFree\"><Stop>2</Stop><AK A1=\"0\"/><IPOC>1</IPOC></Sen>";
  EXPECT_EQ(parseRsiSen(sen.data(), sen.size(), s), RsiError::kBadStop);
  RsiRob r;
  r.ipoc = 77;
  const std::string bad = with("A3=\"90.0\"", "A3=\"nan\"");
  EXPECT_EQ(parseRsiRob(bad.data(), bad.size(), r), RsiError::kNotFinite);
  EXPECT_EQ(r.ipoc, 77u) << "a refused packet changed the output";
  EXPECT_STREQ(rsiErrorName(RsiError::kAxesDisagree), "axes_disagree");
}

// Every cut of the packet short of its closing tag is refused; random corruptions (bytes replaced, inserted, dropped; drawn from the seed)
// never crash, and whatever is accepted has finite values within the axis count.
TEST(RsiXml, CutsAndCorruptionsAreRefusedCleanly) {
  for (std::size_t n = 0; n < kRob.find("</Rob>") + 6; ++n)
    EXPECT_NE(rob(kRob.substr(0, n)), RsiError::kNone) << "cut at " << n << ": " << kRob.substr(0, n);
  std::mt19937_64 rng(test::testSeed());
  const std::string alphabet = "<>/=\"' AIPSos0123456789.-eE\nRbnaIPOCK";
  int accepted = 0;
  long allocations = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    std::string t = kRob;
    for (int edits = 1 + static_cast<int>(rng() % 4); edits > 0; --edits) {
      const std::size_t p = rng() % t.size();
      const char c = rng() % 3 == 0 ? static_cast<char>(rng() % 256) : alphabet[rng() % alphabet.size()];
      switch (rng() % 3) {
        case 0: t[p] = c; break;
        case 1: t.insert(t.begin() + static_cast<std::ptrdiff_t>(p), c); break;
        default: t.erase(p, 1); break;
      }
    }
    RsiRob r;
    RsiError e = RsiError::kNone;
    allocations += allocationsInRsi([&] { e = parseRsiRob(t.data(), t.size(), r); });
    if (e != RsiError::kNone) continue;
    ++accepted;
    ASSERT_GE(r.axes, 1);
    ASSERT_LE(r.axes, kMaxServoJoints);
    for (int k = 0; k < r.axes; ++k) ASSERT_TRUE(std::isfinite(r.setpoint_deg[static_cast<size_t>(k)])) << t;
  }
  std::printf("  20000 corrupted packets: %d still read as a packet (a changed digit or skipped element), the rest "
              "refused; %ld allocations\n",
              accepted, allocations);
  EXPECT_EQ(allocations, 0);
}

}  // namespace
}  // namespace cellcal
