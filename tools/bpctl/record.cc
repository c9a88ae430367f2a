// bpctl record (the update stream to a file) and bpctl replay (a file back onto the topic).
#include <algorithm>
#include <thread>

#include "common.h"

#include "bp/client/update_publisher.h"
#include "bp/transport/recording.h"

namespace bp::bpctl {

int Record(const Common& common, const RecordOptions& options) {
  auto connection = Connect(common);
  if (!connection) return 1;
  // The recorder reads the updates topic like the daemon does (reliable, KEEP_ALL, bounded), so
  // it sees every batch; a recorder slower than the producers slows them down, it never drops.
  dds::Qos qos;
  transport::qos::UpdatesReader(qos.get(), common.config.dds.update_queue);
  dds::Reader reader;
  dds::WaitSet waitset;
  if (Status s = connection->CreateReader(transport::TopicId::kUpdates, qos, &reader); !s.ok()) {
    std::fprintf(stderr, "bpctl record: %s\n", s.ToString().c_str());
    return 1;
  }
  if (Status s = dds::WaitSet::Create(connection->participant(), &waitset);
      !s.ok() || !waitset.Attach(reader).ok()) {
    std::fprintf(stderr, "bpctl record: cannot create a waitset\n");
    return 1;
  }
  wire::RecordingWriter writer;
  wire::RecordingHeader header;
  header.set_created_ns(transport::WallClockNs());
  header.set_topic(common.config.dds.topics.updates);
  header.set_note(options.note);
  if (Status s = writer.Open(options.file, header); !s.ok()) {
    std::fprintf(stderr, "bpctl record: %s\n", s.ToString().c_str());
    return 1;
  }
  std::fprintf(stderr, "bpctl record: recording topic '%s' to %s (Ctrl-C to stop)\n",
               common.config.dds.topics.updates.c_str(), options.file.c_str());
  const auto start = std::chrono::steady_clock::now();
  auto report_at = start + std::chrono::seconds(1);
  Status failure;
  const auto full = [&] { return options.batches > 0 && writer.batches() >= options.batches; };
  // Takes what the reader holds (up to 64) into the file; the number taken.
  const auto take_some = [&] {
    size_t taken = 0;
    Status s = reader.Take(
        64,
        [&](const dds::Received& r) {
          if (!failure.ok() || full()) return;
          failure = writer.Append(
              transport::WallClockNs(),
              std::string_view(reinterpret_cast<const char*>(r.payload.data()), r.payload.size()));
        },
        &taken);
    if (!s.ok()) failure = s;
    return taken;
  };
  while (!StopRequested() && failure.ok()) {
    if (options.seconds > 0 && SecondsSince(start) >= options.seconds) break;
    if (full()) break;
    int triggered = 0;
    if (Status s = waitset.Wait(std::chrono::milliseconds(100), &triggered); !s.ok()) {
      failure = s;
      break;
    }
    take_some();
    if (std::chrono::steady_clock::now() >= report_at) {
      std::fprintf(stderr, "bpctl record: %llu batches, %.1f MB\n",
                   static_cast<unsigned long long>(writer.batches()),
                   static_cast<double>(writer.bytes()) / 1e6);
      report_at += std::chrono::seconds(1);
      (void)writer.Flush();
    }
  }
  // Batches already delivered to this reader (and acknowledged to their producers) belong to
  // the recording: take what is left before closing.
  while (failure.ok() && !full() && take_some() > 0) {
  }
  Status closed = writer.Close();
  if (!failure.ok() || !closed.ok()) {
    std::fprintf(stderr, "bpctl record: %s\n",
                 (!failure.ok() ? failure : closed).ToString().c_str());
    return 1;
  }
  std::fprintf(stderr, "bpctl record: %llu batches written to %s\n",
               static_cast<unsigned long long>(writer.batches()), options.file.c_str());
  return 0;
}

int Replay(const Common& common, const ReplayOptions& options) {
  if (!(options.speed > 0)) {
    std::fprintf(stderr, "bpctl replay: --speed must be > 0\n");
    return 2;
  }
  // Read the whole recording first: the pace must not depend on the disk.
  wire::RecordingReader reader;
  if (Status s = reader.Open(options.file); !s.ok()) {
    std::fprintf(stderr, "bpctl replay: %s\n", s.ToString().c_str());
    return 1;
  }
  std::vector<wire::RecordedBatch> batches;
  for (;;) {
    wire::RecordedBatch b;
    bool end = false;
    if (Status s = reader.Next(&b, &end); !s.ok()) {
      if (s.code() != StatusCode::kDataLoss || batches.empty()) {
        std::fprintf(stderr, "bpctl replay: %s\n", s.ToString().c_str());
        return 1;
      }
      // A recorder killed mid-write leaves a partial last batch: replay the complete ones.
      std::fprintf(stderr, "bpctl replay: warning: %s; replaying the %zu complete batches\n",
                   s.message().c_str(), batches.size());
      break;
    }
    if (end) break;
    batches.push_back(std::move(b));
  }
  auto connection = Connect(common);
  if (!connection) return 1;
  // One writer for every producer of the recording; the payloads go out byte for byte.
  std::unique_ptr<client::UpdatePublisher> pub;
  if (Status s = client::UpdatePublisher::Create(
          *connection, 1, std::chrono::milliseconds(common.config.dds.write_timeout_ms), &pub);
      !s.ok()) {
    std::fprintf(stderr, "bpctl replay: %s\n", s.ToString().c_str());
    return 1;
  }
  if (Status s = WaitInterruptibly(
          common.wait_s, [&](std::chrono::milliseconds t) { return pub->WaitForDaemon(t); });
      !s.ok()) {
    std::fprintf(stderr, "bpctl replay: no daemon listening (%s)\n", s.ToString().c_str());
    return 1;
  }
  const auto start = std::chrono::steady_clock::now();
  const uint64_t t0 = batches.empty() ? 0 : batches.front().time_ns();
  uint64_t retries = 0;
  int last_percent = -1;
  wire::UpdateBatch restamp;
  std::string restamped;
  for (size_t i = 0; i < batches.size() && !StopRequested(); ++i) {
    const auto& b = batches[i];
    if (!options.fast) {
      const double offset_s =
          static_cast<double>(b.time_ns() >= t0 ? b.time_ns() - t0 : 0) / 1e9 / options.speed;
      const auto due = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                   std::chrono::duration<double>(offset_s));
      // In slices, so that Ctrl-C is not held up by a pause in the recording.
      while (!StopRequested() && std::chrono::steady_clock::now() < due) {
        std::this_thread::sleep_until(
            std::min(due, std::chrono::steady_clock::now() + std::chrono::milliseconds(50)));
      }
      if (StopRequested()) break;
    }
    // The batch's send time is restamped (unless --raw), so that latency measured downstream is
    // the replay's, not the recording's age; a payload that does not parse goes out as it is.
    const std::string* payload = &b.payload();
    if (!options.raw && restamp.ParseFromString(b.payload()) && restamp.sent_time_ns() != 0) {
      restamp.set_sent_time_ns(transport::WallClockNs());
      restamped.clear();
      if (restamp.SerializeToString(&restamped)) payload = &restamped;
    }
    for (;;) {
      Status s = pub->PublishRaw(*payload);
      if (s.ok()) break;
      if (s.code() != StatusCode::kDeadlineExceeded || StopRequested()) {
        std::fprintf(stderr, "\nbpctl replay: batch %zu: %s\n", i, s.ToString().c_str());
        return 1;
      }
      ++retries;
    }
    const int percent = static_cast<int>(100 * (i + 1) / batches.size());
    if (options.progress && percent != last_percent) {
      last_percent = percent;
      const int bar = percent / 4;
      std::fprintf(stderr, "\r[%.*s%*s] %3d%% %zu/%zu batches", bar,
                   "=========================", 25 - bar, "", percent, i + 1, batches.size());
    }
  }
  if (options.progress) std::fprintf(stderr, "\n");
  (void)pub->Flush(std::chrono::seconds(10));
  std::fprintf(stderr, "bpctl replay: %zu batches in %.2f s, %llu back-pressure retries\n",
               batches.size(), SecondsSince(start), static_cast<unsigned long long>(retries));
  if (StopRequested()) std::fprintf(stderr, "bpctl replay: interrupted\n");
  return 0;
}

}  // namespace bp::bpctl
