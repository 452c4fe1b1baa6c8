#include "server/cluster/redis_client.h"

#include <hiredis/hiredis.h>
#include <sys/time.h>

#include <memory>
#include <utility>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace dance::server {
namespace {

RedisReply Flatten(const redisReply* r) {
  RedisReply out;
  switch (r->type) {
    case REDIS_REPLY_INTEGER:
      out.type = RedisReply::Type::kInteger;
      out.integer = r->integer;
      break;
    case REDIS_REPLY_STRING:
    case REDIS_REPLY_STATUS:
      out.type = RedisReply::Type::kString;
      out.str.assign(r->str, r->len);
      break;
    case REDIS_REPLY_ARRAY:
      out.type = RedisReply::Type::kArray;
      out.elements.reserve(r->elements);
      for (size_t i = 0; i < r->elements; ++i) out.elements.push_back(Flatten(r->element[i]));
      break;
    default:  // REDIS_REPLY_NIL (errors are handled by the caller)
      break;
  }
  return out;
}

struct ReplyDeleter {
  void operator()(redisReply* r) const { freeReplyObject(r); }
};
using ReplyPtr = std::unique_ptr<redisReply, ReplyDeleter>;


}  // namespace

RedisClient::RedisClient(std::string address, absl::Duration timeout)
    : address_(std::move(address)), timeout_(timeout) {}

RedisClient::~RedisClient() { Disconnect(); }

void RedisClient::Disconnect() {
  if (ctx_ != nullptr) redisFree(ctx_);
  ctx_ = nullptr;
}

absl::Status RedisClient::EnsureConnected() {
  if (ctx_ != nullptr) return absl::OkStatus();
  const size_t colon = address_.rfind(':');
  int port = 0;
  if (colon == std::string::npos || !absl::SimpleAtoi(address_.substr(colon + 1), &port)) {
    return absl::InvalidArgumentError(absl::StrCat("session store address is not host:port: ", address_));
  }
  const std::string host = address_.substr(0, colon);
  redisContext* c = redisConnectWithTimeout(host.c_str(), port, absl::ToTimeval(timeout_));
  if (c == nullptr || c->err != 0) {
    const std::string why = c != nullptr ? c->errstr : "out of memory";
    if (c != nullptr) redisFree(c);
    return absl::UnavailableError(absl::StrCat("session store ", address_, " unreachable: ", why));
  }
  redisSetTimeout(c, absl::ToTimeval(timeout_));
  ctx_ = c;
  return absl::OkStatus();
}

absl::StatusOr<RedisReply> RedisClient::Command(const std::vector<std::string>& args) {
  absl::StatusOr<std::vector<RedisReply>> r = Pipeline({args});
  if (!r.ok()) return r.status();
  return std::move((*r)[0]);
}

absl::StatusOr<std::vector<RedisReply>> RedisClient::Pipeline(const std::vector<std::vector<std::string>>& commands) {
  if (absl::Status s = EnsureConnected(); !s.ok()) return s;
  std::vector<const char*> argv;
  std::vector<size_t> argvlen;
  for (const auto& cmd : commands) {
    argv.clear();
    argvlen.clear();
    for (const std::string& a : cmd) {
      argv.push_back(a.data());
      argvlen.push_back(a.size());
    }
    if (redisAppendCommandArgv(ctx_, static_cast<int>(argv.size()), argv.data(), argvlen.data()) != REDIS_OK) {
      const std::string why = ctx_->errstr;
      Disconnect();
      return absl::UnavailableError(absl::StrCat("session store ", address_, ": ", why));
    }
  }
  std::vector<RedisReply> out;
  out.reserve(commands.size());
  absl::Status error = absl::OkStatus();
  for (size_t i = 0; i < commands.size(); ++i) {
    void* raw = nullptr;
    if (redisGetReply(ctx_, &raw) != REDIS_OK || raw == nullptr) {
      const std::string why = ctx_->errstr;
      Disconnect();
      return absl::UnavailableError(absl::StrCat("session store ", address_, ": ", why));
    }
    ReplyPtr reply(static_cast<redisReply*>(raw));
    if (reply->type == REDIS_REPLY_ERROR) {
      // Keep reading: the connection stays in step only if every reply is consumed.
      if (error.ok()) error = absl::InternalError(absl::StrCat("session store: ", std::string(reply->str, reply->len)));
      continue;
    }
    out.push_back(Flatten(reply.get()));
  }
  if (!error.ok()) return error;
  return out;
}

}  // namespace dance::server
