// The Foxglove WebSocket protocol v1 (subprotocol "foxglove.websocket.v1"), the part a read-only live source needs:
// the server says who it is (serverInfo) and what it has (advertise), clients subscribe and unsubscribe by channel,
// and every message goes out as a binary Message Data frame. No sockets here: the messages only.
//
// cellcal serves no client publishing, parameters, services or assets; a client that asks for them gets a status
// message saying so, and its connection stays open.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

namespace cellcal::foxglove {

constexpr const char* kSubprotocol = "foxglove.websocket.v1";

// One advertised channel: a topic with its message encoding and schema (cellcal: encoding "cdr", schemaEncoding
// "omgidl", schema = the IDL text, schemaName = the IDL's fully qualified type name), as in the MCAP recordings.
struct Channel {
  std::uint32_t id = 0;
  std::string topic;
  std::string encoding;
  std::string schema_name;
  std::string schema;
  std::string schema_encoding;
};

enum class StatusLevel : int { kInfo = 0, kWarning = 1, kError = 2 };

// {"op":"serverInfo", ...}: no capabilities (a read-only source); metadata as given; session_id tells a reconnecting
// client whether this is the server instance it saw before.
std::string serverInfoJson(const std::string& name, const std::map<std::string, std::string>& metadata,
                           const std::string& session_id);
// {"op":"advertise","channels":[...]}.
std::string advertiseJson(const std::vector<Channel>& channels);
// {"op":"status","level":...,"message":...}.
std::string statusJson(StatusLevel level, const std::string& message);

// The binary Message Data frame: opcode 0x01, subscription id (uint32 LE), receive time in ns (uint64 LE), payload.
std::string messageDataFrame(std::uint32_t subscription_id, std::uint64_t receive_time_ns, const std::string& payload);
// The other way round (for tests and tools): false when `frame` is not a Message Data frame.
bool parseMessageDataFrame(const std::string& frame, std::uint32_t* subscription_id, std::uint64_t* receive_time_ns,
                           std::string* payload);

// A text message from a client, parsed. kInvalid: not JSON, no "op", or fields of the wrong type (error says which);
// kUnsupported: a well-formed request for something this server does not offer (error names the op).
struct ClientRequest {
  enum Kind { kSubscribe, kUnsubscribe, kUnsupported, kInvalid } kind = kInvalid;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> subscribe;  // (subscription id, channel id)
  std::vector<std::uint32_t> unsubscribe;                          // subscription ids
  std::string error;
};
ClientRequest parseClientText(const std::string& text);

// What one client has subscribed to, with the protocol's rules: a subscription id is not reused while active, a
// channel has at most one subscription per client, and only advertised channels can be subscribed. Each call
// returns the problems it refused (one line each; empty when all was applied).
class Subscriptions {
 public:
  std::vector<std::string> subscribe(const std::vector<std::pair<std::uint32_t, std::uint32_t>>& subs,
                                     const std::vector<Channel>& advertised);
  std::vector<std::string> unsubscribe(const std::vector<std::uint32_t>& subscription_ids);
  // The subscription of `channel_id`, if any.
  bool subscriptionOf(std::uint32_t channel_id, std::uint32_t* subscription_id) const;
  std::size_t size() const { return by_subscription_.size(); }

 private:
  std::map<std::uint32_t, std::uint32_t> by_subscription_;  // subscription -> channel
  std::map<std::uint32_t, std::uint32_t> by_channel_;       // channel -> subscription
};

}  // namespace cellcal::foxglove
