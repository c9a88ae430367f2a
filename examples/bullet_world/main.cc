// bullet_world: a Bullet rigid-body simulation as a producer of broadphased, checked against
// Bullet's own pairs at every step.
//
// Each step (1/60 s of simulated time) it steps the world (world.h), publishes one frame:
// inserts for new bodies (static geometry flagged static), updates only for bodies whose box
// changed (resting bodies send nothing), erases for removed ones; and states the events it
// expects: the difference between Bullet's overlapping pairs after this step and after the last
// one. It subscribes to the daemon's events and compares them frame by frame (checker.h). At the
// end it erases its objects in one last frame (also checked) and prints a summary.
//
//   bullet_world --bodies 5000 --steps 600 --cyclone-config config/cyclonedds-loopback.xml
//   bullet_world --bodies 300 --steps 300 --domain 18 --partition test --csv steps.csv --json
//
// Exit status: 0 when every frame was received and equal to Bullet's; 1 when a frame differed
// or was not received (each is reported); 2 on bad arguments or no daemon.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <iterator>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "checker.h"
#include "world.h"
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "bp/client/batch_builder.h"
#include "bp/client/connection.h"
#include "bp/client/update_publisher.h"

namespace {

using Clock = std::chrono::steady_clock;
using bp::examples::BodyBox;
using bp::examples::FrameCheck;

std::atomic<bool> stop_requested{false};
extern "C" void OnSignal(int) { stop_requested.store(true); }

struct Options {
  bp::examples::WorldOptions world;
  uint32_t steps = 600;
  double rate_hz = 60;
  uint32_t domain = 0;
  std::string partition;
  std::string cyclone_config;
  uint32_t producer = 1;
  uint32_t max_batch_items = 65536;
  uint32_t readers = 1;
  double wait_s = 10;
  bool check = true;
  bool keep = false;
  bool json = false;
  bool quiet = false;
  std::string csv;
};

// What a step did, kept until its events are compared.
struct StepRow {
  size_t bodies = 0, awake = 0, inserts = 0, updates = 0, erases = 0, pairs = 0;
  size_t collides = 0, uncollides = 0;
  double step_ms = 0, broadphase_ms = 0, pairs_ms = 0, publish_ms = 0;
};

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5)];
}

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

void Add(bp::wire::BoxArray* array, const BodyBox& b, bool with_static_flag) {
  bp::client::AddBox<3>(array, b.id, bp::Box<3, float>{b.lo, b.hi});
  if (with_static_flag) array->add_static_flags(b.is_static);
}

// Publishes one frame's changes in batches of at most max_items items, the last closing the
// frame; returns the last batch's sent time (the one the daemon's events carry).
bp::Status PublishFrame(bp::client::UpdatePublisher& pub, const bp::examples::WorldChanges& c,
                        uint64_t frame, uint32_t max_items, uint64_t* out_sent_ns) {
  bp::wire::UpdateBatch batch;
  size_t e = 0, i = 0, u = 0;
  do {
    batch.Clear();
    batch.set_dim(3);
    batch.set_frame(frame);
    uint32_t items = 0;
    for (; e < c.erases.size() && items < max_items; ++e, ++items) batch.add_erases(c.erases[e]);
    for (; i < c.inserts.size() && items < max_items; ++i, ++items) {
      Add(batch.mutable_inserts(), c.inserts[i], true);
    }
    for (; u < c.updates.size() && items < max_items; ++u, ++items) {
      Add(batch.mutable_updates(), c.updates[u], false);
    }
    batch.set_end_of_frame(e == c.erases.size() && i == c.inserts.size() && u == c.updates.size());
    if (bp::Status s = pub.Publish(&batch); !s.ok()) return s;
  } while (!batch.end_of_frame());
  *out_sent_ns = batch.sent_time_ns();
  return bp::Status::Ok();
}

int Run(const Options& o) {
  bp::client::ConnectionOptions connection_options;
  connection_options.domain = o.domain;
  connection_options.partition = o.partition;
  if (!o.cyclone_config.empty()) {
    if (bp::Status s = bp::client::ReadTextFile(o.cyclone_config, &connection_options.cyclone_xml);
        !s.ok()) {
      std::fprintf(stderr, "bullet_world: --cyclone-config: %s\n", s.ToString().c_str());
      return 2;
    }
  }
  std::unique_ptr<bp::client::Connection> connection;
  if (bp::Status s = bp::client::Connection::Open(connection_options, &connection); !s.ok()) {
    std::fprintf(stderr, "bullet_world: cannot join DDS domain %u: %s\n", o.domain,
                 s.ToString().c_str());
    return 2;
  }
  std::unique_ptr<bp::client::UpdatePublisher> pub;
  if (bp::Status s = bp::client::UpdatePublisher::Create(*connection, o.producer,
                                                         std::chrono::seconds(5), &pub);
      !s.ok()) {
    std::fprintf(stderr, "bullet_world: %s\n", s.ToString().c_str());
    return 2;
  }
  std::unique_ptr<bp::examples::EventChecker> checker;
  if (o.check) {
    if (bp::Status s = bp::examples::EventChecker::Start(*connection, o.producer, &checker);
        !s.ok()) {
      std::fprintf(stderr, "bullet_world: events: %s\n", s.ToString().c_str());
      return 2;
    }
  }
  const auto wait = std::chrono::milliseconds(static_cast<int64_t>(o.wait_s * 1000));
  bp::Status ready = pub->WaitForDaemon(wait);
  if (ready.ok() && o.readers > 1) ready = pub->WaitForReaders(o.readers, wait);
  if (ready.ok() && checker) ready = checker->WaitForDaemon(wait);
  if (!ready.ok()) {
    std::fprintf(stderr, "bullet_world: no daemon on domain %u partition '%s' within %.0f s (%s)\n",
                 o.domain, o.partition.c_str(), o.wait_s, ready.ToString().c_str());
    return 2;
  }
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> csv(nullptr, std::fclose);
  if (!o.csv.empty()) {
    csv.reset(std::fopen(o.csv.c_str(), "w"));
    if (!csv) {
      std::fprintf(stderr, "bullet_world: --csv: cannot create '%s'\n", o.csv.c_str());
      return 2;
    }
    std::fputs(
        "step,bodies,awake,inserts,updates,erases,pairs,collides,uncollides,bullet_step_ms,"
        "bullet_broadphase_ms,pairs_ms,publish_ms,latency_ms,missing,unexpected\n",
        csv.get());
  }

  bp::examples::BulletWorld world(o.world);
  if (!o.quiet) {
    std::fprintf(stderr,
                 "bullet_world: %u bodies poured over %u steps into a %.0f m world, then %u "
                 "spawned per step, each removed %u steps later; %u steps at %.0f Hz; producer "
                 "%u\n",
                 o.world.bodies, o.world.fill_steps, world.side(), o.world.stream, o.world.lifetime,
                 o.steps, o.rate_hz, o.producer);
  }
  std::map<uint64_t, StepRow> rows;  // steps whose events are not compared yet
  std::vector<double> latency, step_ms, broadphase_ms, moved, events;
  uint64_t checked = 0, differing = 0, missing = 0, unexpected = 0, foreign = 0, received = 0;
  uint64_t lost = 0;  // frames whose events never arrived while later ones did
  auto on_check = [&](const FrameCheck& c) {
    if (!c.arrived) {
      ++lost;
      std::fprintf(stderr, "bullet_world: step %llu: %s\n",
                   static_cast<unsigned long long>(c.frame), c.first_difference.c_str());
      rows.erase(c.frame);
      return;
    }
    ++checked;
    received += c.received;
    missing += c.missing;
    unexpected += c.unexpected;
    foreign += c.foreign;
    latency.push_back(c.latency_ms);
    if (!c.first_difference.empty()) {
      ++differing;
      std::fprintf(stderr,
                   "bullet_world: DIFFERENCE at step %llu: %s (%llu missing, %llu unexpected)\n",
                   static_cast<unsigned long long>(c.frame), c.first_difference.c_str(),
                   static_cast<unsigned long long>(c.missing),
                   static_cast<unsigned long long>(c.unexpected));
    }
    auto it = rows.find(c.frame);
    if (it == rows.end()) return;
    const StepRow& r = it->second;
    if (csv) {
      std::fprintf(
          csv.get(), "%llu,%zu,%zu,%zu,%zu,%zu,%zu,%zu,%zu,%.4f,%.4f,%.4f,%.4f,%.4f,%llu,%llu\n",
          static_cast<unsigned long long>(c.frame), r.bodies, r.awake, r.inserts, r.updates,
          r.erases, r.pairs, r.collides, r.uncollides, r.step_ms, r.broadphase_ms, r.pairs_ms,
          r.publish_ms, c.latency_ms, static_cast<unsigned long long>(c.missing),
          static_cast<unsigned long long>(c.unexpected));
    }
    rows.erase(it);
  };

  bp::examples::WorldChanges changes;
  std::vector<uint64_t> pairs, last_pairs, collide, uncollide;
  const auto start = Clock::now();
  auto next = start;
  auto report_at = start + std::chrono::seconds(1);
  const auto period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(o.rate_hz > 0 ? 1.0 / o.rate_hz : 0.0));
  uint64_t frame = 0, late = 0;
  bool failed = false;
  for (uint32_t step = 1; step <= o.steps + 1 && !failed; ++step) {
    // The last frame erases everything (unless --keep), and is checked like the others.
    const bool last = step == o.steps + 1 || stop_requested.load();
    if (last && o.keep) break;
    StepRow row;
    if (last) {
      world.Clear();
    } else {
      const bp::examples::StepStats s = world.Step();
      row.step_ms = s.step_ms;
      row.broadphase_ms = s.broadphase_ms;
    }
    world.TakeChanges(&changes);
    auto t = Clock::now();
    world.ExactPairs(&pairs);
    collide.clear();
    uncollide.clear();
    std::set_difference(pairs.begin(), pairs.end(), last_pairs.begin(), last_pairs.end(),
                        std::back_inserter(collide));
    std::set_difference(last_pairs.begin(), last_pairs.end(), pairs.begin(), pairs.end(),
                        std::back_inserter(uncollide));
    row.pairs_ms = MsSince(t);
    row.bodies = world.bodies();
    row.awake = world.awake();
    row.inserts = changes.inserts.size();
    row.updates = changes.updates.size();
    row.erases = changes.erases.size();
    row.pairs = pairs.size();
    row.collides = collide.size();
    row.uncollides = uncollide.size();
    step_ms.push_back(row.step_ms);
    broadphase_ms.push_back(row.broadphase_ms);
    moved.push_back(static_cast<double>(row.updates));
    events.push_back(static_cast<double>(row.collides + row.uncollides));
    t = Clock::now();
    uint64_t sent_ns = 0;
    if (bp::Status s = PublishFrame(*pub, changes, ++frame, o.max_batch_items, &sent_ns); !s.ok()) {
      std::fprintf(stderr, "bullet_world: step %u: %s\n", step, s.ToString().c_str());
      failed = true;
      break;
    }
    row.publish_ms = MsSince(t);
    if (checker) {
      rows[frame] = row;
      checker->Expect(frame, sent_ns, uncollide, collide);
      checker->Collect(on_check);
    }
    last_pairs.swap(pairs);
    if (last) break;
    const auto now = Clock::now();
    if (!o.quiet && now >= report_at) {
      std::fprintf(stderr,
                   "bullet_world: step %u/%u, %zu bodies (%zu awake), %zu moved, %zu events, "
                   "%llu checked, %llu differing, %zu awaiting events\n",
                   step, o.steps, row.bodies, row.awake, row.updates, row.collides + row.uncollides,
                   static_cast<unsigned long long>(checked),
                   static_cast<unsigned long long>(differing),
                   checker ? checker->pending() : size_t{0});
      report_at = now + std::chrono::seconds(1);
    }
    next += period;
    if (next > Clock::now()) {
      std::this_thread::sleep_until(next);
    } else if (period.count() > 0) {
      ++late;  // the step took longer than the period: the next one starts at once
      next = Clock::now();
    }
  }
  // The events of the last frames.
  const auto drain_until = Clock::now() + wait;
  while (checker && checker->pending() > 0 && Clock::now() < drain_until) {
    checker->Collect(on_check);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const size_t pending = checker ? checker->pending() : 0;
  if (pending > 0) {
    std::fprintf(stderr, "bullet_world: the events of %zu frames did not arrive within %.0f s%s\n",
                 pending, o.wait_s, checker->gaps() > 0 ? " (envelopes were lost: a gap)" : "");
  }
  const size_t never = pending + lost;
  if (checker && !checker->listen_status().ok()) {
    std::fprintf(stderr, "bullet_world: the event listener stopped: %s\n",
                 checker->listen_status().ToString().c_str());
    failed = true;
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  const uint64_t gaps = checker ? checker->gaps() : 0;
  const bool exact = checker && !failed && never == 0 && differing == 0 && gaps == 0;
  std::string verdict = !checker ? "not checked" : exact ? "all equal" : "";
  if (checker && !exact) {
    verdict = fmt::format("{} differing, {} not received", differing, never);
    if (gaps > 0) verdict += fmt::format(", {} envelopes lost", gaps);
    if (failed) verdict += ", stopped early (see above)";
  }
  std::printf(
      "bullet_world: %llu frames in %.1f s (%llu late), %llu compared with Bullet's pairs: %s; "
      "%llu events received; moved bodies per step p50 %.0f; latency p50 %.2f ms p99 %.2f ms; "
      "Bullet step p50 %.2f ms, its broadphase p50 %.2f ms\n",
      static_cast<unsigned long long>(frame), seconds, static_cast<unsigned long long>(late),
      static_cast<unsigned long long>(checked), verdict.c_str(),
      static_cast<unsigned long long>(received), Quantile(moved, 0.5), Quantile(latency, 0.5),
      Quantile(latency, 0.99), Quantile(step_ms, 0.5), Quantile(broadphase_ms, 0.5));
  if (o.json) {
    std::printf(
        "{\"bodies\": %u, \"steps\": %u, \"frames\": %llu, \"checked\": %llu, \"differing\": "
        "%llu, \"missing_frames\": %zu, \"missing_events\": %llu, \"unexpected_events\": %llu, "
        "\"foreign_events\": %llu, \"gaps\": %llu, \"events\": %llu, \"moved_p50\": %.1f, "
        "\"events_p50\": %.1f, \"latency_ms_p50\": %.3f, \"latency_ms_p99\": %.3f, "
        "\"bullet_step_ms_p50\": %.3f, \"bullet_broadphase_ms_p50\": %.3f, \"late\": %llu, "
        "\"seconds\": %.2f}\n",
        o.world.bodies, o.steps, static_cast<unsigned long long>(frame),
        static_cast<unsigned long long>(checked), static_cast<unsigned long long>(differing), never,
        static_cast<unsigned long long>(missing), static_cast<unsigned long long>(unexpected),
        static_cast<unsigned long long>(foreign), static_cast<unsigned long long>(gaps),
        static_cast<unsigned long long>(received), Quantile(moved, 0.5), Quantile(events, 0.5),
        Quantile(latency, 0.5), Quantile(latency, 0.99), Quantile(step_ms, 0.5),
        Quantile(broadphase_ms, 0.5), static_cast<unsigned long long>(late), seconds);
  }
  (void)pub->Flush(std::chrono::seconds(5));
  if (failed) return 1;
  return !checker || exact ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{"A Bullet rigid-body world publishing to broadphased, checked against Bullet"};
  app.add_option("--bodies", o.world.bodies, "dynamic bodies in the world")
      ->check(CLI::Range(1u, 1000000u));
  app.add_option("--steps", o.steps, "steps of 1/60 s")->check(CLI::Range(1u, 100000000u));
  app.add_option("--fill-steps", o.world.fill_steps, "steps over which the bodies are poured in")
      ->check(CLI::Range(1u, 100000u));
  app.add_option("--stream", o.world.stream,
                 "bodies spawned from the spouts per step once the pour is done")
      ->check(CLI::Range(0u, 100000u));
  app.add_option("--lifetime", o.world.lifetime, "steps a streamed body lives before removal")
      ->check(CLI::Range(1u, 100000000u));
  app.add_option("--seed", o.world.seed, "seeds sizes, shapes and spawn order");
  app.add_option("--solver-iterations", o.world.solver_iterations, "Bullet's solver iterations")
      ->check(CLI::Range(1, 1000));
  app.add_option("--rate", o.rate_hz, "steps per second of wall time (0: as fast as it can)")
      ->check(CLI::Range(0.0, 10000.0));
  app.add_option("--domain", o.domain, "DDS domain of the daemon")->check(CLI::Range(0u, 232u));
  app.add_option("--partition", o.partition, "DDS partition of the daemon");
  app.add_option("--cyclone-config", o.cyclone_config,
                 "Cyclone DDS XML file (as the daemon's dds.cyclone_config)")
      ->check(CLI::ExistingFile);
  app.add_option("--producer", o.producer, "producer id")->check(CLI::Range(1u, 65535u));
  app.add_option("--max-batch-items", o.max_batch_items, "most items per update batch")
      ->check(CLI::Range(1u, 1u << 24));
  app.add_option("--readers", o.readers,
                 "update readers to wait for before the first step (2: the daemon and a recorder)")
      ->check(CLI::Range(1u, 1000u));
  app.add_option("--wait", o.wait_s, "seconds to wait for the daemon, and for the last events")
      ->check(CLI::Range(0.1, 3600.0));
  app.add_flag("!--no-check", o.check, "publish only: do not compare the events");
  app.add_flag("--keep", o.keep, "leave the objects in the daemon at the end");
  app.add_option("--csv", o.csv, "one line per compared step");
  app.add_flag("--json", o.json, "the summary also as one JSON line on stdout");
  app.add_flag("--quiet", o.quiet, "no progress line each second");
  CLI11_PARSE(app, argc, argv);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  return Run(o);
}
