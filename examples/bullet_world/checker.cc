#include "checker.h"

#include <algorithm>
#include <iterator>

#include <fmt/format.h>

#include "bp/client/update_publisher.h"

namespace bp::examples {
namespace {

// The daemon's key of an object: (producer << 48) | producer-local id (docs/PROTOCOL.md).
constexpr int kProducerShift = 48;

std::string PairName(uint64_t pair) {
  return fmt::format("({}, {})", pair >> 32, pair & 0xffffffffu);
}

// Counts a - b and b - a; names the first element of either.
void Compare(const char* kind, const std::vector<uint64_t>& expected,
             const std::vector<uint64_t>& got, FrameCheck* out) {
  std::vector<uint64_t> missing, unexpected;
  std::set_difference(expected.begin(), expected.end(), got.begin(), got.end(),
                      std::back_inserter(missing));
  std::set_difference(got.begin(), got.end(), expected.begin(), expected.end(),
                      std::back_inserter(unexpected));
  out->missing += missing.size();
  out->unexpected += unexpected.size();
  if (!out->first_difference.empty()) return;
  if (!missing.empty()) {
    out->first_difference = fmt::format("{} {} expected, not received", kind, PairName(missing[0]));
  } else if (!unexpected.empty()) {
    out->first_difference =
        fmt::format("{} {} received, not expected", kind, PairName(unexpected[0]));
  }
}

}  // namespace

Status EventChecker::Start(client::Connection& connection, uint32_t producer,
                           std::unique_ptr<EventChecker>* out) {
  std::unique_ptr<EventChecker> c(new EventChecker());
  c->producer_ = producer;
  if (Status s = client::EventSubscriber::Create(connection, 4096, &c->subscriber_); !s.ok()) {
    return s;
  }
  EventChecker* self = c.get();
  if (Status s = c->subscriber_->Listen([self](const wire::EventBatch& b) { self->OnPart(b); });
      !s.ok()) {
    return s;
  }
  *out = std::move(c);
  return Status::Ok();
}

EventChecker::~EventChecker() {
  if (subscriber_) subscriber_->StopListening();
}

Status EventChecker::WaitForDaemon(std::chrono::milliseconds timeout) const {
  return subscriber_->WaitForDaemon(timeout);
}

void EventChecker::OnPart(const wire::EventBatch& part) {
  const uint64_t now = client::WallClockNs();
  if (part.snapshot() || part.interest() != 0 || part.source_producer() != producer_) return;
  std::lock_guard lock(mutex_);
  Received& r = received_[part.source_frame()];
  // Keys of this producer's objects back to local ids; pairs naming another producer's object
  // are counted and left out (the comparison covers this simulator's world).
  auto add = [&](const google::protobuf::RepeatedField<uint64_t>& flat, std::vector<uint64_t>* to) {
    for (int i = 0; i + 1 < flat.size(); i += 2) {
      const uint64_t a = flat[i], b = flat[i + 1];
      if (a >> kProducerShift != producer_ || b >> kProducerShift != producer_) {
        ++r.foreign;
        continue;
      }
      const uint64_t mask = (uint64_t{1} << kProducerShift) - 1;
      to->push_back((a & mask) << 32 | (b & mask));
    }
  };
  add(part.uncollide(), &r.uncollide);
  add(part.collide(), &r.collide);
  if (part.last_part()) {
    r.complete = true;
    r.arrived_ns = now;
  }
}

void EventChecker::Expect(uint64_t frame, uint64_t sent_ns, std::vector<uint64_t> uncollide,
                          std::vector<uint64_t> collide) {
  expected_[frame] = Expected{sent_ns, std::move(uncollide), std::move(collide)};
}

void EventChecker::Collect(const std::function<void(const FrameCheck&)>& f) {
  while (!expected_.empty()) {
    auto e = expected_.begin();
    Received r;
    {
      std::lock_guard lock(mutex_);
      auto it = received_.find(e->first);
      if (it == received_.end() || !it->second.complete) {
        // The daemon publishes frames in order: once a later frame is complete, this one will
        // not come (a part lost, or the batch refused whole). It is reported as not received.
        bool later_complete = false;
        for (auto l = received_.upper_bound(e->first); l != received_.end(); ++l) {
          later_complete = later_complete || l->second.complete;
        }
        if (!later_complete) return;
        if (it != received_.end()) received_.erase(it);
        FrameCheck lost;
        lost.frame = e->first;
        lost.expected = e->second.uncollide.size() + e->second.collide.size();
        lost.arrived = false;
        lost.first_difference = "the frame's events did not arrive (a later frame's did)";
        expected_.erase(e);
        f(lost);
        continue;
      }
      r = std::move(it->second);
      received_.erase(it);
    }
    // The daemon lists each kind sorted by (a, b); with one producer's keys that is this order.
    std::sort(r.uncollide.begin(), r.uncollide.end());
    std::sort(r.collide.begin(), r.collide.end());
    FrameCheck check;
    check.frame = e->first;
    check.expected = e->second.uncollide.size() + e->second.collide.size();
    check.received = r.uncollide.size() + r.collide.size();
    check.foreign = r.foreign;
    check.latency_ms =
        static_cast<double>(static_cast<int64_t>(r.arrived_ns - e->second.sent_ns)) / 1e6;
    Compare("uncollide", e->second.uncollide, r.uncollide, &check);
    Compare("collide", e->second.collide, r.collide, &check);
    expected_.erase(e);
    f(check);
  }
}

}  // namespace bp::examples
