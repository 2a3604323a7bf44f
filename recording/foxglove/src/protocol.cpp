#include "cellcal/foxglove/protocol.hpp"

#include <algorithm>

namespace cellcal::foxglove {

using nlohmann::json;

std::string serverInfoJson(const std::string& name, const std::map<std::string, std::string>& metadata,
                           const std::string& session_id) {
  json j = {{"op", "serverInfo"}, {"name", name}, {"capabilities", json::array()}, {"sessionId", session_id}};
  j["metadata"] = json::object();
  for (const auto& [k, v] : metadata) j["metadata"][k] = v;
  return j.dump();
}

std::string advertiseJson(const std::vector<Channel>& channels) {
  json list = json::array();
  for (const auto& c : channels) {
    json e = {{"id", c.id}, {"topic", c.topic}, {"encoding", c.encoding}, {"schemaName", c.schema_name},
              {"schema", c.schema}};
    if (!c.schema_encoding.empty()) e["schemaEncoding"] = c.schema_encoding;
    list.push_back(std::move(e));
  }
  return json{{"op", "advertise"}, {"channels", std::move(list)}}.dump();
}

std::string statusJson(StatusLevel level, const std::string& message) {
  return json{{"op", "status"}, {"level", static_cast<int>(level)}, {"message", message}}.dump();
}

namespace {
void putLe(std::string& out, std::uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
std::uint64_t getLe(const std::string& in, std::size_t at, int bytes) {
  std::uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v |= static_cast<std::uint64_t>(static_cast<unsigned char>(in[at + i])) << (8 * i);
  return v;
}

// An unsigned 32-bit integer field of `o`, or an error naming it.
bool uint32Field(const json& o, const char* field, const std::string& where, std::uint32_t* out, std::string* error) {
  auto it = o.find(field);
  if (it == o.end() || !it->is_number_unsigned() || it->get<std::uint64_t>() > 0xffffffffULL) {
    *error = where + "." + field + ": needs an unsigned 32-bit integer";
    return false;
  }
  *out = static_cast<std::uint32_t>(it->get<std::uint64_t>());
  return true;
}
}  // namespace

std::string messageDataFrame(std::uint32_t subscription_id, std::uint64_t receive_time_ns, const std::string& payload) {
  std::string f;
  f.reserve(13 + payload.size());
  f.push_back('\x01');
  putLe(f, subscription_id, 4);
  putLe(f, receive_time_ns, 8);
  f += payload;
  return f;
}

bool parseMessageDataFrame(const std::string& frame, std::uint32_t* subscription_id, std::uint64_t* receive_time_ns,
                           std::string* payload) {
  if (frame.size() < 13 || frame[0] != '\x01') return false;
  *subscription_id = static_cast<std::uint32_t>(getLe(frame, 1, 4));
  *receive_time_ns = getLe(frame, 5, 8);
  payload->assign(frame, 13, std::string::npos);
  return true;
}

ClientRequest parseClientText(const std::string& text) {
  ClientRequest r;
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    r.error = "not a JSON object";
    return r;
  }
  auto op = j.find("op");
  if (op == j.end() || !op->is_string()) {
    r.error = "no \"op\" string";
    return r;
  }
  const std::string name = op->get<std::string>();
  if (name == "subscribe") {
    auto subs = j.find("subscriptions");
    if (subs == j.end() || !subs->is_array()) {
      r.error = "subscribe: needs a \"subscriptions\" array";
      return r;
    }
    for (std::size_t i = 0; i < subs->size(); ++i) {
      const json& s = (*subs)[i];
      const std::string where = "subscribe.subscriptions[" + std::to_string(i) + "]";
      std::uint32_t id = 0, channel = 0;
      if (!s.is_object()) {
        r.error = where + ": needs an object";
        return r;
      }
      if (!uint32Field(s, "id", where, &id, &r.error) || !uint32Field(s, "channelId", where, &channel, &r.error))
        return r;
      r.subscribe.emplace_back(id, channel);
    }
    r.kind = ClientRequest::kSubscribe;
    return r;
  }
  if (name == "unsubscribe") {
    auto ids = j.find("subscriptionIds");
    if (ids == j.end() || !ids->is_array()) {
      r.error = "unsubscribe: needs a \"subscriptionIds\" array";
      return r;
    }
    for (std::size_t i = 0; i < ids->size(); ++i) {
      const json& v = (*ids)[i];
      if (!v.is_number_unsigned() || v.get<std::uint64_t>() > 0xffffffffULL) {
        r.error = "unsubscribe.subscriptionIds[" + std::to_string(i) + "]: needs an unsigned 32-bit integer";
        return r;
      }
      r.unsubscribe.push_back(static_cast<std::uint32_t>(v.get<std::uint64_t>()));
    }
    r.kind = ClientRequest::kUnsubscribe;
    return r;
  }
  r.kind = ClientRequest::kUnsupported;
  r.error = "\"" + name + "\" is not served: cellcal's live view is read-only (subscribe and unsubscribe only)";
  return r;
}

std::vector<std::string> Subscriptions::subscribe(const std::vector<std::pair<std::uint32_t, std::uint32_t>>& subs,
                                                  const std::vector<Channel>& advertised) {
  std::vector<std::string> refused;
  for (const auto& [id, channel] : subs) {
    const bool known = std::any_of(advertised.begin(), advertised.end(), [&](const Channel& c) { return c.id == channel; });
    if (!known) {
      refused.push_back("subscription " + std::to_string(id) + ": channel " + std::to_string(channel) +
                        " was not advertised");
    } else if (by_subscription_.count(id)) {
      refused.push_back("subscription " + std::to_string(id) + ": id already in use (channel " +
                        std::to_string(by_subscription_[id]) + ")");
    } else if (by_channel_.count(channel)) {
      refused.push_back("subscription " + std::to_string(id) + ": channel " + std::to_string(channel) +
                        " already subscribed as " + std::to_string(by_channel_[channel]));
    } else {
      by_subscription_[id] = channel;
      by_channel_[channel] = id;
    }
  }
  return refused;
}

std::vector<std::string> Subscriptions::unsubscribe(const std::vector<std::uint32_t>& subscription_ids) {
  std::vector<std::string> refused;
  for (std::uint32_t id : subscription_ids) {
    auto it = by_subscription_.find(id);
    if (it == by_subscription_.end()) {
      refused.push_back("unsubscribe " + std::to_string(id) + ": no such subscription");
      continue;
    }
    by_channel_.erase(it->second);
    by_subscription_.erase(it);
  }
  return refused;
}

bool Subscriptions::subscriptionOf(std::uint32_t channel_id, std::uint32_t* subscription_id) const {
  auto it = by_channel_.find(channel_id);
  if (it == by_channel_.end()) return false;
  *subscription_id = it->second;
  return true;
}

}  // namespace cellcal::foxglove
