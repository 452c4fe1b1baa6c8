// RFC 6455 handshake (server/web/websocket.h).
#include "gtest/gtest.h"
#include "server/web/websocket.h"

namespace dance::server {
namespace {

TEST(WebSocket, AcceptKeyMatchesRfc6455Example) {
  EXPECT_EQ(WebSocketAcceptKey("dGhlIHNhbXBsZSBub25jZQ=="), "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=");
}

}  // namespace
}  // namespace dance::server
