// BP_ASSERT: cheap invariant checks, compiled in for debug builds and when BP_VALIDATE is set
// (tests and CI); an O(1) condition only. O(n) checks belong in Validate() members.
#pragma once

#include <cstdio>
#include <cstdlib>

#if !defined(NDEBUG) || defined(BP_VALIDATE)
#define BP_ASSERT(cond)                                                                  \
  do {                                                                                   \
    if (!(cond)) {                                                                       \
      std::fprintf(stderr, "%s:%d: BP_ASSERT(%s) failed\n", __FILE__, __LINE__, #cond);  \
      std::abort();                                                                      \
    }                                                                                    \
  } while (false)
#else
#define BP_ASSERT(cond) \
  do {                  \
  } while (false)
#endif
