// RedisClient: one blocking connection to Redis (hiredis), reconnecting on demand. The cluster registry's
// two threads each own one; nothing on a gRPC reactor thread uses it.
//
// Usage:
//   RedisClient redis("127.0.0.1:6379", absl::Milliseconds(500));
//   absl::StatusOr<RedisReply> r = redis.Command({"GET", "dance:session:s-1"});
//   if (r.ok() && r->is_string()) use(r->str);
//   redis.Pipeline({{"SET", "k", "v", "EX", "5"}, {"ZADD", "z", "1", "m"}});   // one round trip
//
// Errors: UNAVAILABLE when the server cannot be reached or the connection breaks (the next call
// reconnects); INTERNAL for an error reply ("-ERR ..."), with Redis's message.
// Thread safety: none; one client per thread.
#ifndef DANCE_SERVER_CLUSTER_REDIS_CLIENT_H_
#define DANCE_SERVER_CLUSTER_REDIS_CLIENT_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"

struct redisContext;

namespace dance::server {

// A reply, flattened: nil, integer, string (bulk or status) or an array of replies.
struct RedisReply {
  enum class Type { kNil, kInteger, kString, kArray };
  Type type = Type::kNil;
  int64_t integer = 0;
  std::string str;
  std::vector<RedisReply> elements;
  bool is_string() const { return type == Type::kString; }
};

class RedisClient {
 public:
  // `address` is host:port. `timeout` bounds connecting and every command.
  RedisClient(std::string address, absl::Duration timeout);
  ~RedisClient();
  RedisClient(const RedisClient&) = delete;
  RedisClient& operator=(const RedisClient&) = delete;

  absl::StatusOr<RedisReply> Command(const std::vector<std::string>& args);
  // Sends every command, then reads every reply (one round trip). Fails as a whole on a connection error;
  // an error reply of one command fails the whole call too.
  absl::StatusOr<std::vector<RedisReply>> Pipeline(const std::vector<std::vector<std::string>>& commands);

  const std::string& address() const { return address_; }

 private:
  absl::Status EnsureConnected();
  void Disconnect();

  const std::string address_;
  const absl::Duration timeout_;
  redisContext* ctx_ = nullptr;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CLUSTER_REDIS_CLIENT_H_
