// broadphased's loop (daemon.h): creation, the wait-and-take loop, and the intake of update
// batches (decode, admit, reject item by item). Producers over time are in
// daemon_producers.cc, frames and what goes out (events, snapshots, status) in daemon_output.cc.
#include "daemon.h"

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstddef>
#include <cstring>
#include <random>

#include <spdlog/spdlog.h>
#include <unistd.h>

#include "bp/transport/clock.h"

namespace bp::service {
namespace {

using Clock = std::chrono::steady_clock;
// Rejections logged one by one per batch; the rest are summarised in one line.
constexpr size_t kRejectionsLogged = 10;

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
  transport::ConnectionOptions options;
  options.domain = config.dds.domain;
  options.partition = config.dds.partition;
  options.topics = {config.dds.topics.updates,   config.dds.topics.events,
                    config.dds.topics.status,    config.dds.topics.requests,
                    config.dds.topics.interests, config.dds.topics.replies};
  if (!config.dds.cyclone_config.empty()) {
    if (Status s = transport::ReadTextFile(config.dds.cyclone_config, &options.cyclone_xml);
        !s.ok()) {
      return Status(s.code(), "dds.cyclone_config: " + s.message());
    }
  }
  if (Status s = transport::Connection::Open(options, &d->connection_); !s.ok()) return s;
  const auto timeout = std::chrono::milliseconds(config.dds.write_timeout_ms);
  dds::Qos updates_qos;
  transport::qos::UpdatesReader(updates_qos.get(), config.dds.update_queue);
  dds::Qos events_qos;
  transport::qos::EventsWriter(events_qos.get(), config.dds.event_history, timeout);
  dds::Qos status_qos;
  transport::qos::StatusWriter(status_qos.get(), timeout);
  dds::Qos requests_qos;
  transport::qos::RequestsReader(requests_qos.get());
  auto& participant = d->connection_->participant();
  // The waitset first: the liveliness listener wakes it as soon as the reader exists.
  if (Status s = dds::WaitSet::Create(participant, &d->waitset_); !s.ok()) return s;
  d->liveliness_ = std::make_unique<dds::WriterLiveliness>();
  d->liveliness_->SetOnChange([daemon = d.get()] { daemon->waitset_.Wake(); });
  if (Status s = d->connection_->CreateReader(transport::TopicId::kUpdates, updates_qos,
                                              &d->updates_, d->liveliness_.get());
      !s.ok()) {
    return s;
  }
  if (Status s = d->connection_->CreateWriter(transport::TopicId::kEvents, events_qos, &d->events_);
      !s.ok()) {
    return s;
  }
  if (Status s = d->connection_->CreateWriter(transport::TopicId::kStatus, status_qos, &d->status_);
      !s.ok()) {
    return s;
  }
  if (Status s =
          d->connection_->CreateReader(transport::TopicId::kRequests, requests_qos, &d->requests_);
      !s.ok()) {
    return s;
  }
  d->interest_liveliness_ = std::make_unique<dds::WriterLiveliness>();
  d->interest_liveliness_->SetOnChange([daemon = d.get()] { daemon->waitset_.Wake(); });
  dds::Qos interests_qos;
  transport::qos::InterestsReader(interests_qos.get());
  // Without the interests topic (DDS Security permissions that predate it), the daemon serves
  // the whole world only.
  if (Status s =
          d->connection_->CreateReader(transport::TopicId::kInterests, interests_qos,
                                       &d->interest_requests_, d->interest_liveliness_.get());
      !s.ok()) {
    spdlog::warn("interests are off: {}", s.ToString());
  }
  if (Status s = d->waitset_.Attach(d->updates_); !s.ok()) return s;
  if (Status s = d->waitset_.Attach(d->requests_); !s.ok()) return s;
  if (d->interest_requests_.get() != 0) {
    if (Status s = d->waitset_.Attach(d->interest_requests_); !s.ok()) return s;
  }
  d->interests_ = std::make_unique<InterestTable>(
      d->host_.get(),
      InterestLimits{config.limits.max_interests, config.limits.max_interest_regions,
                     config.limits.max_interest_keys, config.engine.margin > 0},
      [daemon = d.get()](uint32_t producer) { return daemon->claims_.count(producer) != 0; });
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
  // The readers (and so the listeners) outlive the waitset among the members: stop the wakes.
  if (liveliness_) liveliness_->SetOnChange(nullptr);
  if (interest_liveliness_) interest_liveliness_->SetOnChange(nullptr);
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
  auto next_interest_expiry = Clock::time_point::max();
  while (!stop_.load()) {
    auto wake =
        std::min({next_summary, next_expiry, next_snapshot, next_resync, next_interest_expiry});
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
    ServeInterests();
    next_snapshot = ServeRequests();
    next_expiry = CheckProducers();
    next_interest_expiry = CheckInterestOwners();
    next_resync = CheckResyncs();
    // A declaration takes effect at a frame: at once when no producer's frame is open (an
    // open one is closed by its producer, or by the next tick).
    if (interests_changed_ && !frame_dirty_ && !tick_mode) RunFrame(0, 0, 0);
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
    RunFrame(producer, batch_.frame(), batch_.sent_time_ns(), batch_.restate());
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

}  // namespace bp::service
