// cellcal's Foxglove server (recording/foxglove/server.hpp) through real sockets, with a plain WebSocket client
// written here from RFC 6455 (handshake, masked client frames, server frames read byte by byte): what each client
// receives, and a client that stops reading losing messages (counted) while another one receives every message.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <random>
#include <thread>

#include "cellcal/foxglove/server.hpp"
#include "test_support.hpp"

namespace cellcal::foxglove {
namespace {

class RawClient {
 public:
  explicit RawClient(std::uint16_t port, const std::string& subprotocol = kSubprotocol) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) throw std::runtime_error("connect");
    timeval limit{30, 0};  // a frame that never comes fails the test instead of hanging it
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &limit, sizeof limit);
    std::string req = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                      "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n";
    if (!subprotocol.empty()) req += "Sec-WebSocket-Protocol: " + subprotocol + "\r\n";
    req += "\r\n";
    writeAll(req);
    while (response_.find("\r\n\r\n") == std::string::npos) {
      char c;
      if (::recv(fd_, &c, 1, 0) != 1) break;
      response_.push_back(c);
    }
  }
  ~RawClient() { ::close(fd_); }
  const std::string& response() const { return response_; }

  void sendText(const std::string& text) {
    std::string f(1, '\x81');  // FIN, text
    const std::size_t n = text.size();
    if (n < 126) {
      f.push_back(static_cast<char>(0x80 | n));
    } else {
      f.push_back(static_cast<char>(0x80 | 126));
      f.push_back(static_cast<char>(n >> 8));
      f.push_back(static_cast<char>(n & 0xff));
    }
    const char mask[4] = {0x12, 0x34, 0x56, 0x78};
    f.append(mask, 4);
    for (std::size_t i = 0; i < n; ++i) f.push_back(static_cast<char>(text[i] ^ mask[i % 4]));
    writeAll(f);
  }
  // The next data frame (opcode, payload); false on a closed socket.
  bool readFrame(int* opcode, std::string* payload) {
    unsigned char h[2];
    if (!readAll(h, 2)) return false;
    *opcode = h[0] & 0x0f;
    std::uint64_t n = h[1] & 0x7f;
    if (n == 126) {
      unsigned char e[2];
      if (!readAll(e, 2)) return false;
      n = (std::uint64_t(e[0]) << 8) | e[1];
    } else if (n == 127) {
      unsigned char e[8];
      if (!readAll(e, 8)) return false;
      n = 0;
      for (int i = 0; i < 8; ++i) n = (n << 8) | e[i];
    }
    payload->resize(n);
    return readAll(payload->data(), n);
  }
  // The next binary frame, skipping text (status, serverInfo, advertise).
  bool readBinary(std::string* payload) {
    int op = 0;
    while (readFrame(&op, payload))
      if (op == 2) return true;
    return false;
  }
  // Sends a subscribe request and waits until the server has applied it: the server answers a request it does not
  // serve with a status, and handles one connection's messages in order.
  void subscribe(const std::string& subscriptions) {
    sendText(R"({"op":"subscribe","subscriptions":)" + subscriptions + "}");
    sendText(R"({"op":"sync"})");
    while (readText().find("sync") == std::string::npos) {
    }
  }
  std::string readText() {
    int op = 0;
    std::string p;
    while (readFrame(&op, &p))
      if (op == 1) return p;
    return "";
  }

 private:
  void writeAll(const std::string& s) {
    std::size_t done = 0;
    while (done < s.size()) {
      const ssize_t k = ::send(fd_, s.data() + done, s.size() - done, MSG_NOSIGNAL);
      if (k <= 0) throw std::runtime_error("send");
      done += static_cast<std::size_t>(k);
    }
  }
  bool readAll(void* out, std::size_t n) {
    auto* p = static_cast<char*>(out);
    while (n > 0) {
      const ssize_t k = ::recv(fd_, p, n, 0);
      if (k <= 0) return false;
      p += k;
      n -= static_cast<std::size_t>(k);
    }
    return true;
  }
  int fd_ = -1;
  std::string response_;
};

std::vector<Channel> twoChannels() {
  return {{1, "cellcal/joint_state", "cdr", "cellcal::msg::JointState", "module m {};", "omgidl"},
          {2, "cellcal/tracker_pose", "cdr", "cellcal::msg::TrackerPose", "module m {};", "omgidl"}};
}

ServerOptions anyPort() {
  ServerOptions o;
  o.port = 0;
  return o;
}

TEST(FoxgloveServer, EachClientGetsItsSubscribedChannelsInOrder) {
  Server server(anyPort(), twoChannels());
  RawClient a(server.port()), b(server.port());
  for (RawClient* c : {&a, &b}) {
    ASSERT_NE(c->response().find("101"), std::string::npos) << c->response();
    ASSERT_NE(c->response().find("Sec-WebSocket-Protocol: foxglove.websocket.v1"), std::string::npos);
    EXPECT_NE(c->readText().find("\"serverInfo\""), std::string::npos);
    EXPECT_NE(c->readText().find("\"advertise\""), std::string::npos);
  }
  a.subscribe(R"([{"id":10,"channelId":1}])");
  b.subscribe(R"([{"id":20,"channelId":2},{"id":21,"channelId":1}])");
  std::mt19937_64 rng(test::testSeed());
  std::vector<std::tuple<std::uint32_t, std::uint64_t, std::string>> sent;
  for (int i = 0; i < 300; ++i) {
    const std::uint32_t ch = 1 + rng() % 2;
    std::string payload(rng() % 70000, '\0');
    for (auto& c : payload) c = static_cast<char>(rng());
    sent.emplace_back(ch, rng(), payload);
    server.publish(ch, std::get<1>(sent.back()), payload);
  }
  server.publish(2, 0, "end");
  server.publish(1, 0, "end");
  auto drain = [](RawClient& c, std::map<std::uint32_t, std::vector<std::pair<std::uint64_t, std::string>>>* got) {
    for (int ends = 0; ends < 2;) {
      std::string f, pay;
      std::uint32_t s;
      std::uint64_t t;
      if (!c.readBinary(&f) || !parseMessageDataFrame(f, &s, &t, &pay)) return false;
      if (pay == "end") ++ends;
      else (*got)[s].emplace_back(t, pay);
    }
    return true;
  };
  std::map<std::uint32_t, std::vector<std::pair<std::uint64_t, std::string>>> got_a, got_b;
  ASSERT_TRUE(drain(b, &got_b));
  a.sendText("{}");  // a saw one "end" only (channel 1): make it stop on the next one
  server.publish(1, 0, "end");
  ASSERT_TRUE(drain(a, &got_a));
  std::vector<std::pair<std::uint64_t, std::string>> want1, want2;
  for (const auto& [ch, t, p] : sent) (ch == 1 ? want1 : want2).emplace_back(t, p);
  EXPECT_EQ(got_a.size(), 1u);
  EXPECT_EQ(got_a[10], want1);
  EXPECT_EQ(got_b[20], want2);
  EXPECT_EQ(got_b[21], want1);
  EXPECT_EQ(server.stats().frames_dropped, 0u);
}

TEST(FoxgloveServer, RefusesAHandshakeWithoutItsSubprotocol) {
  Server server(anyPort(), twoChannels());
  RawClient c(server.port(), "");
  EXPECT_NE(c.response().find("400"), std::string::npos) << c.response();
  while (server.stats().clients_rejected < 1) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(server.stats().clients_accepted, 0u);
}

TEST(FoxgloveServer, ListeningOnAPortInUseSaysWhich) {
  Server first(anyPort(), twoChannels());
  ServerOptions o;
  o.port = first.port();
  try {
    Server second(o, twoChannels());
    FAIL() << "a second server listened on the same port";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("127.0.0.1:" + std::to_string(first.port())), std::string::npos) << e.what();
  }
}

// A client that stops reading loses messages once more than max_queued_bytes_per_client waits for it; a client that
// reads gets every message, and the slow client's losses are exactly the server's count.
TEST(FoxgloveServer, AClientThatStopsReadingLosesMessagesNotTheOthers) {
  ServerOptions o = anyPort();
  o.max_queued_bytes_per_client = 1u << 20;
  Server server(o, twoChannels());
  RawClient slow(server.port()), fast(server.port());
  for (RawClient* c : {&slow, &fast}) {
    c->readText();
    c->readText();
    c->subscribe(R"([{"id":1,"channelId":1}])");
  }
  std::string f;
  const int n = 500;  // 500 x 64 KiB = 32 MiB, more than loopback's socket buffers hold
  const std::string payload(64 * 1024, 'x');
  for (int i = 0; i < n; ++i) {
    server.publish(1, static_cast<std::uint64_t>(i + 1), payload);
    ASSERT_TRUE(fast.readBinary(&f)) << i;  // in lockstep: fast never has more than one message queued
    std::uint32_t s;
    std::uint64_t t;
    std::string p;
    ASSERT_TRUE(parseMessageDataFrame(f, &s, &t, &p));
    ASSERT_EQ(t, static_cast<std::uint64_t>(i + 1));
  }
  // Every delivery is done: fast got the last message, and each publish serves both clients in one step.
  const std::uint64_t dropped = server.stats().frames_dropped;
  EXPECT_GT(dropped, 0u);
  // The slow client now reads what it was sent, in order.
  std::uint64_t received = 0, last = 0;
  while (received < n - dropped) {
    std::uint32_t s;
    std::uint64_t t;
    std::string p;
    ASSERT_TRUE(slow.readBinary(&f)) << "after " << received << " of " << n - dropped;
    ASSERT_TRUE(parseMessageDataFrame(f, &s, &t, &p));
    ASSERT_GT(t, last);
    last = t;
    ++received;
  }
  // Once it has read its queue, it is served again: the next message reaches it.
  server.publish(1, 999999, "after");
  std::uint32_t s;
  std::uint64_t t;
  std::string p;
  ASSERT_TRUE(slow.readBinary(&f));
  ASSERT_TRUE(parseMessageDataFrame(f, &s, &t, &p));
  EXPECT_EQ(p, "after");
  EXPECT_EQ(server.stats().frames_dropped, dropped);
  EXPECT_EQ(received + server.stats().frames_dropped, static_cast<std::uint64_t>(n));
  std::printf("slow client: %llu of %d received, %llu dropped by the server\n", static_cast<unsigned long long>(received),
              n, static_cast<unsigned long long>(server.stats().frames_dropped));
}

}  // namespace
}  // namespace cellcal::foxglove
