// broadphased's producers over time (daemon.h): ids claimed per writer, liveliness leases and
// expiry, rediscovered writers, batch_seq gaps, and the resyncs (restates) the daemon asks for.
#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstddef>
#include <cstring>
#include <random>

#include "daemon.h"
#include <spdlog/spdlog.h>
#include <unistd.h>

#include "bp/transport/clock.h"

namespace bp::service {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::chrono::seconds kFirstReask{1};
constexpr std::chrono::seconds kLastReask{30};

std::string FormatSeconds(double s) { return fmt::format("{:g} s", s); }

}  // namespace

bool Daemon::ClaimProducer(uint32_t producer, dds_instance_handle_t writer) {
  auto it = claims_.find(producer);
  if (it == claims_.end()) {
    // A writer that is already not alive may still have batches queued: it claims the id, and
    // its lease (counted from when it stopped being alive) expires the claim again.
    claims_.emplace(producer, Claim{writer, updates_.MatchedWriterGuid(writer)});
    return true;
  }
  if (it->second.writer == writer) return true;
  // The same writer under a new handle: Cyclone dropped it after a stall longer than the
  // participant lease and discovered it again. It keeps its id and its objects.
  const dds::Guid guid = updates_.MatchedWriterGuid(writer);
  if (guid != dds::Guid{} && guid == it->second.guid) {
    // Its batch came before its liveliness change: the batch_seq check finds what was lost.
    spdlog::info("producer {}: its writer was rediscovered; it keeps its objects", producer);
    down_since_.erase(it->second.writer);
    it->second.writer = writer;
    return true;
  }
  // Another writer holds the id: it keeps it while it is alive (matched, liveliness not lost).
  (void)CheckProducers();  // liveliness changes that arrived with this batch
  it = claims_.find(producer);
  if (it == claims_.end()) {  // the lease just expired
    claims_.emplace(producer, Claim{writer, guid});
    return true;
  }
  const auto matched = updates_.MatchedWriterHandles();
  const bool matched_now =
      std::find(matched.begin(), matched.end(), it->second.writer) != matched.end();
  if (matched_now && !down_since_.contains(it->second.writer)) return false;
  // A new incarnation: what the old writer left is erased before the new one's batch applies.
  ExpireProducer(producer,
                 matched_now ? "its writer is not alive and a new writer takes over"
                             : "its writer left and a new writer takes over",
                 /*lease=*/false);
  claims_.emplace(producer, Claim{writer, guid});
  return true;
}

std::chrono::steady_clock::time_point Daemon::CheckProducers() {
  liveliness_->TakeChanges(&liveliness_changes_);
  const auto now = Clock::now();
  for (const auto& change : liveliness_changes_) {
    if (change.alive) {
      down_since_.erase(change.writer);
      FollowRediscoveredWriter(change.writer);
    } else {
      down_since_.try_emplace(change.writer, now);
    }
  }
  auto next = Clock::time_point::max();
  if (down_since_.empty()) return next;
  const bool leasing = config_.producers.lease_s > 0;
  const auto lease = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(config_.producers.lease_s));
  std::vector<uint32_t> expired;
  bool forget_gone = false;
  for (const auto& [writer, since] : down_since_) {
    const auto due = since + lease;
    bool holds = false;
    for (const auto& [producer, claim] : claims_) {  // a writer may hold several ids (replay)
      if (claim.writer != writer) continue;
      holds = true;
      if (leasing && now >= due) expired.push_back(producer);
    }
    if (holds && leasing && now < due) next = std::min(next, due);
    // An entry stays while its writer is matched, so that a late batch of an expired writer
    // claims its id only to see it expire again; one that left is forgotten.
    if (!holds && now >= due) forget_gone = true;
  }
  for (uint32_t producer : expired) {
    ExpireProducer(producer,
                   "its writer has not been alive for producers.lease_s = " +
                       FormatSeconds(config_.producers.lease_s),
                   /*lease=*/true);
  }
  if (forget_gone && now >= next_forget_) {  // at most once a second
    next_forget_ = now + std::chrono::seconds(1);
    const auto matched = updates_.MatchedWriterHandles();
    std::erase_if(down_since_, [&](const auto& entry) {
      return std::find(matched.begin(), matched.end(), entry.first) == matched.end() &&
             std::none_of(claims_.begin(), claims_.end(),
                          [&](const auto& c) { return c.second.writer == entry.first; });
    });
  }
  return next;
}

void Daemon::FollowRediscoveredWriter(dds_instance_handle_t writer) {
  dds::Guid guid{};
  std::vector<uint32_t> producers;
  for (auto& [producer, claim] : claims_) {
    if (claim.writer == writer) continue;  // known under this handle (a batch came first)
    if (guid == dds::Guid{}) {
      guid = updates_.MatchedWriterGuid(writer);
      if (guid == dds::Guid{}) return;  // gone again
    }
    if (claim.guid != guid) continue;
    down_since_.erase(claim.writer);
    claim.writer = writer;
    producers.push_back(producer);
  }
  if (producers.empty()) return;
  std::sort(producers.begin(), producers.end());
  spdlog::warn(
      "producer {}: its writer was dropped by DDS and discovered again; it keeps its objects",
      producers.front());
  RequestResync(producers, "its writer was discovered again: batches may have been lost");
}

void Daemon::RequestResync(const std::vector<uint32_t>& producers, const char* why) {
  const auto now = Clock::now();
  bool raised = false;
  for (uint32_t producer : producers) {
    auto [it, fresh] = resync_.try_emplace(producer);
    if (fresh) spdlog::warn("producer {}: {}; asking it to restate its objects", producer, why);
    // A new cause raises the request again (the producer may have answered an older one with a
    // restate that did not arrive whole), but not more than once a second.
    if (!fresh && now - it->second.last_raise < kFirstReask) continue;
    it->second = Resync{status_seq_ + 1, now, kFirstReask};
    raised = true;
  }
  if (raised) PublishStatus(wire::SERVING, false);
}

std::chrono::steady_clock::time_point Daemon::CheckResyncs() {
  auto next = Clock::time_point::max();
  if (resync_.empty()) return next;
  const auto now = Clock::now();
  bool raised = false;
  for (auto& [producer, request] : resync_) {
    const auto run = runs_.find(producer);
    if (run != runs_.end() && !run->second.broken) continue;  // a restate is arriving
    const auto due = request.last_raise + request.backoff;
    if (now < due) {
      next = std::min(next, due);
      continue;
    }
    spdlog::info("producer {}: no restate {:.0f} s after the request; asking again", producer,
                 std::chrono::duration<double>(request.backoff).count());
    request =
        Resync{status_seq_ + 1, now, std::min<Clock::duration>(request.backoff * 2, kLastReask)};
    next = std::min(next, now + request.backoff);
    raised = true;
  }
  if (raised) PublishStatus(wire::SERVING, false);
  return next;
}

bool Daemon::TrackSequence(uint32_t producer) {
  uint64_t& last_seq = last_batch_seq_[producer];
  const uint64_t seq = batch_.batch_seq();
  // A producer's first batch after batch_seq 1 shows that this daemon missed its earlier
  // batches (a restart), unless it starts a restate run.
  const bool gap = seq != 0 && seq != last_seq + 1;
  if (gap && last_seq != 0) {
    spdlog::warn("producer {}: batch_seq jumped from {} to {}", producer, last_seq, seq);
  }
  if (seq != 0) last_seq = seq;
  const auto run = runs_.find(producer);
  const uint64_t first = batch_.restate() ? batch_.restate_run() : 0;
  if (first == 0) {
    if (run == runs_.end()) return !gap;
    runs_.erase(run);  // a run cut short names too little to erase anything
    return false;
  }
  if (first == seq) {  // a run starts: what was lost before it, it covers
    runs_[producer] = RestateRun{seq, false, {}};
    return true;
  }
  if (run == runs_.end() || run->second.first != first) {  // its first batch was lost
    runs_[producer] = RestateRun{first, true, {}};
    return false;
  }
  if (gap && !run->second.broken) {
    run->second.broken = true;
    run->second.ids = {};
    return false;
  }
  return true;
}

void Daemon::ContinueRestate(uint32_t producer) {
  auto it = runs_.find(producer);
  if (it == runs_.end()) return;
  RestateRun& run = it->second;
  if (!run.broken) {
    for (uint64_t id : batch_.inserts().ids()) run.ids.push_back(id);
  }
  if (!batch_.end_of_frame()) return;
  if (run.broken) {
    runs_.erase(it);
    spdlog::warn("producer {}: its restate missed a batch and erased nothing", producer);
    // It has sent the whole run: a new cause, so that it restates again.
    RequestResync({producer}, "its restate missed a batch");
    return;
  }
  std::sort(run.ids.begin(), run.ids.end());
  const uint64_t erased = host_->EraseProducer(producer, &run.ids);
  spdlog::info("producer {}: restated {} objects, erased {} it no longer has", producer,
               run.ids.size(), erased);
  interval_updates_ += erased;
  runs_.erase(it);
  resync_.erase(producer);
}

void Daemon::ExpireProducer(uint32_t producer, const std::string& why, bool lease) {
  const uint64_t erased = host_->EraseProducer(producer, nullptr);
  claims_.erase(producer);
  last_batch_seq_.erase(producer);
  runs_.erase(producer);
  resync_.erase(producer);
  if (lease) producers_expired_.fetch_add(1);
  if (lease || erased > 0) {
    spdlog::warn("producer {}: {}; erased its {} objects", producer, why, erased);
  } else {
    spdlog::info("producer {}: {}", producer, why);
  }
  if (erased > 0) {
    frame_dirty_ = true;
    // A lease: the uncollides go out now, whatever the frame boundary. A take-over: the new
    // writer's batch follows and its frame carries them.
    if (lease) RunFrame(0, 0, 0);
  }
  if (lease) {
    // Operators see producers_expired change; a producer that is in fact alive (it hung
    // longer than the lease) sees its id and restates its objects.
    expired_now_.push_back(producer);
    PublishStatus(wire::SERVING, false);
    expired_now_.clear();
  }
}

}  // namespace bp::service
