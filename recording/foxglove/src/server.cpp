// The only translation unit that compiles websocketpp (slow to compile: keep it here).
#include "cellcal/foxglove/server.hpp"

#include <websocketpp/config/asio_no_tls.hpp>
#include <websocketpp/server.hpp>

#include <atomic>
#include <chrono>
#include <future>
#include <set>
#include <stdexcept>
#include <thread>

namespace cellcal::foxglove {
namespace {
using WsServer = websocketpp::server<websocketpp::config::asio>;
using Hdl = websocketpp::connection_hdl;
}  // namespace

struct Server::Impl {
  ServerOptions options;
  std::vector<Channel> channels;
  std::string session_id;
  WsServer ws;
  std::thread thread;
  std::uint16_t port = 0;
  // Only the server thread touches the clients.
  std::map<Hdl, Subscriptions, std::owner_less<Hdl>> clients;
  std::atomic<std::uint64_t> accepted{0}, rejected{0}, now{0}, published{0}, sent{0}, dropped{0}, bytes{0},
      refused{0};

  void send(Hdl h, const std::string& text) {
    websocketpp::lib::error_code ec;
    ws.send(h, text, websocketpp::frame::opcode::text, ec);
  }

  void refuse(Hdl h, const std::string& why) {
    ++refused;
    send(h, statusJson(StatusLevel::kError, why));
  }

  void onMessage(Hdl h, WsServer::message_ptr msg) {
    auto it = clients.find(h);
    if (it == clients.end()) return;
    if (msg->get_opcode() != websocketpp::frame::opcode::text) {
      refuse(h, "binary client messages are not served: cellcal's live view is read-only");
      return;
    }
    const ClientRequest r = parseClientText(msg->get_payload());
    std::vector<std::string> problems;
    switch (r.kind) {
      case ClientRequest::kSubscribe: problems = it->second.subscribe(r.subscribe, channels); break;
      case ClientRequest::kUnsubscribe: problems = it->second.unsubscribe(r.unsubscribe); break;
      default: problems.push_back(r.error);
    }
    for (const auto& p : problems) refuse(h, p);
  }

  void deliver(std::uint32_t channel, std::uint64_t t_ns, const std::string& payload) {
    for (auto& [h, subs] : clients) {
      std::uint32_t sub = 0;
      if (!subs.subscriptionOf(channel, &sub)) continue;
      websocketpp::lib::error_code ec;
      auto con = ws.get_con_from_hdl(h, ec);
      if (ec) continue;
      if (con->get_buffered_amount() > options.max_queued_bytes_per_client) {
        ++dropped;
        continue;
      }
      const std::string frame = messageDataFrame(sub, t_ns, payload);
      con->send(frame.data(), frame.size(), websocketpp::frame::opcode::binary);
      ++sent;
      bytes += frame.size();
    }
  }
};

Server::Server(const ServerOptions& options, std::vector<Channel> channels) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.options = options;
  std::set<std::uint32_t> ids;
  for (const auto& c : channels)
    if (!ids.insert(c.id).second) throw std::invalid_argument("foxglove server: channel id " + std::to_string(c.id) + " twice");
  m.channels = std::move(channels);
  m.session_id = std::to_string(std::chrono::system_clock::now().time_since_epoch().count());
  m.ws.clear_access_channels(websocketpp::log::alevel::all);
  m.ws.clear_error_channels(websocketpp::log::elevel::all);
  m.ws.init_asio();
  m.ws.set_reuse_addr(true);
  m.ws.set_validate_handler([&m](Hdl h) {
    auto con = m.ws.get_con_from_hdl(h);
    for (const auto& p : con->get_requested_subprotocols())
      if (p == kSubprotocol) {
        con->select_subprotocol(p);
        return true;
      }
    ++m.rejected;
    con->set_status(websocketpp::http::status_code::bad_request);
    con->set_body(std::string("cellcal live view: this is a Foxglove WebSocket server; ask for the ") + kSubprotocol +
                  " subprotocol\n");
    return false;
  });
  m.ws.set_open_handler([&m](Hdl h) {
    m.clients.emplace(h, Subscriptions{});
    ++m.accepted;
    m.now = m.clients.size();
    m.send(h, serverInfoJson(m.options.name, m.options.metadata, m.session_id));
    m.send(h, advertiseJson(m.channels));
  });
  auto gone = [&m](Hdl h) {
    m.clients.erase(h);
    m.now = m.clients.size();
  };
  m.ws.set_close_handler(gone);
  m.ws.set_fail_handler(gone);
  m.ws.set_message_handler([&m](Hdl h, WsServer::message_ptr msg) { m.onMessage(h, msg); });

  websocketpp::lib::error_code ec;
  const auto address = asio::ip::make_address(options.address, ec);
  const std::string where = options.address + ":" + std::to_string(options.port);
  if (ec) throw std::runtime_error("foxglove server: '" + options.address + "' is not an IP address");
  m.ws.listen(asio::ip::tcp::endpoint(address, options.port), ec);
  if (ec) throw std::runtime_error("foxglove server: cannot listen on " + where + ": " + ec.message());
  m.ws.start_accept(ec);
  if (ec) throw std::runtime_error("foxglove server: cannot accept on " + where + ": " + ec.message());
  m.port = m.ws.get_local_endpoint(ec).port();
  m.thread = std::thread([&m] { m.ws.run(); });
}

Server::~Server() {
  Impl& m = *impl_;
  asio::post(m.ws.get_io_service(), [&m] {
    websocketpp::lib::error_code ec;
    m.ws.stop_listening(ec);
    for (auto& [h, subs] : m.clients) m.ws.close(h, websocketpp::close::status::going_away, "cellcal stopping", ec);
  });
  // run() returns once every close handshake is done; a client that does not answer is cut after 2 s.
  auto done = std::async(std::launch::async, [&m] { m.thread.join(); });
  if (done.wait_for(std::chrono::seconds(2)) != std::future_status::ready) m.ws.stop();
  done.wait();
}

std::uint16_t Server::port() const { return impl_->port; }
const std::vector<Channel>& Server::channels() const { return impl_->channels; }

void Server::publish(std::uint32_t channel_id, std::uint64_t receive_time_ns, std::string payload) {
  Impl* m = impl_.get();
  ++m->published;
  asio::post(m->ws.get_io_service(), [m, channel_id, receive_time_ns, p = std::move(payload)] {
    m->deliver(channel_id, receive_time_ns, p);
  });
}

void Server::broadcastStatus(StatusLevel level, const std::string& message) {
  Impl* m = impl_.get();
  asio::post(m->ws.get_io_service(), [m, text = statusJson(level, message)] {
    for (auto& [h, subs] : m->clients) m->send(h, text);
  });
}

ServerStats Server::stats() const {
  const Impl& m = *impl_;
  ServerStats s;
  s.clients_accepted = m.accepted;
  s.clients_rejected = m.rejected;
  s.clients_now = m.now;
  s.messages_published = m.published;
  s.frames_sent = m.sent;
  s.frames_dropped = m.dropped;
  s.bytes_sent = m.bytes;
  s.requests_refused = m.refused;
  return s;
}

}  // namespace cellcal::foxglove
