// KeepAwake: one SCHED_IDLE thread per CPU of the process, spinning only within the window after
// a Touch. Only eventual states are asserted: a SCHED_IDLE thread gets a CPU when nothing else
// wants it, which on a busy test machine may take a while.
#include "keep_awake.h"

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>

#include <dirent.h>
#include <gtest/gtest.h>
#include <sched.h>

namespace bp::service {
namespace {

using namespace std::chrono_literals;

// Polls until pred() holds or 30 s passed.
template <class Pred>
bool Eventually(Pred pred) {
  const auto until = std::chrono::steady_clock::now() + 30s;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > until) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

// Threads of this process whose scheduling policy (field 41 of /proc/self/task/TID/stat) is
// SCHED_IDLE.
int IdleClassThreads() {
  int count = 0;
  DIR* dir = opendir("/proc/self/task");
  if (dir == nullptr) return -1;
  while (dirent* entry = readdir(dir)) {
    if (entry->d_name[0] == '.') continue;
    std::ifstream in(std::string("/proc/self/task/") + entry->d_name + "/stat");
    std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const size_t close = stat.rfind(')');  // the name may hold spaces; fields follow it
    if (close == std::string::npos) continue;
    std::istringstream fields(stat.substr(close + 2));
    std::string field;
    for (int i = 3; i <= 41 && fields >> field; ++i) {
      if (i == 41 && field == std::to_string(SCHED_IDLE)) ++count;
    }
  }
  closedir(dir);
  return count;
}

unsigned AllowedCpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) != 0) return 1;
  return static_cast<unsigned>(CPU_COUNT(&set));
}

// Touches until some thread spun through a window and every thread waits again. Touched once,
// a thread that gets its CPU only after the window (a loaded machine) sees no deadline ahead and
// keeps waiting, so the touch is repeated while every thread still waits.
bool TouchUntilSpun(KeepAwake& keeper, uint64_t before) {
  return Eventually([&] {
    const bool all_waiting = keeper.waiting() == keeper.threads();
    if (all_waiting && keeper.rounds() > before) return true;
    if (all_waiting) keeper.Touch();
    return false;
  });
}

TEST(KeepAwake, OneIdleClassThreadPerCpuSpinsOnlyAfterATouch) {
  std::unique_ptr<KeepAwake> keeper;
  ASSERT_TRUE(KeepAwake::Start(20ms, &keeper).ok());
  ASSERT_NE(keeper, nullptr);
  EXPECT_EQ(keeper->threads(), std::min(AllowedCpus(), 256u));
  EXPECT_EQ(IdleClassThreads(), static_cast<int>(keeper->threads()));
  // No touch yet: every thread waits, none spun.
  ASSERT_TRUE(Eventually([&] { return keeper->waiting() == keeper->threads(); }));
  EXPECT_EQ(keeper->rounds(), 0u);
  // Touched: the threads spin through the window, then wait again.
  ASSERT_TRUE(TouchUntilSpun(*keeper, 0));
  const uint64_t after_window = keeper->rounds();
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(keeper->rounds(), after_window) << "spun outside the window";
  // Touched again, they spin again.
  ASSERT_TRUE(TouchUntilSpun(*keeper, after_window));
}

TEST(KeepAwake, StopsPromptlyWhileSpinning) {
  std::unique_ptr<KeepAwake> keeper;
  ASSERT_TRUE(KeepAwake::Start(60s, &keeper).ok());
  keeper->Touch();
  // At least one thread left its wait and spins (the window is a minute).
  ASSERT_TRUE(Eventually([&] { return keeper->waiting() < keeper->threads(); }));
  const auto start = std::chrono::steady_clock::now();
  keeper.reset();  // joins the threads: must not wait for the 60 s window
  // A SCHED_IDLE thread sees the stop only when its CPU has time for it: on a loaded machine
  // (tests in parallel) that took over a second here; well under the window anyway.
  EXPECT_LT(std::chrono::steady_clock::now() - start, 45s);
  // A joined thread may stay listed in /proc for a moment while it exits.
  EXPECT_TRUE(Eventually([] { return IdleClassThreads() == 0; }));
}

TEST(KeepAwake, RefusesAnEmptyWindow) {
  std::unique_ptr<KeepAwake> keeper;
  Status s = KeepAwake::Start(0ms, &keeper);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(keeper, nullptr);
}

}  // namespace
}  // namespace bp::service
