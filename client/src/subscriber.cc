#include "bp/client/subscriber.h"

#include <type_traits>

#include <spdlog/spdlog.h>

namespace bp::client {

template <class Msg>
Status Subscriber<Msg>::Create(Connection& connection, int32_t depth,
                               std::unique_ptr<Subscriber>* out, uint64_t interest) {
  std::unique_ptr<Subscriber> s(new Subscriber());
  dds::Qos qos;
  TopicId topic = TopicId::kStatus;
  std::string partition;
  if constexpr (std::is_same_v<Msg, wire::EventBatch>) {
    qos::EventsReader(qos.get(), depth);
    topic = TopicId::kEvents;
    if (interest != 0) {
      // The interest's writer keeps its recent parts for a reader that matches it late.
      dds_qset_durability(qos.get(), DDS_DURABILITY_TRANSIENT_LOCAL);
      partition = transport::InterestPartition(connection.options().partition, interest);
    }
  } else {
    qos::StatusReader(qos.get(), depth);
    if (interest != 0) {
      return Status(StatusCode::kInvalidArgument, "an interest has no status stream");
    }
  }
  if (Status st = connection.CreateReader(topic, qos, &s->reader_, nullptr,
                                          partition.empty() ? nullptr : &partition);
      !st.ok()) {
    return st;
  }
  if (Status st = dds::WaitSet::Create(connection.participant(), &s->waitset_); !st.ok()) {
    return st;
  }
  if (Status st = s->waitset_.Attach(s->reader_); !st.ok()) return st;
  *out = std::move(s);
  return Status::Ok();
}

template <class Msg>
Status Subscriber<Msg>::Poll(std::chrono::milliseconds timeout, std::vector<Msg>* out) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    size_t taken = 0;
    Status st = reader_.Take(
        256,
        [&](const dds::Received& r) {
          // Counted per writer: a restarted daemon is a new writer and numbers from 1 again.
          uint64_t& last = last_seq_[r.info != nullptr ? r.info->publication_handle : 0];
          if (last != 0 && r.seq > last + 1) gaps_ += r.seq - last - 1;
          last = r.seq;
          Msg msg;
          if (!msg.ParseFromArray(r.payload.data(), static_cast<int>(r.payload.size()))) {
            ++malformed_;
            return;
          }
          out->push_back(std::move(msg));
        },
        &taken);
    if (!st.ok()) return st;
    if (taken > 0) return Status::Ok();
    const auto left = deadline - std::chrono::steady_clock::now();
    if (left <= std::chrono::nanoseconds(0)) return Status::Ok();
    int triggered = 0;
    if (Status w = waitset_.Wait(left, &triggered); !w.ok()) return w;
  }
}

template <class Msg>
Status Subscriber<Msg>::Listen(std::function<void(const Msg&)> f) {
  if (listening_.exchange(true)) {
    return Status(StatusCode::kInvalidArgument, "already listening");
  }
  if (listener_.joinable()) listener_.join();  // a listener that ended by itself
  listener_ = std::thread([this, f = std::move(f)] {
    std::vector<Msg> messages;
    while (listening_.load()) {
      messages.clear();
      if (Status s = Poll(std::chrono::milliseconds(100), &messages); !s.ok()) {
        spdlog::error("event listener stopped: {}", s.ToString());
        std::lock_guard lock(listen_mutex_);
        listen_status_ = s;
        listening_.store(false);
        return;
      }
      for (const Msg& m : messages) f(m);
    }
  });
  return Status::Ok();
}

template <class Msg>
void Subscriber<Msg>::StopListening() {
  listening_.store(false);
  waitset_.Wake();
  if (!listener_.joinable()) return;
  if (listener_.get_id() == std::this_thread::get_id()) return;  // from the callback itself
  listener_.join();
}

template <class Msg>
Status Subscriber<Msg>::listen_status() const {
  std::lock_guard lock(listen_mutex_);
  return listen_status_;
}

template class Subscriber<wire::EventBatch>;
template class Subscriber<wire::DaemonStatus>;

}  // namespace bp::client
