// bpinterests: many interest subscribers in one process against a running broadphased (whose
// scene bpctl scene publishes), beside one whole-world subscriber. Measures what each interest
// subscriber receives (payload bytes per second, against the whole world's), whether each keeps
// its exact set (OverlapView against the daemon's set size after every part), gaps, the CPU a
// subscriber spends on its stream against a receiver-side filter (the whole world decoded, then
// the pairs that involve its region's members kept; members it could only know from the boxes,
// here taken from its own stream), and the daemon's frame time from its status reports over
// the measured window. CPU is this thread's (decoding and the view); Cyclone's receive threads
// are not counted. scripts/interests-bench runs it; one JSON line on stdout.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <unordered_set>
#include <vector>

#include "config.h"
#include <CLI/CLI.hpp>

#include "bp/client/interests.h"
#include "bp/client/overlap_view.h"
#include "bp/client/subscriber.h"
#include "bp/util/percentile.h"
#include "bp/workload.h"
#include "bp/workload_scenarios.h"

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

double ThreadCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

struct Follower {
  uint64_t id = 0;
  std::unique_ptr<bp::client::EventSubscriber> sub;
  bp::client::OverlapView view;
  Clock::time_point asked{};
  uint64_t bytes = 0, parts = 0, mismatches = 0, checked = 0;
  std::unordered_set<uint64_t> members;  // its region's objects (for the receiver-side filter)
};

int Fail(const std::string& what) {
  std::fprintf(stderr, "bpinterests: %s\n", what.c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bpinterests: interest subscribers against a running broadphased"};
  std::string config_path, scenario = "S1-200k";
  int regions = 100;
  double fraction = 0.01, margin = 0, seconds = 20, warmup = 5;
  uint64_t seed = 1;
  app.add_option("--config", config_path, "the daemon's YAML (deployment, partition)")->required();
  app.add_option("--scenario", scenario, "the scene bpctl scene publishes (for its world size)");
  app.add_option("--regions", regions, "interest subscribers, one region each (0: none)")
      ->check(CLI::Range(0, 100000));
  app.add_option("--fraction", fraction, "each region's share of the world's volume")
      ->check(CLI::Range(1e-9, 1.0));
  app.add_option("--leave-margin", margin, "each region's leave margin")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seconds", seconds, "measured seconds")->check(CLI::PositiveNumber);
  app.add_option("--warmup", warmup, "seconds before the measurement")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", seed, "region placement");
  CLI11_PARSE(app, argc, argv);

  bp::service::Config config;
  if (bp::Status s = bp::service::LoadConfigFile(config_path, &config); !s.ok()) {
    return Fail(s.ToString());
  }
  const auto* golden = bp::workload::FindGolden(scenario);
  if (golden == nullptr) return Fail("unknown scenario '" + scenario + "'");
  const bp::workload::Scene scene(golden->Params());
  const double side = scene.side();
  const int dim = golden->dim;

  bp::transport::ConnectionOptions options;
  const auto& dds = config.dds;
  options.domain = dds.domain;
  options.partition = dds.partition;
  options.topics = {dds.topics.updates,  dds.topics.events,    dds.topics.status,
                    dds.topics.requests, dds.topics.interests, dds.topics.replies};
  if (!dds.cyclone_config.empty()) {
    if (bp::Status s = bp::transport::ReadTextFile(dds.cyclone_config, &options.cyclone_xml);
        !s.ok()) {
      return Fail(s.ToString());
    }
  }
  std::unique_ptr<bp::transport::Connection> connection;
  if (bp::Status s = bp::transport::Connection::Open(options, &connection); !s.ok()) {
    return Fail(s.ToString());
  }
  std::unique_ptr<bp::client::EventSubscriber> world;
  std::unique_ptr<bp::client::StatusSubscriber> status;
  std::unique_ptr<bp::client::SnapshotRequester> requests;
  std::unique_ptr<bp::client::InterestClient> interests;
  for (bp::Status s : {bp::client::EventSubscriber::Create(*connection, 4096, &world),
                       bp::client::StatusSubscriber::Create(*connection, 64, &status),
                       bp::client::SnapshotRequester::Create(*connection, &requests),
                       bp::client::InterestClient::Create(*connection, &interests)}) {
    if (!s.ok()) return Fail(s.ToString());
  }
  for (bp::Status s :
       {world->WaitForDaemon(20s), requests->WaitForDaemon(20s), interests->WaitForDaemon(20s)}) {
    if (!s.ok()) return Fail("no daemon: " + s.ToString());
  }

  // Regions: cubes of `fraction` of the world's volume, placed at random inside it.
  std::vector<Follower> followers(static_cast<size_t>(regions));
  std::mt19937_64 rng(seed);
  const double edge = side * std::pow(fraction, 1.0 / dim);
  std::uniform_real_distribution<double> at(0, std::max(0.0, side - edge));
  for (Follower& f : followers) {
    bp::wire::Interest in;
    f.id = bp::client::InterestClient::NewInterestId();
    in.set_id(f.id);
    in.set_dim(static_cast<uint32_t>(dim));
    for (int a = 0; a < dim; ++a) in.add_region_lo(at(rng));
    for (int a = 0; a < dim; ++a) in.add_region_hi(in.region_lo(a) + edge);
    in.set_leave_margin(margin);
    if (bp::Status s = bp::client::EventSubscriber::Create(*connection, 1024, &f.sub, f.id);
        !s.ok()) {
      return Fail(s.ToString());
    }
    if (bp::Status s = interests->Declare(in); !s.ok()) return Fail(s.ToString());
  }

  // The loop: every stream polled in turn. The counters restart after the warm-up.
  const auto start = Clock::now();
  const auto measure_from =
      start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(warmup));
  const auto until = measure_from + std::chrono::duration_cast<Clock::duration>(
                                        std::chrono::duration<double>(seconds));
  bool measuring = false;
  uint64_t world_bytes = 0, world_frames = 0, world_pairs = 0;
  double world_cpu = 0, interest_cpu = 0, filter_cpu = 0;
  static volatile uint64_t filter_sink = 0;  // keeps the filter from being optimised away
  uint64_t world_gaps0 = 0;
  std::vector<uint64_t> interest_gaps0(followers.size());
  std::vector<double> frame_p50, query_p50, publish_p50, daemon_fps;
  std::vector<bp::wire::EventBatch> parts;
  std::vector<bp::wire::DaemonStatus> reports;
  std::vector<bp::wire::InterestRefusal> refusals;
  while (Clock::now() < until) {
    if (!measuring && Clock::now() >= measure_from) {
      measuring = true;
      world_bytes = world_frames = world_pairs = 0;
      world_cpu = interest_cpu = filter_cpu = 0;
      world_gaps0 = world->gaps();
      for (size_t i = 0; i < followers.size(); ++i) {
        followers[i].bytes = followers[i].parts = 0;
        interest_gaps0[i] = followers[i].sub->gaps();
      }
    }
    bool any = false;
    // The whole world, and the receiver-side filter each subscriber would run on it.
    double t0 = ThreadCpuSeconds();
    parts.clear();
    if (bp::Status s = world->Poll(0ms, &parts); !s.ok()) return Fail(s.ToString());
    double t1 = ThreadCpuSeconds();
    world_cpu += t1 - t0;
    for (const auto& p : parts) {
      any = true;
      if (p.snapshot()) continue;
      world_bytes += p.ByteSizeLong();
      world_pairs += static_cast<uint64_t>(p.collide_size() + p.uncollide_size()) / 2;
      if (p.last_part()) ++world_frames;
      // One subscriber's filter stands for each one's (they differ only in their members).
      if (!followers.empty()) {
        uint64_t kept = 0;
        for (const auto* list : {&p.collide(), &p.uncollide()}) {
          for (int i = 0; i < list->size(); ++i) kept += followers[0].members.count((*list)[i]);
        }
        filter_sink = filter_sink + kept;
      }
    }
    filter_cpu += ThreadCpuSeconds() - t1;
    // Each interest's own stream.
    t0 = ThreadCpuSeconds();
    for (Follower& f : followers) {
      parts.clear();
      if (bp::Status s = f.sub->Poll(0ms, &parts); !s.ok()) return Fail(s.ToString());
      for (const auto& p : parts) {
        any = true;
        if (!p.snapshot()) {
          f.bytes += p.ByteSizeLong();
          ++f.parts;
          // The region's members, for the receiver-side filter: (region, object) pairs.
          for (int i = 0; i + 1 < p.uncollide_size(); i += 2) {
            if (p.uncollide(i) < (uint64_t{1} << 48)) f.members.erase(p.uncollide(i + 1));
          }
          for (int i = 0; i + 1 < p.collide_size(); i += 2) {
            if (p.collide(i) < (uint64_t{1} << 48)) f.members.insert(p.collide(i + 1));
          }
        } else {
          for (int i = 0; i + 1 < p.snapshot_pairs_size(); i += 2) {
            if (p.snapshot_pairs(i) < (uint64_t{1} << 48))
              f.members.insert(p.snapshot_pairs(i + 1));
          }
        }
        if (f.view.Apply(p)) f.asked = {};
        if (!p.snapshot() && p.last_part() && f.view.synced()) {
          ++f.checked;
          if (f.view.size() != p.overlaps()) ++f.mismatches;
        }
      }
      if (f.view.wants_snapshot() && Clock::now() - f.asked > 1s) {
        (void)requests->Request("bench", f.id);
        f.asked = Clock::now();
      }
    }
    interest_cpu += ThreadCpuSeconds() - t0;
    reports.clear();
    if (bp::Status s = status->Poll(0ms, &reports); !s.ok()) return Fail(s.ToString());
    for (const auto& r : reports) {
      refusals.clear();
      (void)interests->OnStatus(r, &refusals);
      if (!refusals.empty()) return Fail("interest refused: " + refusals[0].message());
      if (measuring && r.has_interval() && r.interval().frames() > 0) {
        frame_p50.push_back(r.interval().frame_ms_p50());
        query_p50.push_back(r.interval().query_ms_p50());
        publish_p50.push_back(r.interval().publish_ms_p50());
        daemon_fps.push_back(static_cast<double>(r.interval().frames()) / r.interval().seconds());
      }
    }
    if (!any) std::this_thread::sleep_for(1ms);
  }
  for (const Follower& f : followers) (void)interests->Drop(f.id);
  if (frame_p50.empty())
    return Fail("no status report with statistics from the daemon while measuring");

  std::vector<double> bytes_per_s;
  uint64_t gaps = 0, mismatches = 0, synced = 0, checked = 0;
  for (size_t i = 0; i < followers.size(); ++i) {
    const Follower& f = followers[i];
    bytes_per_s.push_back(static_cast<double>(f.bytes) / seconds);
    gaps += f.sub->gaps() - interest_gaps0[i];
    mismatches += f.mismatches;
    checked += f.checked;
    if (f.view.synced()) ++synced;
  }
  const double world_bps = static_cast<double>(world_bytes) / seconds;
  const double median_bps = bp::util::Percentile(bytes_per_s, 0.5);
  const double max_bps =
      bytes_per_s.empty() ? 0 : *std::max_element(bytes_per_s.begin(), bytes_per_s.end());
  const double n = std::max<double>(1, static_cast<double>(followers.size()));
  (void)filter_sink;
  std::printf(
      "{\"scenario\": \"%s\", \"regions\": %zu, \"fraction\": %g, \"leave_margin\": %g, "
      "\"seconds\": %g, \"world_frames_per_s\": %.2f, \"world_pairs_per_s\": %.0f, "
      "\"world_bytes_per_s\": %.0f, \"interest_bytes_per_s_median\": %.0f, "
      "\"interest_bytes_per_s_max\": %.0f, \"interest_to_world_median\": %.4f, "
      "\"interest_to_world_max\": %.4f, \"daemon_frame_ms_p50\": %.3f, \"daemon_query_ms_p50\": "
      "%.3f, \"daemon_publish_ms_p50\": %.3f, \"daemon_frames_per_s\": %.2f, "
      "\"world_gaps\": %llu, \"interest_gaps\": %llu, \"interests_synced\": %llu, "
      "\"interest_frames_checked\": %llu, \"interest_mismatches\": %llu, "
      "\"subscriber_cpu_ms_per_s_interest\": %.3f, "
      "\"subscriber_cpu_ms_per_s_receiver_filter\": %.3f}\n",
      scenario.c_str(), followers.size(), fraction, margin, seconds,
      static_cast<double>(world_frames) / seconds, static_cast<double>(world_pairs) / seconds,
      world_bps, median_bps, max_bps, world_bps > 0 ? median_bps / world_bps : 0.0,
      world_bps > 0 ? max_bps / world_bps : 0.0, bp::util::Percentile(frame_p50, 0.5),
      bp::util::Percentile(query_p50, 0.5), bp::util::Percentile(publish_p50, 0.5),
      bp::util::Percentile(daemon_fps, 0.5),
      static_cast<unsigned long long>(world->gaps() - world_gaps0),
      static_cast<unsigned long long>(gaps), static_cast<unsigned long long>(synced),
      static_cast<unsigned long long>(checked), static_cast<unsigned long long>(mismatches),
      interest_cpu / n / seconds * 1000.0, (world_cpu + filter_cpu) / seconds * 1000.0);
  return mismatches == 0 ? 0 : 1;
}
