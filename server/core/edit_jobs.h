// EditJobs: the diffusion editor's job queue. A few worker threads take jobs in order of arrival; a bounded
// queue and a per-client cap keep one client from taking every worker; a job cancelled while queued never
// runs and one cancelled while running stops at its next denoising step, freeing its worker.
//
// Usage:
//   EditJobs jobs(editor.get(), {.workers = 1, .max_queued = 8, .max_per_client = 1});
//   ASSIGN_OR_RETURN(std::shared_ptr<EditJob> job, jobs.Submit("ipv4:10.0.0.7", config, listener));
//   ... job->Cancel();                    // e.g. the call was cancelled
//   jobs.Shutdown();                      // cancels everything, joins the workers (also the destructor)
//
// The listener runs on a worker thread (or on Submit's caller for the first "queued" event): events are
// kQueued (position = jobs ahead), kProgress, then exactly one kDone with the status and output.
//
// Thread safety: every public method is thread-safe.
#ifndef DANCE_SERVER_CORE_EDIT_JOBS_H_
#define DANCE_SERVER_CORE_EDIT_JOBS_H_

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_map.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "server/core/editor_port.h"

namespace dance::server {

struct EditJobsOptions {
  int workers = 1;            // edits that run at once (each uses one thread)
  int max_queued = 8;         // jobs waiting (not running) before RESOURCE_EXHAUSTED
  int max_per_client = 1;     // jobs queued or running per client key
  double max_audio_s = 600.0; // longest song
};

struct EditEvent {
  enum class Kind { kQueued, kProgress, kDone };
  Kind kind = Kind::kQueued;
  int position = 0;              // kQueued
  EditProgress progress;         // kProgress
  absl::Status status;           // kDone
  std::shared_ptr<EditOutput> output;  // kDone with OK
  double compute_s = 0.0;        // kDone: the run time
};

// The request's numbers and sizes against the editor: INVALID_ARGUMENT naming the field (no audio, steps
// outside 0..1000, guidance outside [0, 100], overlap_s outside [0, window), a client name over 64 bytes,
// a style weight that is negative or not finite, controls of a bad shape).
absl::Status ValidateEditConfig(const EditConfig& config, const EditorDescription& editor);

class EditJob {
 public:
  void Cancel() { cancelled_.store(true); }
  bool cancelled() const { return cancelled_.load(); }

 private:
  friend class EditJobs;
  std::string client;
  EditConfig config;
  std::function<void(const EditEvent&)> listener;
  std::atomic<bool> cancelled_{false};
};

class EditJobs {
 public:
  EditJobs(const EditorBackend* editor, EditJobsOptions options);
  ~EditJobs();
  EditJobs(const EditJobs&) = delete;
  EditJobs& operator=(const EditJobs&) = delete;

  // RESOURCE_EXHAUSTED when the queue is full or `client` has max_per_client jobs; UNAVAILABLE after
  // Shutdown.
  absl::StatusOr<std::shared_ptr<EditJob>> Submit(std::string client, EditConfig config,
                                                  std::function<void(const EditEvent&)> listener);
  void Shutdown();

  const EditJobsOptions& options() const { return options_; }
  const EditorBackend* editor() const { return editor_; }
  int running() const;
  int queued() const;

 private:
  void Work();
  void Finish(const std::shared_ptr<EditJob>& job) ABSL_LOCKS_EXCLUDED(mu_);

  const EditorBackend* const editor_;
  const EditJobsOptions options_;
  mutable absl::Mutex mu_;
  std::deque<std::shared_ptr<EditJob>> queue_ ABSL_GUARDED_BY(mu_);
  absl::flat_hash_map<std::string, int> per_client_ ABSL_GUARDED_BY(mu_);
  int running_ ABSL_GUARDED_BY(mu_) = 0;
  bool stopping_ ABSL_GUARDED_BY(mu_) = false;
  std::vector<std::thread> workers_;
};

}  // namespace dance::server

#endif  // DANCE_SERVER_CORE_EDIT_JOBS_H_
