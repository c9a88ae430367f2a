// Invariant checking. BP_ASSERT: cheap O(1) checks, compiled in for debug builds and when
// BP_VALIDATE is set. With BP_VALIDATE every engine also runs its O(n) Validate() after each
// query (the validation switch the tests turn on). A failure goes to the failure handler: by
// default it prints and aborts; tests install one that turns it into a test failure, so the seed
// of the failing run is reported (as Jolt routes asserts to test failures).
#pragma once

#include <cstdio>
#include <cstdlib>

namespace bp {

/// Called with the place and the description of a broken invariant. If it returns, the
/// process aborts; a test handler may throw to unwind instead.
using FailureHandler = void (*)(const char* file, int line, const char* what);

namespace detail {
inline FailureHandler& FailureHandlerSlot() {
  static FailureHandler handler = nullptr;
  return handler;
}
}  // namespace detail

/// Installs handler (nullptr: the default, print and abort). Not thread-safe: call at start-up.
inline void SetFailureHandler(FailureHandler handler) { detail::FailureHandlerSlot() = handler; }

/// Reports a broken invariant; does not return normally.
[[noreturn]] inline void ReportFailure(const char* file, int line, const char* what) {
  if (FailureHandler handler = detail::FailureHandlerSlot()) handler(file, line, what);
  std::fprintf(stderr, "%s:%d: broken invariant: %s\n", file, line, what);
  std::abort();
}

#if defined(BP_VALIDATE)
/// True when engines validate themselves after every query.
inline constexpr bool kValidateEachQuery = true;
#else
inline constexpr bool kValidateEachQuery = false;
#endif

}  // namespace bp

#if !defined(NDEBUG) || defined(BP_VALIDATE)
#define BP_ASSERT(cond)                                                           \
  do {                                                                            \
    if (!(cond)) ::bp::ReportFailure(__FILE__, __LINE__, "BP_ASSERT(" #cond ")"); \
  } while (false)
#else
#define BP_ASSERT(cond) \
  do {                  \
  } while (false)
#endif
