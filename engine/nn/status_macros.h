// Early-return helpers for absl::Status / absl::StatusOr (internal to the engine's .cc files).
//
//   DANCE_RETURN_IF_ERROR(DoThing());
//   DANCE_ASSIGN_OR_RETURN(member_, LoadMatrix(file, name, rows, cols));
#ifndef DANCE_ENGINE_NN_STATUS_MACROS_H_
#define DANCE_ENGINE_NN_STATUS_MACROS_H_

#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define DANCE_RETURN_IF_ERROR(expr)                \
  do {                                             \
    const absl::Status dance_status_ = (expr);     \
    if (!dance_status_.ok()) return dance_status_; \
  } while (0)

#define DANCE_STATUS_CONCAT_INNER_(a, b) a##b
#define DANCE_STATUS_CONCAT_(a, b) DANCE_STATUS_CONCAT_INNER_(a, b)

#define DANCE_ASSIGN_OR_RETURN(lhs, expr) \
  DANCE_ASSIGN_OR_RETURN_IMPL_(DANCE_STATUS_CONCAT_(dance_statusor_, __LINE__), lhs, expr)

#define DANCE_ASSIGN_OR_RETURN_IMPL_(statusor, lhs, expr) \
  auto statusor = (expr);                                 \
  if (!statusor.ok()) return statusor.status();           \
  lhs = *std::move(statusor)

#endif  // DANCE_ENGINE_NN_STATUS_MACROS_H_
