// RelayHttpUpgrade: hands a browser's WebSocket request (/ws/watch of a session another server holds) to
// that server and copies the bytes both ways until either side closes: the browser talks to the owner as
// if directly, through whichever server the proxy picked. The request head is sent again with
// "X-Dance-Peer: 1" (the owner then answers from its own sessions only, so a stale entry cannot loop).
//
// Usage (dance_server.cc, in the HTTP handler, on the connection's own thread):
//   if (peer.ok()) RelayHttpUpgrade(request, connection.fd(), peer->http_address);
//
// Blocks until the relayed connection ends (HttpServer::Stop ends it by shutting the client socket).
// Errors: UNAVAILABLE when the owner cannot be reached (nothing has been written to the client then).
#ifndef DANCE_SERVER_CLUSTER_HTTP_RELAY_H_
#define DANCE_SERVER_CLUSTER_HTTP_RELAY_H_

#include <string>

#include "absl/status/status.h"
#include "server/web/http_server.h"

namespace dance::server {

inline constexpr char kPeerHeader[] = "x-dance-peer";

absl::Status RelayHttpUpgrade(const HttpRequest& request, int client_fd, const std::string& upstream_address);

// The request head as sent upstream (exposed for tests): request line with the query re-encoded, every
// header, then X-Dance-Peer.
std::string RelayRequestHead(const HttpRequest& request);

}  // namespace dance::server

#endif  // DANCE_SERVER_CLUSTER_HTTP_RELAY_H_
