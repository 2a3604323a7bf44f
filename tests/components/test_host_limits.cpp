// The host's kernel limits a DDS process depends on (host_limits.hpp): the capped socket-buffer warning and the
// kernel's count of datagrams dropped for full receive buffers.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <random>

#include "test_support.hpp"
#include "cellcal/components/host_limits.hpp"

namespace cellcal::components {
namespace {

TEST(HostLimits, ACappedReceiveOrSendBufferIsNamedWithItsSysctlAndTheFix) {
  std::mt19937_64 rng(test::testSeed());
  const std::uint32_t asked = 65536u + static_cast<std::uint32_t>(rng() % 8000000u);
  const std::int64_t below = static_cast<std::int64_t>(asked) - 1 - static_cast<std::int64_t>(rng() % 60000u);
  const std::string r = socketBufferWarning("participant profile 'p'", asked, 0, below, std::nullopt);
  EXPECT_NE(r.find("net.core.rmem_max = " + std::to_string(below)), std::string::npos) << r;
  EXPECT_NE(r.find("below the " + std::to_string(asked)), std::string::npos) << r;
  EXPECT_NE(r.find("profile 'p'"), std::string::npos) << r;
  EXPECT_NE(r.find("sysctl -p config/sysctl/60-cellcal.conf"), std::string::npos) << r;
  EXPECT_EQ(r.find("wmem_max"), std::string::npos) << r;
  const std::string w = socketBufferWarning("x", 0, asked, std::nullopt, below);
  EXPECT_NE(w.find("UDP send buffer"), std::string::npos) << w;
  EXPECT_NE(w.find("net.core.wmem_max"), std::string::npos) << w;
  // Not capped: the cap at or above the ask, the OS default (0), or a cap that cannot be read.
  EXPECT_EQ(socketBufferWarning("x", asked, asked, asked, static_cast<std::int64_t>(asked) + 1), "");
  EXPECT_EQ(socketBufferWarning("x", 0, 0, 1, 1), "");
  EXPECT_EQ(socketBufferWarning("x", asked, asked, std::nullopt, std::nullopt), "");
}

TEST(HostLimits, KernelDropsAreReadFromTheUdpLinesOfSnmp) {
  std::mt19937_64 rng(test::testSeed());
  const std::uint64_t drops = rng() % 1000000000ULL;
  const std::string path = ::testing::TempDir() + "/snmp_" + std::to_string(rng());
  {
    std::ofstream f(path);
    f << "Ip: Forwarding DefaultTTL\nIp: 1 64\n"
         "Udp: InDatagrams NoPorts InErrors OutDatagrams RcvbufErrors SndbufErrors InCsumErrors IgnoredMulti MemErrors\n"
         "Udp: 5 6 7 8 " << drops << " 0 0 0 0\n"
         "UdpLite: InDatagrams NoPorts InErrors OutDatagrams RcvbufErrors SndbufErrors InCsumErrors IgnoredMulti MemErrors\n"
         "UdpLite: 0 0 0 0 99 0 0 0 0\n";
  }
  EXPECT_EQ(udpReceiveBufferErrors(path), drops);
  std::remove(path.c_str());
  EXPECT_EQ(udpReceiveBufferErrors(path), std::nullopt);
  EXPECT_EQ(readKernelLimit(path), std::nullopt);
  // This machine's own (Linux): readable.
  EXPECT_TRUE(udpReceiveBufferErrors().has_value());
  EXPECT_TRUE(readKernelLimit("/proc/sys/net/core/rmem_max").has_value());
}

}  // namespace
}  // namespace cellcal::components
