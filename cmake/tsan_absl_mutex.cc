// ThreadSanitizer builds only (DANCE_SANITIZE=thread): makes absl::Mutex visible to TSan.
//
// Debian's libabsl is not built with -fsanitize=thread, so TSan cannot see the happens-before edges of
// absl::Mutex (its atomics and futex waits live in the uninstrumented library) and reports every access
// guarded by one as a data race. This file defines the absl::Mutex entry points used by the project (and by
// gRPC, whose grpc_core::Mutex wraps absl::Mutex): the executable's definitions take precedence over the
// shared library's (ELF interposition), call the library's through dlsym(RTLD_NEXT) and tell TSan about
// the acquire/release. An abseil built with TSan annotates itself; then this file is not needed.
#include <dlfcn.h>

#include <cstdio>
#include <cstdlib>
#include <string>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

extern "C" void __tsan_acquire(void* addr);
extern "C" void __tsan_release(void* addr);

namespace {

#define DANCE_STR2(x) #x
#define DANCE_STR(x) DANCE_STR2(x)

// Itanium mangling of absl::<inline ns>::Mutex::<method><args>.
std::string Mangled(const char* method_and_args) {
  const std::string ns = DANCE_STR(ABSL_OPTION_INLINE_NAMESPACE_NAME);
  return "_ZN4absl" + std::to_string(ns.size()) + ns + "5Mutex" + method_and_args;
}

template <typename Fn>
Fn Real(const char* method_and_args) {
  const std::string name = Mangled(method_and_args);
  void* f = dlsym(RTLD_NEXT, name.c_str());
  if (f == nullptr) {
    std::fprintf(stderr, "tsan_absl_mutex: %s not found\n", name.c_str());
    std::abort();
  }
  return reinterpret_cast<Fn>(f);
}

// absl evaluates a waiter's Condition with the mutex held, but inside the library (by the waiter or by
// the thread that unlocks): wrap it so each evaluation acquires and releases the mutex for TSan too.
struct AnnotatedCondition {
  const absl::Condition* inner;
  void* mu;
  static bool Eval(void* arg) {
    auto* self = static_cast<AnnotatedCondition*>(arg);
    __tsan_acquire(self->mu);
    const bool r = self->inner->Eval();
    __tsan_release(self->mu);
    return r;
  }
};

}  // namespace

namespace absl {
ABSL_NAMESPACE_BEGIN

void Mutex::Lock() {
  static const auto real = Real<void (*)(Mutex*)>("4LockEv");
  real(this);
  __tsan_acquire(this);
}

bool Mutex::TryLock() {
  static const auto real = Real<bool (*)(Mutex*)>("7TryLockEv");
  const bool ok = real(this);
  if (ok) __tsan_acquire(this);
  return ok;
}

void Mutex::Unlock() {
  static const auto real = Real<void (*)(Mutex*)>("6UnlockEv");
  __tsan_release(this);
  real(this);
}

void Mutex::ReaderLock() {
  static const auto real = Real<void (*)(Mutex*)>("10ReaderLockEv");
  real(this);
  __tsan_acquire(this);
}

void Mutex::ReaderUnlock() {
  static const auto real = Real<void (*)(Mutex*)>("12ReaderUnlockEv");
  __tsan_release(this);
  real(this);
}

// Await* release the mutex while waiting and hold it again on return.
void Mutex::Await(const Condition& cond) {
  static const auto real = Real<void (*)(Mutex*, const Condition&)>("5AwaitERKNS0_9ConditionE");
  __tsan_release(this);
  AnnotatedCondition ac{&cond, this};
  real(this, Condition(&AnnotatedCondition::Eval, &ac));
  __tsan_acquire(this);
}

bool Mutex::AwaitWithTimeout(const Condition& cond, absl::Duration timeout) {
  static const auto real =
      Real<bool (*)(Mutex*, const Condition&, absl::Duration)>("16AwaitWithTimeoutERKNS0_9ConditionENS0_8DurationE");
  __tsan_release(this);
  AnnotatedCondition ac{&cond, this};
  const bool r = real(this, Condition(&AnnotatedCondition::Eval, &ac), timeout);
  __tsan_acquire(this);
  return r;
}

bool Mutex::AwaitWithDeadline(const Condition& cond, absl::Time deadline) {
  static const auto real =
      Real<bool (*)(Mutex*, const Condition&, absl::Time)>("17AwaitWithDeadlineERKNS0_9ConditionENS0_4TimeE");
  __tsan_release(this);
  AnnotatedCondition ac{&cond, this};
  const bool r = real(this, Condition(&AnnotatedCondition::Eval, &ac), deadline);
  __tsan_acquire(this);
  return r;
}

void Mutex::LockWhen(const Condition& cond) {
  static const auto real = Real<void (*)(Mutex*, const Condition&)>("8LockWhenERKNS0_9ConditionE");
  AnnotatedCondition ac{&cond, this};
  real(this, Condition(&AnnotatedCondition::Eval, &ac));
  __tsan_acquire(this);
}

bool Mutex::LockWhenWithTimeout(const Condition& cond, absl::Duration timeout) {
  static const auto real = Real<bool (*)(Mutex*, const Condition&, absl::Duration)>(
      "19LockWhenWithTimeoutERKNS0_9ConditionENS0_8DurationE");
  AnnotatedCondition ac{&cond, this};
  const bool r = real(this, Condition(&AnnotatedCondition::Eval, &ac), timeout);
  __tsan_acquire(this);
  return r;
}

bool Mutex::LockWhenWithDeadline(const Condition& cond, absl::Time deadline) {
  static const auto real = Real<bool (*)(Mutex*, const Condition&, absl::Time)>(
      "20LockWhenWithDeadlineERKNS0_9ConditionENS0_4TimeE");
  AnnotatedCondition ac{&cond, this};
  const bool r = real(this, Condition(&AnnotatedCondition::Eval, &ac), deadline);
  __tsan_acquire(this);
  return r;
}

ABSL_NAMESPACE_END
}  // namespace absl
