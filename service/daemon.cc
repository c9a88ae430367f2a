#include "daemon.h"

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstddef>
#include <cstring>
#include <random>

#include "percentile.h"
#include <spdlog/spdlog.h>
#include <unistd.h>

#include "bp/client/update_publisher.h"

namespace bp::service {
namespace {

using Clock = std::chrono::steady_clock;
constexpr size_t kTakeBatch = 64;
// Rejections logged one by one per batch; the rest are summarised in one line.
constexpr size_t kRejectionsLogged = 10;

std::string FormatSeconds(double s) { return fmt::format("{:g} s", s); }

std::string HostName() {
  char name[256] = {};
  if (gethostname(name, sizeof(name) - 1) != 0) return "unknown";
  return name;
}

}  // namespace

Status Daemon::Create(const Config& config, std::unique_ptr<Daemon>* out) {
  std::unique_ptr<Daemon> d(new Daemon());
  d->config_ = config;
  d->daemon_name_ = HostName() + ":" + std::to_string(getpid());
  if (Status s = MakeEngineHost(config.engine, config.limits.max_objects, &d->host_); !s.ok()) {
    return s;
  }
  client::ConnectionOptions options;
  options.domain = config.dds.domain;
  options.partition = config.dds.partition;
  options.topics = {config.dds.topics.updates, config.dds.topics.events, config.dds.topics.status,
                    config.dds.topics.requests};
  if (!config.dds.cyclone_config.empty()) {
    if (Status s = client::ReadTextFile(config.dds.cyclone_config, &options.cyclone_xml); !s.ok()) {
      return Status(s.code(), "dds.cyclone_config: " + s.message());
    }
  }
  if (Status s = client::Connection::Open(options, &d->connection_); !s.ok()) return s;
  const auto timeout = std::chrono::milliseconds(config.dds.write_timeout_ms);
  dds::Qos updates_qos;
  client::qos::UpdatesReader(updates_qos.get(), config.dds.update_queue);
  dds::Qos events_qos;
  client::qos::EventsWriter(events_qos.get(), config.dds.event_history, timeout);
  dds::Qos status_qos;
  client::qos::StatusWriter(status_qos.get(), timeout);
  dds::Qos requests_qos;
  client::qos::RequestsReader(requests_qos.get());
  auto& participant = d->connection_->participant();
  // The waitset first: the liveliness listener wakes it as soon as the reader exists.
  if (Status s = dds::WaitSet::Create(participant, &d->waitset_); !s.ok()) return s;
  d->liveliness_ = std::make_unique<dds::WriterLiveliness>();
  d->liveliness_->SetOnChange([daemon = d.get()] { daemon->waitset_.Wake(); });
  if (Status s = d->connection_->CreateReader(client::TopicId::kUpdates, updates_qos, &d->updates_,
                                              d->liveliness_.get());
      !s.ok()) {
    return s;
  }
  if (Status s = d->connection_->CreateWriter(client::TopicId::kEvents, events_qos, &d->events_);
      !s.ok()) {
    return s;
  }
  if (Status s = d->connection_->CreateWriter(client::TopicId::kStatus, status_qos, &d->status_);
      !s.ok()) {
    return s;
  }
  if (Status s =
          d->connection_->CreateReader(client::TopicId::kRequests, requests_qos, &d->requests_);
      !s.ok()) {
    return s;
  }
  if (Status s = d->waitset_.Attach(d->updates_); !s.ok()) return s;
  if (Status s = d->waitset_.Attach(d->requests_); !s.ok()) return s;
  if (const std::string& path = config.logging.frame_log; !path.empty()) {
    d->frame_log_.reset(std::fopen(path.c_str(), "w"));
    if (!d->frame_log_) {
      return Status(StatusCode::kUnavailable,
                    "logging.frame_log: cannot open '" + path + "': " + std::strerror(errno));
    }
    std::fputs(
        "frame,wall_ns,source_producer,source_frame,source_sent_ns,batches,ingest_ms,query_ms,"
        "publish_ms,prepare_ms,core_ms,route_ms,cells_ms,fold_ms,events_ms,inserts,updates,"
        "erases,collides,uncollides,objects,overlaps,cells_queried\n",
        d->frame_log_.get());
  }
  std::random_device random;
  while (d->epoch_ == 0) d->epoch_ = uint64_t{random()} << 32 | random();
  *out = std::move(d);
  return Status::Ok();
}

Daemon::~Daemon() {
  // The reader (and so the listener) outlives the waitset among the members: stop the wakes.
  if (liveliness_) liveliness_->SetOnChange(nullptr);
}

void Daemon::RequestStop() {
  stop_.store(true);
  waitset_.Wake();
}

Status Daemon::Run() {
  const size_t engine_threads = host_->GetStats().threads;  // 1 for the single-threaded engines
  spdlog::info(
      "broadphased {}: engine {} ({}-D, {}, {} thread{}), DDS domain {} partition '{}', topics {} "
      "/ {} / {} / {}, frames on {}, producer lease {} s, epoch {:016x}",
      daemon_name_, host_->Name(), host_->Dimension(),
      CoordinateTypeName(config_.engine.coordinate), engine_threads, engine_threads == 1 ? "" : "s",
      config_.dds.domain, config_.dds.partition, config_.dds.topics.updates,
      config_.dds.topics.events, config_.dds.topics.status, config_.dds.topics.requests,
      FrameBoundaryName(config_.frames.boundary), config_.producers.lease_s, epoch_);
  if (config_.frames.keep_cpus_awake_ms > 0) {
    if (Status s = KeepAwake::Start(std::chrono::milliseconds(config_.frames.keep_cpus_awake_ms),
                                    &keep_awake_);
        s.ok()) {
      cpus_kept_awake_.store(keep_awake_->threads());
      spdlog::info(
          "keeping {} CPU{} awake for {} ms after each update batch "
          "(frames.keep_cpus_awake_ms)",
          keep_awake_->threads(), keep_awake_->threads() == 1 ? "" : "s",
          config_.frames.keep_cpus_awake_ms);
    } else {
      spdlog::warn("frames.keep_cpus_awake_ms: CPUs are not kept awake: {}", s.ToString());
    }
  }
  PublishStatus(wire::SERVING, false);
  serving_.store(true);
  interval_start_ = Clock::now();
  const bool tick_mode = config_.frames.boundary == FrameBoundary::kTick;
  const auto tick = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double, std::milli>(config_.frames.tick_ms));
  const bool summaries = config_.logging.summary_interval_s > 0;
  summaries_ = summaries;
  const auto summary_every = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(summaries ? config_.logging.summary_interval_s : 3600.0));
  const size_t drain_rounds = static_cast<size_t>(config_.dds.update_queue) / kTakeBatch + 1;
  auto next_tick = Clock::now() + tick;
  auto next_summary = Clock::now() + summary_every;

  auto next_expiry = Clock::time_point::max();
  auto next_snapshot = Clock::time_point::max();
  auto next_resync = Clock::time_point::max();
  while (!stop_.load()) {
    auto wake = std::min({next_summary, next_expiry, next_snapshot, next_resync});
    if (tick_mode) wake = std::min(wake, next_tick);
    const auto now = Clock::now();
    int triggered = 0;
    if (wake > now) {
      if (Status s = waitset_.Wait(wake - now, &triggered); !s.ok()) {
        spdlog::error("{}", s.ToString());
        return s;
      }
    }
    if (stop_.load()) break;
    // At most one queue's worth per turn: under sustained load the queue never empties, and
    // ticks, summaries and a stop request must still get their turn.
    Drain(drain_rounds, /*until_stop=*/true);
    next_snapshot = ServeRequests();
    next_expiry = CheckProducers();
    next_resync = CheckResyncs();
    if (tick_mode && Clock::now() >= next_tick) {
      RunFrame(0, 0, 0);
      next_tick += tick;
      // A frame longer than the tick: skip the missed ticks instead of bursting to catch up.
      if (next_tick < Clock::now()) next_tick = Clock::now() + tick;
    }
    if (summaries && Clock::now() >= next_summary) {
      Summary();
      next_summary += summary_every;
      if (next_summary < Clock::now()) next_summary = Clock::now() + summary_every;
    }
  }

  // The spinners stop first: joining them can take a while on a loaded machine, where
  // SCHED_IDLE threads get the least CPU, and the last frame needs no CPU kept awake.
  keep_awake_.reset();
  cpus_kept_awake_.store(0);
  // Stop: take what has already arrived (one bounded round, so a producer that keeps sending
  // cannot hold the daemon up), finish the frame, publish its events, and let them be acked.
  Drain(drain_rounds, /*until_stop=*/false);
  if (frame_dirty_) {
    spdlog::info("stopping: finishing frame {}", frames_.load() + 1);
    RunFrame(0, 0, 0);
  } else {
    spdlog::info("stopping: no open frame");
  }
  if (Status s = events_.WaitForAcks(std::chrono::seconds(2)); !s.ok()) {
    spdlog::warn("not every subscriber acknowledged the last events: {}", s.ToString());
  }
  if (summaries) Summary();
  if (frame_log_ && std::fflush(frame_log_.get()) != 0) {
    spdlog::error("logging.frame_log: cannot write ({})", std::strerror(errno));
  }
  PublishStatus(wire::STOPPING, false);
  (void)status_.WaitForAcks(std::chrono::milliseconds(500));
  spdlog::info("stopped after {} frames, {} batches, {} rejected items", frames_.load(),
               batches_total_.load(), rejected_total_.load());
  serving_.store(false);
  return Status::Ok();
}

void Daemon::Drain(size_t max_rounds, bool until_stop) {
  for (size_t round = 0; round < max_rounds && !(until_stop && stop_.load()); ++round) {
    size_t taken = 0;
    Status s = updates_.Take(
        kTakeBatch, [this](const dds::Received& r) { ProcessPayload(r.payload, *r.info); }, &taken);
    if (!s.ok()) {
      spdlog::error("reading updates: {}", s.ToString());
      return;
    }
    if (taken == 0) return;
  }
}

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

namespace {
constexpr std::chrono::seconds kFirstReask{1};
constexpr std::chrono::seconds kLastReask{30};
}  // namespace

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

void Daemon::ProcessPayload(std::span<const uint8_t> payload, const dds_sample_info_t& info) {
  const auto start = Clock::now();
  if (keep_awake_) keep_awake_->Touch();
  ++batches_total_;
  ++interval_batches_;
  ++frame_batches_;
  auto batch_reject = [&](uint32_t producer, wire::RejectReason reason, std::string why) {
    ReportRejection(producer, nullptr, Reject{wire::OP_BATCH, 0, 0, reason, std::move(why)});
    FlushRejections();
  };
  Reject refused;
  if (!AdmitBatch(payload, config_.limits, &batch_, &refused)) {
    // A payload too large to parse, or malformed, names no producer: it is reported as the one
    // its writer holds (0 if the writer holds none, or several as a replay does). Its batch_seq
    // is unknown, so the writer's next batch shows the gap and the producer is asked to restate.
    const uint32_t producer = batch_.producer();
    if (producer == 0 && (refused.reason == wire::OVERSIZE || refused.reason == wire::MALFORMED)) {
      batch_reject(WriterProducer(info.publication_handle), refused.reason,
                   std::move(refused.message));
      return;
    }
    // A parsed batch refused, of the writer holding the id, is not a gap in its sequence.
    // A restate batch refused breaks its run (it would erase the objects the batch named).
    const auto claim = claims_.find(producer);
    bool broke = false;
    if (claim != claims_.end() && claim->second.writer == info.publication_handle) {
      if (batch_.batch_seq() != 0) last_batch_seq_[producer] = batch_.batch_seq();
      auto run = runs_.find(producer);
      if (batch_.restate() && batch_.restate_run() != 0 &&
          (run == runs_.end() || run->second.first != batch_.restate_run())) {
        run = runs_.insert_or_assign(producer, RestateRun{batch_.restate_run(), false, {}}).first;
      }
      if (run != runs_.end() && !run->second.broken) {
        run->second.broken = true;
        run->second.ids = {};
        broke = true;
      }
    }
    batch_reject(producer, refused.reason, std::move(refused.message));
    if (broke) RequestResync({producer}, "a batch of its restate was refused");
    return;
  }
  const uint32_t producer = batch_.producer();
  if (!ClaimProducer(producer, info.publication_handle)) {
    batch_reject(producer, wire::PRODUCER_CONFLICT,
                 "producer id " + std::to_string(producer) +
                     " is in use by another live writer; give each producer its own id");
    return;
  }
  if (!TrackSequence(producer)) {
    RequestResync({producer}, "batches were lost (a batch_seq gap, or a restate run cut short)");
  }

  ApplyCounts counts;
  host_->Apply(
      batch_, [&](Reject&& r) { ReportRejection(producer, &batch_, std::move(r)); }, &counts);
  FlushRejections();
  if (batch_.restate() && batch_.restate_run() != 0) ContinueRestate(producer);
  interval_updates_ += counts.inserts + counts.updates + counts.erases;
  frame_dirty_ = true;
  ingest_work_ += Clock::now() - start;
  if (config_.frames.boundary == FrameBoundary::kEndOfFrame && batch_.end_of_frame()) {
    RunFrame(producer, batch_.frame(), batch_.sent_time_ns());
  }
}

uint32_t Daemon::WriterProducer(dds_instance_handle_t writer) const {
  uint32_t found = 0;
  for (const auto& [producer, claim] : claims_) {
    if (claim.writer != writer) continue;
    if (found != 0) return 0;
    found = producer;
  }
  return found;
}

void Daemon::ReportRejection(uint32_t producer, const wire::UpdateBatch* batch, Reject&& r) {
  ++rejected_total_;
  ++interval_rejected_;
  const size_t seen = pending_rejections_.size() + pending_not_listed_;
  if (seen < kRejectionsLogged) {
    spdlog::warn("rejected from producer {}{}: {}", producer,
                 batch ? " frame " + std::to_string(batch->frame()) : std::string(), r.message);
  }
  if (pending_rejections_.size() >= config_.limits.max_rejections_reported) {
    ++pending_not_listed_;
    return;
  }
  wire::Rejection& out = pending_rejections_.emplace_back();
  out.set_producer(producer);
  if (batch) {
    out.set_frame(batch->frame());
    out.set_batch_seq(batch->batch_seq());
  }
  out.set_op(r.op);
  out.set_index(r.index);
  out.set_id(r.id);
  out.set_reason(r.reason);
  out.set_message(std::move(r.message));
}

void Daemon::FlushRejections() {
  if (pending_rejections_.empty() && pending_not_listed_ == 0) return;
  const uint64_t total = pending_rejections_.size() + pending_not_listed_;
  if (total > kRejectionsLogged) {
    spdlog::warn("... {} rejections in this batch in all ({} more not logged)", total,
                 total - kRejectionsLogged);
  }
  PublishStatus(wire::SERVING, false);
  pending_rejections_.clear();
  pending_not_listed_ = 0;
}

void Daemon::RunFrame(uint32_t source_producer, uint64_t source_frame, uint64_t source_sent_ns) {
  const auto start = Clock::now();
  const int64_t start_wall_ns = frame_log_ ? static_cast<int64_t>(client::WallClockNs()) : 0;
  host_->Query(&uncollide_, &collide_);
  const auto queried = Clock::now();
  const uint64_t frame = frames_.load() + 1;
  // Pairs of the frame: uncollides then collides, split into parts of at most max pairs.
  const size_t pairs = (uncollide_.size() + collide_.size()) / 2;
  const size_t per_part = static_cast<size_t>(config_.limits.max_pairs_per_event_batch);
  const size_t parts = std::max<size_t>(1, (pairs + per_part - 1) / per_part);
  size_t next = 0;  // pair index over the concatenation
  for (size_t part = 0; part < parts; ++part) {
    event_msg_.Clear();
    event_msg_.set_version(wire::SCHEMA_VERSION_1);
    event_msg_.set_frame(frame);
    event_msg_.set_sequence(++event_seq_);
    event_msg_.set_part(static_cast<uint32_t>(part));
    event_msg_.set_last_part(part + 1 == parts);
    const size_t end = std::min(pairs, next + per_part);
    const size_t n_unc = uncollide_.size() / 2;
    // The part's pairs [next, end): a run of uncollides, then a run of collides, copied whole.
    if (next < n_unc) {
      const size_t to = std::min(end, n_unc);
      event_msg_.mutable_uncollide()->Add(
          uncollide_.begin() + static_cast<std::ptrdiff_t>(2 * next),
          uncollide_.begin() + static_cast<std::ptrdiff_t>(2 * to));
    }
    if (end > n_unc) {
      const size_t from = std::max(next, n_unc) - n_unc;
      const size_t to = end - n_unc;
      event_msg_.mutable_collide()->Add(collide_.begin() + static_cast<std::ptrdiff_t>(2 * from),
                                        collide_.begin() + static_cast<std::ptrdiff_t>(2 * to));
    }
    next = end;
    event_msg_.set_source_producer(source_producer);
    event_msg_.set_source_frame(source_frame);
    event_msg_.set_source_sent_time_ns(source_sent_ns);
    event_msg_.set_objects(host_->Objects());
    event_msg_.set_overlaps(host_->Overlaps());
    WriteEventPart();
  }
  frames_.store(frame);
  frame_dirty_ = false;
  ++interval_frames_;
  interval_events_ += pairs;
  if (summaries_ || frame_log_) {
    using Ms = std::chrono::duration<double, std::milli>;
    const double ingest = Ms(ingest_work_).count(), query = Ms(queried - start).count(),
                 publish = Ms(Clock::now() - queried).count();
    // Kept for the summary's percentiles only, and cleared by it (no summary, no growth).
    if (summaries_) {
      ingest_ms_.push_back(ingest);
      query_ms_.push_back(query);
      publish_ms_.push_back(publish);
      frame_ms_.push_back(ingest + query + publish);
    }
    if (frame_log_) {
      LogFrame(frame, start_wall_ns, source_producer, source_frame, source_sent_ns, ingest, query,
               publish);
    }
  }
  ingest_work_ = std::chrono::nanoseconds(0);
  frame_batches_ = 0;
}

void Daemon::LogFrame(uint64_t frame, int64_t wall_ns, uint32_t source_producer,
                      uint64_t source_frame, uint64_t source_sent_ns, double ingest, double query,
                      double publish) {
  const Stats st = host_->GetStats();
  std::FILE* f = frame_log_.get();
  const int written = std::fprintf(
      f,
      "%" PRIu64 ",%" PRId64 ",%" PRIu32 ",%" PRIu64 ",%" PRIu64 ",%" PRIu64
      ",%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%zu,%zu,%zu,%zu,%zu,%zu,%zu,%zu\n",
      frame, wall_ns, source_producer, source_frame, source_sent_ns, frame_batches_, ingest, query,
      publish, st.prepare_ms, st.core_ms, st.route_ms, st.cells_ms, st.fold_ms, st.events_ms,
      st.inserts, st.updates, st.erases, st.collides, st.uncollides, st.objects, st.overlaps,
      st.cells_queried);
  // Buffered; flushed about once a second (and when the daemon stops), so that a reader follows
  // the file without a write per frame.
  const auto now = Clock::now();
  const bool flush = now - frame_log_flushed_ >= std::chrono::seconds(1);
  if (written < 0 || (flush && std::fflush(f) != 0)) {
    spdlog::error("logging.frame_log: cannot write ({}); no more frames are logged",
                  std::strerror(errno));
    frame_log_.reset();
    return;
  }
  if (flush) frame_log_flushed_ = now;
}

void Daemon::WriteEventPart() {
  event_msg_.set_epoch(epoch_);
  event_msg_.set_published_time_ns(client::WallClockNs());
  buffer_.clear();
  Status s = event_msg_.SerializeToString(&buffer_)
                 ? events_.Write(event_msg_.sequence(), buffer_)
                 : Status(StatusCode::kResourceExhausted,
                          "the part does not serialise (over 2 GiB?); lower "
                          "limits.max_pairs_per_event_batch");
  if (!s.ok()) {
    ++event_write_failures_;
    spdlog::error("frame {} {}part {}: not delivered ({}); subscribers see a gap at sequence {}",
                  event_msg_.frame(), event_msg_.snapshot() ? "snapshot " : "", event_msg_.part(),
                  s.ToString(), event_msg_.sequence());
  }
}

std::chrono::steady_clock::time_point Daemon::ServeRequests() {
  // One take per loop turn (bounded); requests beyond it wait for the next turn.
  size_t valid = 0;
  {
    size_t taken = 0;
    Status s = requests_.Take(
        kTakeBatch,
        [&](const dds::Received& r) {
          if (!request_.ParseFromArray(r.payload.data(), static_cast<int>(r.payload.size())) ||
              request_.version() != wire::SCHEMA_VERSION_1) {
            spdlog::warn("ignored a snapshot request that does not parse as version 1 ({} bytes)",
                         r.payload.size());
            return;
          }
          spdlog::debug("snapshot requested by {:016x} ({})", request_.requester(),
                        request_.reason());
          ++valid;
        },
        &taken);
    if (!s.ok()) spdlog::error("reading snapshot requests: {}", s.ToString());
  }
  if (valid > 0) snapshot_due_ = true;
  // One snapshot serves every request so far, at most one per limits.snapshot_interval_ms; a
  // stopping daemon publishes none.
  if (!snapshot_due_ || stop_.load()) return Clock::time_point::max();
  const auto interval = std::chrono::milliseconds(config_.limits.snapshot_interval_ms);
  const auto now = Clock::now();
  if (last_snapshot_ != Clock::time_point{} && now < last_snapshot_ + interval) {
    return last_snapshot_ + interval;
  }
  PublishSnapshot();
  snapshot_due_ = false;
  last_snapshot_ = now;
  return Clock::time_point::max();
}

void Daemon::PublishSnapshot() {
  host_->Snapshot(&snapshot_pairs_);
  snapshots_published_.fetch_add(1);  // before its parts: a reader that saw them sees the count
  const size_t pairs = snapshot_pairs_.size();
  const size_t per_part = static_cast<size_t>(config_.limits.max_pairs_per_event_batch);
  const size_t parts = std::max<size_t>(1, (pairs + per_part - 1) / per_part);
  for (size_t part = 0, next = 0; part < parts; ++part) {
    event_msg_.Clear();
    event_msg_.set_version(wire::SCHEMA_VERSION_1);
    event_msg_.set_frame(frames_.load());
    event_msg_.set_sequence(++event_seq_);
    event_msg_.set_part(static_cast<uint32_t>(part));
    event_msg_.set_last_part(part + 1 == parts);
    event_msg_.set_snapshot(true);
    for (const size_t end = std::min(pairs, next + per_part); next < end; ++next) {
      event_msg_.add_snapshot_pairs(snapshot_pairs_[next].first);
      event_msg_.add_snapshot_pairs(snapshot_pairs_[next].second);
    }
    event_msg_.set_objects(host_->Objects());
    event_msg_.set_overlaps(host_->Overlaps());
    WriteEventPart();
  }
  spdlog::info("snapshot of frame {}: {} pairs in {} part(s)", frames_.load(), pairs, parts);
}

void Daemon::PublishStatus(wire::Health health, bool with_interval) {
  status_msg_.Clear();
  status_msg_.set_version(wire::SCHEMA_VERSION_1);
  status_msg_.set_health(health);
  status_msg_.set_daemon(daemon_name_);
  status_msg_.set_engine(host_->Name());
  status_msg_.set_dim(static_cast<uint32_t>(host_->Dimension()));
  status_msg_.set_coordinate(std::string(CoordinateTypeName(config_.engine.coordinate)));
  status_msg_.set_time_ns(client::WallClockNs());
  status_msg_.set_frame(frames_.load());
  status_msg_.set_objects(host_->Objects());
  status_msg_.set_overlaps(host_->Overlaps());
  if (with_interval) *status_msg_.mutable_interval() = last_interval_;
  for (auto& r : pending_rejections_) *status_msg_.add_rejections() = r;
  status_msg_.set_rejections_not_listed(pending_not_listed_);
  status_msg_.set_rejected_total(rejected_total_.load());
  status_msg_.set_event_write_failures(event_write_failures_);
  status_msg_.set_producers(static_cast<uint32_t>(claims_.size()));
  status_msg_.set_epoch(epoch_);
  status_msg_.set_producers_expired(producers_expired_.load());
  for (uint32_t p : expired_now_) status_msg_.add_expired_producers(p);
  for (const auto& [p, resync] : resync_) {
    wire::ResyncRequest* request = status_msg_.add_resync();
    request->set_producer(p);
    const auto seen = last_batch_seq_.find(p);
    request->set_seen_batch_seq(seen == last_batch_seq_.end() ? 0 : seen->second);
    request->set_raised(resync.raised);
  }
  status_msg_.set_max_batch_items(config_.limits.max_batch_items);
  status_msg_.set_max_batch_bytes(config_.limits.max_batch_bytes);
  buffer_.clear();
  if (!status_msg_.SerializeToString(&buffer_)) {
    spdlog::warn("status report does not serialise");
    return;
  }
  if (Status s = status_.Write(++status_seq_, buffer_); !s.ok()) {
    spdlog::warn("status report not delivered: {}", s.ToString());
  }
}

void Daemon::Summary() {
  const auto now = Clock::now();
  const double seconds = std::chrono::duration<double>(now - interval_start_).count();
  wire::IntervalStats& st = last_interval_;
  st.Clear();
  st.set_seconds(seconds);
  st.set_frames(interval_frames_);
  st.set_batches(interval_batches_);
  st.set_updates(interval_updates_);
  st.set_events(interval_events_);
  st.set_rejected(interval_rejected_);
  st.set_frame_ms_p50(Percentile(frame_ms_, 0.50));
  st.set_frame_ms_p99(Percentile(frame_ms_, 0.99));
  st.set_frame_ms_max(frame_ms_.empty() ? 0.0
                                        : *std::max_element(frame_ms_.begin(), frame_ms_.end()));
  st.set_ingest_ms_p50(Percentile(ingest_ms_, 0.50));
  st.set_ingest_ms_p99(Percentile(ingest_ms_, 0.99));
  st.set_query_ms_p50(Percentile(query_ms_, 0.50));
  st.set_query_ms_p99(Percentile(query_ms_, 0.99));
  st.set_publish_ms_p50(Percentile(publish_ms_, 0.50));
  st.set_publish_ms_p99(Percentile(publish_ms_, 0.99));
  const double per_s = seconds > 0 ? 1.0 / seconds : 0.0;
  spdlog::info(
      "objects {} | {:.1f} frames/s | {:.0f} updates/s | {:.0f} events/s | frame p50 "
      "{:.3f} ms p99 {:.3f} ms (p50 ingest {:.3f}, query {:.3f}, publish {:.3f} ms) | rejected {}",
      host_->Objects(), static_cast<double>(interval_frames_) * per_s,
      static_cast<double>(interval_updates_) * per_s, static_cast<double>(interval_events_) * per_s,
      st.frame_ms_p50(), st.frame_ms_p99(), st.ingest_ms_p50(), st.query_ms_p50(),
      st.publish_ms_p50(), interval_rejected_);
  PublishStatus(wire::SERVING, true);
  interval_start_ = now;
  for (auto* v : {&frame_ms_, &ingest_ms_, &query_ms_, &publish_ms_}) v->clear();
  interval_frames_ = interval_batches_ = interval_updates_ = interval_events_ = interval_rejected_ =
      0;
}

}  // namespace bp::service
