#include "server/cluster/registry.h"

#include <algorithm>
#include <utility>

#include "absl/strings/str_cat.h"
#include "server/cluster/redis_client.h"
#include "server/log.h"

namespace dance::server {
namespace {

std::string UnixMs(absl::Time t) { return absl::StrCat(absl::ToUnixMillis(t)); }
std::string Seconds(absl::Duration d) { return absl::StrCat(std::max<int64_t>(1, absl::ToInt64Seconds(d))); }

}  // namespace

ClusterRegistry::ClusterRegistry(ClusterOptions options, LiveIds live_ids)
    : options_(std::move(options)), live_ids_(std::move(live_ids)) {}

ClusterRegistry::~ClusterRegistry() { Stop(); }

void ClusterRegistry::Start(int grpc_port, int http_port) {
  const std::string host = options_.advertise_host.empty() ? "127.0.0.1" : options_.advertise_host;
  self_.grpc_address = absl::StrCat(host, ":", grpc_port);
  self_.http_address = http_port > 0 ? absl::StrCat(host, ":", http_port) : "";
  self_.id = options_.server_id.empty() ? self_.grpc_address : options_.server_id;
  {
    absl::MutexLock lock(&mu_);
    if (started_) return;
    started_ = true;
  }
  sync_thread_ = std::thread([this] { SyncLoop(); });
  lookup_thread_ = std::thread([this] { LookupLoop(); });
}

void ClusterRegistry::Stop() {
  {
    absl::MutexLock lock(&mu_);
    if (!started_ || stopping_) return;
    stopping_ = true;
  }
  if (sync_thread_.joinable()) sync_thread_.join();
  if (lookup_thread_.joinable()) lookup_thread_.join();
}

void ClusterRegistry::SessionsChanged() {
  absl::MutexLock lock(&mu_);
  changed_ = true;
}

std::vector<Peer> ClusterRegistry::Peers() const {
  absl::MutexLock lock(&mu_);
  return peers_;
}

void ClusterRegistry::Lookup(std::string session_id, absl::Time deadline, LookupCallback done) {
  {
    absl::MutexLock lock(&mu_);
    if (started_ && !stopping_) {
      jobs_.push_back(Job{std::move(session_id), deadline, absl::InfinitePast(), std::move(done)});
      ++job_seq_;
      return;
    }
  }
  done(absl::UnavailableError("session store: this server is not in a cluster or is stopping"));
}

absl::StatusOr<Peer> ClusterRegistry::LookupBlocking(const std::string& session_id, absl::Time deadline) {
  absl::Mutex m;
  bool ready = false;
  absl::StatusOr<Peer> result = absl::UnknownError("");
  Lookup(session_id, deadline, [&](absl::StatusOr<Peer> p) {
    absl::MutexLock lock(&m);
    result = std::move(p);
    ready = true;
  });
  absl::MutexLock lock(&m);
  m.Await(absl::Condition(&ready));
  return result;
}

// Mirrors this server and its live sessions into the store. On a change it writes only the difference (a
// new session reaches the store within a millisecond or so of its admission); on each heartbeat it
// rewrites everything with fresh expiry times, which also heals a store that lost its data.
void ClusterRegistry::SyncLoop() {
  RedisClient redis(options_.store_address, options_.store_timeout);
  absl::flat_hash_set<std::string> mirrored;  // ids written to the store and not deleted since
  absl::Time next_heartbeat = absl::InfinitePast();
  bool store_was_down = false;
  const std::string ttl_s = Seconds(options_.ttl);
  for (;;) {
    bool heartbeat = false;
    {
      absl::MutexLock lock(&mu_);
      auto wake = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return changed_ || stopping_; };
      mu_.AwaitWithDeadline(absl::Condition(&wake), next_heartbeat);
      if (stopping_) break;
      changed_ = false;
      heartbeat = absl::Now() >= next_heartbeat;
    }
    const absl::Time now = absl::Now();
    std::vector<std::string> live = live_ids_();
    absl::flat_hash_set<std::string> live_set(live.begin(), live.end());
    std::vector<std::vector<std::string>> cmds;
    for (const std::string& id : live) {
      if (heartbeat || !mirrored.contains(id)) cmds.push_back({"SET", Key("session:" + id), self_.id, "EX", ttl_s});
    }
    std::vector<std::string> ended;
    for (const std::string& id : mirrored) {
      if (!live_set.contains(id)) ended.push_back(id);
    }
    for (const std::string& id : ended) cmds.push_back({"DEL", Key("session:" + id)});
    size_t peers_reply = 0;
    if (heartbeat) {
      cmds.push_back({"HSET", Key("server:" + self_.id), "grpc", self_.grpc_address, "http", self_.http_address});
      cmds.push_back({"EXPIRE", Key("server:" + self_.id), ttl_s});
      cmds.push_back({"ZADD", Key("servers"), UnixMs(now), self_.id});
      // Servers silent for ten times the ttl are long dead: forget them.
      cmds.push_back({"ZREMRANGEBYSCORE", Key("servers"), "-inf", UnixMs(now - 10 * options_.ttl)});
      peers_reply = cmds.size();
      cmds.push_back({"ZRANGEBYSCORE", Key("servers"), UnixMs(now - options_.ttl), "+inf"});
    }
    if (cmds.empty()) continue;
    absl::StatusOr<std::vector<RedisReply>> replies = redis.Pipeline(cmds);
    if (!replies.ok()) {
      if (!store_was_down) Log(LogLevel::kWarning, "store_unavailable", {{"error", replies.status().ToString()}});
      store_was_down = true;
      mirrored.clear();  // rewrite everything once the store is back
      absl::MutexLock lock(&mu_);
      next_heartbeat = absl::Now() + options_.heartbeat;
      continue;
    }
    if (store_was_down) Log(LogLevel::kInfo, "store_available", {{"store", options_.store_address}});
    store_was_down = false;
    mirrored = std::move(live_set);
    if (!heartbeat) continue;
    next_heartbeat = now + options_.heartbeat;
    std::vector<std::vector<std::string>> gets;
    for (const RedisReply& id : (*replies)[peers_reply].elements) {
      if (id.str != self_.id) gets.push_back({"HMGET", Key("server:" + id.str), "grpc", "http"});
    }
    std::vector<Peer> peers;
    if (!gets.empty()) {
      absl::StatusOr<std::vector<RedisReply>> addrs = redis.Pipeline(gets);
      if (!addrs.ok()) continue;
      for (size_t i = 0; i < addrs->size(); ++i) {
        const RedisReply& a = (*addrs)[i];
        if (a.elements.size() != 2 || !a.elements[0].is_string()) continue;  // expired meanwhile
        peers.push_back(Peer{gets[i][1].substr(Key("server:").size()), a.elements[0].str, a.elements[1].str});
      }
    }
    absl::MutexLock lock(&mu_);
    peers_ = std::move(peers);
  }
  // Leaving: take this server and its sessions out of the store (best effort; they expire anyway).
  std::vector<std::vector<std::string>> cmds = {{"ZREM", Key("servers"), self_.id},
                                                {"DEL", Key("server:" + self_.id)}};
  for (const std::string& id : mirrored) cmds.push_back({"DEL", Key("session:" + id)});
  (void)redis.Pipeline(cmds);
}

void ClusterRegistry::LookupLoop() {
  RedisClient redis(options_.store_address, options_.store_timeout);
  for (;;) {
    Job job;
    {
      absl::MutexLock lock(&mu_);
      bool have_job = false;
      while (!stopping_ && !have_job) {
        const absl::Time now = absl::Now();
        absl::Time next = absl::InfiniteFuture();
        for (auto it = jobs_.begin(); it != jobs_.end(); ++it) {
          if (it->next_try <= now) {
            job = std::move(*it);
            jobs_.erase(it);
            have_job = true;
            break;
          }
          next = std::min(next, it->next_try);
        }
        if (have_job) break;
        // Sleep until a retried job is due, a new one arrives or Stop.
        const uint64_t seen = job_seq_;
        auto woken = [this, seen]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return stopping_ || job_seq_ != seen; };
        mu_.AwaitWithDeadline(absl::Condition(&woken), next);
      }
      if (!have_job) break;
    }
    absl::StatusOr<RedisReply> owner = redis.Command({"GET", Key("session:" + job.session_id)});
    absl::StatusOr<Peer> result = absl::NotFoundError(absl::StrCat("no live session ", job.session_id));
    if (!owner.ok()) {
      result = owner.status();
    } else if (owner->is_string()) {
      absl::StatusOr<RedisReply> addr = redis.Command({"HMGET", Key("server:" + owner->str), "grpc", "http"});
      if (!addr.ok()) {
        result = addr.status();
      } else if (addr->elements.size() == 2 && addr->elements[0].is_string()) {
        result = Peer{owner->str, addr->elements[0].str, addr->elements[1].str};
      }
    }
    if (absl::IsNotFound(result.status()) && absl::Now() + absl::Milliseconds(20) < job.deadline) {
      job.next_try = absl::Now() + absl::Milliseconds(20);
      absl::MutexLock lock(&mu_);
      jobs_.push_back(std::move(job));
      ++job_seq_;
      continue;
    }
    job.done(std::move(result));
  }
  std::deque<Job> left;
  {
    absl::MutexLock lock(&mu_);
    left.swap(jobs_);
  }
  for (Job& j : left) j.done(absl::UnavailableError("server shutting down"));
}

}  // namespace dance::server
