// A Foxglove WebSocket server (protocol.hpp) for a read-only live source: it advertises a fixed set of channels to
// every client, keeps each client's subscriptions, and sends each published message to the clients subscribed to
// its channel. Its own thread runs the sockets; publish() may be called from any thread and never blocks on a
// client: a client that reads slower than the source loses messages (counted) instead of growing the server's memory
// or delaying the others.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "cellcal/foxglove/protocol.hpp"

namespace cellcal::foxglove {

struct ServerOptions {
  std::string address = "127.0.0.1";  // "0.0.0.0": every interface
  std::uint16_t port = 8765;          // Foxglove's default; 0: any free port (port() says which)
  std::string name = "cellcal";
  std::map<std::string, std::string> metadata;  // in serverInfo
  // A client with more than this queued and unsent loses the messages that would add to it.
  std::size_t max_queued_bytes_per_client = 16u << 20;
};

struct ServerStats {
  std::uint64_t clients_accepted = 0;
  std::uint64_t clients_rejected = 0;   // handshakes without the foxglove.websocket.v1 subprotocol
  std::uint64_t clients_now = 0;
  std::uint64_t messages_published = 0;  // publish() calls
  std::uint64_t frames_sent = 0;         // Message Data frames handed to a client's socket
  std::uint64_t frames_dropped = 0;      // not sent: the client had more than max_queued_bytes_per_client queued
  std::uint64_t bytes_sent = 0;
  std::uint64_t requests_refused = 0;    // client requests answered with an error status
};

class Server {
 public:
  // Listens on address:port and starts serving. Throws std::runtime_error naming the address and port when it
  // cannot (in use, no such address). Channel ids must be unique.
  Server(const ServerOptions& options, std::vector<Channel> channels);
  // Closes every connection (going away) and stops the thread.
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  std::uint16_t port() const;
  const std::vector<Channel>& channels() const;
  // Queues `payload` for every client subscribed to `channel_id`. Thread-safe, non-blocking.
  void publish(std::uint32_t channel_id, std::uint64_t receive_time_ns, std::string payload);
  // A status message to every connected client.
  void broadcastStatus(StatusLevel level, const std::string& message);
  ServerStats stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellcal::foxglove
