#include "bp/client/interests.h"

namespace bp::client {
uint64_t InterestClient::NewInterestId() { return transport::RandomId(); }

Status InterestClient::Create(Connection& connection, std::unique_ptr<InterestClient>* out) {
  std::unique_ptr<InterestClient> c(new InterestClient());
  c->client_ = transport::RandomId();
  dds::Qos wqos;
  qos::InterestsWriter(wqos.get(), std::chrono::milliseconds(1000));
  if (Status s = connection.CreateWriter(TopicId::kInterests, wqos, &c->writer_); !s.ok()) {
    return s;
  }
  dds::Qos rqos;
  qos::RepliesReader(rqos.get());
  const std::string partition =
      transport::ClientPartition(connection.options().partition, c->client_);
  if (Status s =
          connection.CreateReader(TopicId::kReplies, rqos, &c->replies_, nullptr, &partition);
      !s.ok()) {
    return s;
  }
  if (Status s = dds::WaitSet::Create(connection.participant(), &c->waitset_); !s.ok()) return s;
  if (Status s = c->waitset_.Attach(c->replies_); !s.ok()) return s;
  *out = std::move(c);
  return Status::Ok();
}

Status InterestClient::Send() {
  request_.set_version(wire::SCHEMA_VERSION_1);
  request_.set_client(client_);
  buffer_.clear();
  if (!request_.SerializeToString(&buffer_)) {
    return Status(StatusCode::kInvalidArgument, "the request does not serialise");
  }
  return writer_.Write(++seq_, buffer_);
}

Status InterestClient::Declare(const wire::Interest& interest) {
  if (interest.id() == 0) {
    return Status(StatusCode::kInvalidArgument, "set the interest's id (NewInterestId())");
  }
  request_.Clear();
  *request_.mutable_declare() = interest;
  if (Status s = Send(); !s.ok()) return s;
  const auto old = declared_.find(interest.id());
  before_[interest.id()] =
      old == declared_.end() ? std::nullopt : std::optional<wire::Interest>(old->second);
  declared_[interest.id()] = interest;
  return Status::Ok();
}

Status InterestClient::Drop(uint64_t id) {
  request_.Clear();
  request_.set_drop(id);
  if (Status s = Send(); !s.ok()) return s;
  declared_.erase(id);
  before_.erase(id);
  return Status::Ok();
}

Status InterestClient::OnStatus(const wire::DaemonStatus& status,
                                std::vector<wire::InterestRefusal>* refusals) {
  for (const auto& r : status.interest_refusals()) {
    if (r.client() != client_) continue;
    if (refusals != nullptr) refusals->push_back(r);
    if (const auto b = before_.find(r.interest()); b != before_.end()) {
      if (b->second) {
        declared_[r.interest()] = *b->second;
      } else {
        declared_.erase(r.interest());
      }
      before_.erase(b);
    }
  }
  for (uint64_t id : status.dropped_interests()) {
    const auto it = declared_.find(id);
    if (it == declared_.end()) continue;
    request_.Clear();
    *request_.mutable_declare() = it->second;
    if (Status s = Send(); !s.ok()) return s;
  }
  if (status.epoch() == 0 || status.epoch() == epoch_) return Status::Ok();
  const bool restarted = epoch_ != 0;
  epoch_ = status.epoch();
  if (!restarted) return Status::Ok();
  for (const auto& [id, interest] : declared_) {
    request_.Clear();
    *request_.mutable_declare() = interest;
    if (Status s = Send(); !s.ok()) return s;
  }
  return Status::Ok();
}

Status InterestClient::Query(std::span<const double> lo, std::span<const double> hi,
                             std::chrono::milliseconds timeout, std::vector<uint64_t>* keys,
                             uint64_t* frame) {
  keys->clear();
  const uint64_t query = ++next_query_;
  request_.Clear();
  wire::SpotQuery* q = request_.mutable_query();
  q->set_query(query);
  q->set_dim(static_cast<uint32_t>(lo.size()));
  q->mutable_lo()->Add(lo.begin(), lo.end());
  q->mutable_hi()->Add(hi.begin(), hi.end());
  if (Status s = Send(); !s.ok()) return s;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  wire::SpotAnswer answer;
  uint32_t next_part = 0;
  for (;;) {
    bool done = false;
    Status failure;
    size_t taken = 0;
    Status st = replies_.Take(
        64,
        [&](const dds::Received& r) {
          if (done ||
              !answer.ParseFromArray(r.payload.data(), static_cast<int>(r.payload.size())) ||
              answer.query() != query) {
            return;  // an older query's answer, or not one
          }
          if (!answer.error().empty()) {
            failure = Status(StatusCode::kInvalidArgument, answer.error());
            done = true;
            return;
          }
          if (answer.part() != next_part) {
            failure = Status(StatusCode::kDataLoss,
                             "spot query answer part " + std::to_string(next_part) + " was lost");
            done = true;
            return;
          }
          ++next_part;
          keys->insert(keys->end(), answer.keys().begin(), answer.keys().end());
          if (frame != nullptr) *frame = answer.frame();
          done = answer.last_part();
        },
        &taken);
    if (!st.ok()) return st;
    if (done) return failure;
    const auto left = deadline - std::chrono::steady_clock::now();
    if (left <= std::chrono::nanoseconds(0)) {
      return Status(StatusCode::kDeadlineExceeded, "no answer to the spot query within " +
                                                       std::to_string(timeout.count()) +
                                                       " ms (is broadphased running?)");
    }
    int triggered = 0;
    if (Status w = waitset_.Wait(left, &triggered); !w.ok()) return w;
  }
}

}  // namespace bp::client
