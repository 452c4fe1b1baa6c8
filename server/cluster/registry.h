// ClusterRegistry: where every live session of a cluster of dance-servers is, kept in Redis.
//
// Each server heartbeats itself and mirrors the ids of its own live sessions into the store; any server can
// then find the server that holds a session (to relay a Watch to it) and list its live peers (to gather
// ListSessions). Keys (prefix "dance:" by default; docs/server.md, "Several servers"):
//   <p>servers            ZSET  server id -> unix ms of its last heartbeat (peers: seen within `ttl`)
//   <p>server:<id>        HASH  grpc = host:port, http = host:port; expires after `ttl` without a heartbeat
//   <p>session:<sid>      STRING the owning server's id; expires after `ttl` unless refreshed by the owner
// So a dead server's entries vanish after `ttl` on their own, and a restarted (emptied) store is
// re-filled by the next heartbeat.
//
// Threads: a sync thread (heartbeat every `heartbeat`, and at once after SessionsChanged()) and a lookup
// thread (Lookup's queue), each with its own connection. Nothing blocks the caller except LookupBlocking.
// A store that is down never touches live sessions: heartbeats log a warning and retry, lookups fail with
// UNAVAILABLE.
//
// Usage:
//   ClusterRegistry reg(options, [&hub] { return hub.LiveIds(); });
//   reg.Start();                                    // after the ports are known
//   reg.SessionsChanged();                          // from the hub's listener: mirror now
//   reg.Lookup("s-...", absl::Now() + absl::Seconds(1), [](absl::StatusOr<Peer> p) { ... });
//   reg.Stop();                                     // removes this server's entries; fails pending lookups
//
// Thread safety: every public method is thread-safe. Lookup callbacks run on the lookup thread and must
// not block.
#ifndef DANCE_SERVER_CLUSTER_REGISTRY_H_
#define DANCE_SERVER_CLUSTER_REGISTRY_H_

#include <cstdint>
#include <deque>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace dance::server {

struct ClusterOptions {
  std::string store_address;      // Redis host:port; empty = no cluster (a single server)
  std::string server_id;          // unique per server; empty = "<advertise_host>:<grpc port>"
  std::string advertise_host;     // how peers reach this server (pod IP, 127.0.0.1); empty = 127.0.0.1
  std::string key_prefix = "dance:";
  absl::Duration heartbeat = absl::Seconds(1);
  absl::Duration ttl = absl::Seconds(5);  // entries live this long without a heartbeat
  // A Watch for a session not (yet) in the store is retried this long before NOT_FOUND: covers a session
  // admitted elsewhere a moment ago, before its owner's mirror reached the store.
  absl::Duration lookup_wait = absl::Seconds(1);
  absl::Duration store_timeout = absl::Milliseconds(500);
};

// A server of the cluster.
struct Peer {
  std::string id;
  std::string grpc_address;  // host:port
  std::string http_address;  // host:port, empty if it has no HTTP server
};

class ClusterRegistry {
 public:
  using LiveIds = std::function<std::vector<std::string>()>;
  using LookupCallback = std::function<void(absl::StatusOr<Peer>)>;

  // `live_ids` lists this server's live session ids (called on the sync thread).
  ClusterRegistry(ClusterOptions options, LiveIds live_ids);
  ~ClusterRegistry();  // Stop()
  ClusterRegistry(const ClusterRegistry&) = delete;
  ClusterRegistry& operator=(const ClusterRegistry&) = delete;

  // Sets this server's addresses and starts both threads.
  void Start(int grpc_port, int http_port);
  // Removes this server and its sessions from the store; pending lookups fail with UNAVAILABLE.
  void Stop();

  void SessionsChanged();
  // Finds the server holding `session_id`, retrying a miss until `deadline`: NOT_FOUND when no server
  // holds it, UNAVAILABLE when the store cannot be reached.
  void Lookup(std::string session_id, absl::Time deadline, LookupCallback done);
  absl::StatusOr<Peer> LookupBlocking(const std::string& session_id, absl::Time deadline);
  // Live servers as of the last heartbeat, this one excluded.
  std::vector<Peer> Peers() const;

  const Peer& self() const { return self_; }
  const ClusterOptions& options() const { return options_; }

 private:
  struct Job {
    std::string session_id;
    absl::Time deadline;
    absl::Time next_try;
    LookupCallback done;
  };
  void SyncLoop();
  void LookupLoop();
  std::string Key(const std::string& rest) const { return options_.key_prefix + rest; }

  const ClusterOptions options_;
  const LiveIds live_ids_;
  Peer self_;
  std::thread sync_thread_;
  std::thread lookup_thread_;

  mutable absl::Mutex mu_;
  bool started_ ABSL_GUARDED_BY(mu_) = false;
  bool stopping_ ABSL_GUARDED_BY(mu_) = false;
  bool changed_ ABSL_GUARDED_BY(mu_) = false;
  std::vector<Peer> peers_ ABSL_GUARDED_BY(mu_);
  std::deque<Job> jobs_ ABSL_GUARDED_BY(mu_);
  uint64_t job_seq_ ABSL_GUARDED_BY(mu_) = 0;  // bumped by every push: wakes the lookup thread
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CLUSTER_REGISTRY_H_
