// Routes broken engine invariants (BP_ASSERT, the per-query validators) to test failures: the
// failure is recorded with the active SCOPED_TRACE (seed, frame), then an exception unwinds the
// test instead of aborting the whole binary.
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "bp/detail/assert.h"

namespace {

void FailTest(const char* file, int line, const char* what) {
  ADD_FAILURE_AT(file, line) << "broken invariant: " << what;
  throw std::runtime_error(std::string("broken invariant: ") + what);
}

const bool kInstalled = (bp::SetFailureHandler(&FailTest), true);

TEST(Validation, SwitchIsOnInTests) {
  EXPECT_TRUE(kInstalled);
  EXPECT_TRUE(bp::kValidateEachQuery) << "engine tests must build with BP_VALIDATE";
}

}  // namespace
