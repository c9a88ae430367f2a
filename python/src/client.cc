// broadphase's client classes: the client library (bp/client/) for Python, with numpy arrays in
// and out. Connection, Publisher, EventSubscriber, OverlapView, StatusSubscriber, InterestClient
// and Recording; docs/GUIDE.md ("Python") shows them together.
//
// Every call that waits on DDS (publish under back-pressure, poll, the waits for the daemon, a
// spot query) releases the GIL. A Status that is not ok becomes an exception: InvalidArgument a
// ValueError, NotFound a LookupError (FileNotFoundError for a file), DeadlineExceeded a
// TimeoutError, Unavailable a ConnectionError, anything else a RuntimeError; the message is the
// library's, which names the item and the reason.
//
// Thread safety: as the library's classes (one thread at a time per object); each holds a
// reference to its Connection, which outlives it.
#include "client.h"

#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "arrays.h"
#include "config.h"
#include "engine_host.h"
#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <pybind11/stl.h>

#include "bp/client/batch_builder.h"
#include "bp/client/connection.h"
#include "bp/client/interests.h"
#include "bp/client/overlap_view.h"
#include "bp/client/subscriber.h"
#include "bp/client/update_publisher.h"
#include "bp/transport/recording.h"

namespace bp::python {
namespace {

[[noreturn]] void Throw(const Status& s, const std::string& what) {
  const std::string msg = what + ": " + s.ToString();
  switch (s.code()) {
    case StatusCode::kInvalidArgument:
      throw py::value_error(msg);
    case StatusCode::kNotFound:
      PyErr_SetString(PyExc_LookupError, msg.c_str());
      throw py::error_already_set();
    case StatusCode::kDeadlineExceeded:
      PyErr_SetString(PyExc_TimeoutError, msg.c_str());
      throw py::error_already_set();
    case StatusCode::kUnavailable:
      PyErr_SetString(PyExc_ConnectionError, msg.c_str());
      throw py::error_already_set();
    default:
      throw std::runtime_error(msg);
  }
}
void Check(const Status& s, const std::string& what) {
  if (!s.ok()) Throw(s, what);
}
// Runs f (which returns a Status) with the GIL released, then Check.
template <class F>
void WithoutGil(const std::string& what, F&& f) {
  Status s;
  {
    py::gil_scoped_release release;
    s = f();
  }
  Check(s, what);
}

std::chrono::milliseconds Millis(double seconds, const std::string& what) {
  if (!(seconds >= 0)) {
    throw py::value_error(what + ": timeout must be >= 0, got " + std::to_string(seconds));
  }
  // Longer waits wait kLongestWait (beyond it the library's deadlines would overflow).
  constexpr double kLongestWait = 1e7;
  return std::chrono::milliseconds(
      static_cast<int64_t>(std::ceil(std::min(seconds, kLongestWait) * 1000.0)));
}

// A protobuf message as a dict: the schema's field names; integers as ints (64-bit ones too),
// enums by name, bytes as bytes, repeated fields as lists, a nested message as a dict (None when
// unset); of a oneof, only the field that is set.
py::object ToDict(const google::protobuf::Message& msg);
py::object FieldValue(const google::protobuf::Message& msg,
                      const google::protobuf::FieldDescriptor* f, int index) {
  using FD = google::protobuf::FieldDescriptor;
  const auto* r = msg.GetReflection();
  const bool rep = index >= 0;
  switch (f->cpp_type()) {
    case FD::CPPTYPE_INT32:
      return py::int_(rep ? r->GetRepeatedInt32(msg, f, index) : r->GetInt32(msg, f));
    case FD::CPPTYPE_INT64:
      return py::int_(rep ? r->GetRepeatedInt64(msg, f, index) : r->GetInt64(msg, f));
    case FD::CPPTYPE_UINT32:
      return py::int_(rep ? r->GetRepeatedUInt32(msg, f, index) : r->GetUInt32(msg, f));
    case FD::CPPTYPE_UINT64:
      return py::int_(rep ? r->GetRepeatedUInt64(msg, f, index) : r->GetUInt64(msg, f));
    case FD::CPPTYPE_DOUBLE:
      return py::float_(rep ? r->GetRepeatedDouble(msg, f, index) : r->GetDouble(msg, f));
    case FD::CPPTYPE_FLOAT:
      return py::float_(rep ? r->GetRepeatedFloat(msg, f, index) : r->GetFloat(msg, f));
    case FD::CPPTYPE_BOOL:
      return py::bool_(rep ? r->GetRepeatedBool(msg, f, index) : r->GetBool(msg, f));
    case FD::CPPTYPE_ENUM:
      return py::str((rep ? r->GetRepeatedEnum(msg, f, index) : r->GetEnum(msg, f))->name());
    case FD::CPPTYPE_STRING: {
      const std::string v = rep ? r->GetRepeatedString(msg, f, index) : r->GetString(msg, f);
      if (f->type() == FD::TYPE_BYTES) return py::bytes(v);
      return py::str(v);
    }
    case FD::CPPTYPE_MESSAGE:
      if (!rep && !r->HasField(msg, f)) return py::none();
      return ToDict(rep ? r->GetRepeatedMessage(msg, f, index) : r->GetMessage(msg, f));
  }
  return py::none();
}
py::object ToDict(const google::protobuf::Message& msg) {
  const auto* d = msg.GetDescriptor();
  const auto* r = msg.GetReflection();
  py::dict out;
  for (int i = 0; i < d->field_count(); ++i) {
    const auto* f = d->field(i);
    if (f->is_repeated()) {
      py::list items;
      for (int k = 0; k < r->FieldSize(msg, f); ++k) items.append(FieldValue(msg, f, k));
      out[py::str(f->name())] = items;
    } else if (f->containing_oneof() == nullptr || r->HasField(msg, f)) {
      out[py::str(f->name())] = FieldValue(msg, f, -1);
    }
  }
  return out;
}

// A flattened pair array (a0, b0, a1, b1, ...) as uint64[m, 2].
py::array PairArray(const google::protobuf::RepeatedField<uint64_t>& flat) {
  return Matrix(flat.data(), static_cast<size_t>(flat.size()) / 2, 2);
}

// One received part of the events topic.
struct EventPart {
  uint64_t frame = 0, sequence = 0, epoch = 0, interest = 0, objects = 0, overlaps = 0;
  uint64_t source_frame = 0, source_sent_time_ns = 0, published_time_ns = 0;
  uint32_t part = 0, source_producer = 0;
  bool last_part = false, snapshot = false;
  py::array collides, uncollides, snapshot_pairs;
};
EventPart PartOf(const wire::EventBatch& b) {
  EventPart p;
  p.frame = b.frame();
  p.sequence = b.sequence();
  p.epoch = b.epoch();
  p.interest = b.interest();
  p.objects = b.objects();
  p.overlaps = b.overlaps();
  p.source_frame = b.source_frame();
  p.source_sent_time_ns = b.source_sent_time_ns();
  p.published_time_ns = b.published_time_ns();
  p.part = b.part();
  p.source_producer = b.source_producer();
  p.last_part = b.last_part();
  p.snapshot = b.snapshot();
  p.collides = PairArray(b.collide());
  p.uncollides = PairArray(b.uncollide());
  p.snapshot_pairs = PairArray(b.snapshot_pairs());
  return p;
}

// ---- Connection ----

struct PyConnection {
  std::unique_ptr<transport::Connection> connection;
  int dims = 3;
  bool double_coordinates = false;
  std::string partition;
};

std::shared_ptr<PyConnection> OpenConnection(const py::object& config, const py::object& domain,
                                             const py::object& partition,
                                             const py::object& cyclone_config,
                                             const py::object& dims) {
  service::Config cfg;
  if (!config.is_none()) {
    const std::string path = py::str(config);
    Status s;
    {
      py::gil_scoped_release release;
      s = service::LoadConfigFile(path, &cfg);
    }
    if (!s.ok()) {
      if (s.code() == StatusCode::kNotFound) {
        PyErr_SetString(PyExc_FileNotFoundError, ("Connection: " + s.ToString()).c_str());
        throw py::error_already_set();
      }
      throw py::value_error("Connection: " + s.ToString());
    }
  } else {
    cfg.dds.cyclone_config.clear();  // Cyclone's default unless given
  }
  if (!domain.is_none()) {
    cfg.dds.domain = static_cast<uint32_t>(IntArg(domain, "Connection: domain", 0, 232));
  }
  if (!partition.is_none()) cfg.dds.partition = py::str(partition);
  if (!cyclone_config.is_none()) cfg.dds.cyclone_config = py::str(cyclone_config);
  auto out = std::make_shared<PyConnection>();
  out->dims = dims.is_none() ? cfg.engine.dimension
                             : static_cast<int>(IntArg(dims, "Connection: dims", 2, 3));
  if (out->dims != 2 && out->dims != 3) {
    throw py::value_error("Connection: dims must be 2 or 3, got " + std::to_string(out->dims));
  }
  out->double_coordinates = cfg.engine.coordinate == service::CoordinateType::kDouble;
  out->partition = cfg.dds.partition;
  transport::ConnectionOptions options;
  options.domain = cfg.dds.domain;
  options.partition = cfg.dds.partition;
  options.topics = {cfg.dds.topics.updates,  cfg.dds.topics.events,    cfg.dds.topics.status,
                    cfg.dds.topics.requests, cfg.dds.topics.interests, cfg.dds.topics.replies};
  Status s;
  {
    py::gil_scoped_release release;
    if (!cfg.dds.cyclone_config.empty()) {
      s = transport::ReadTextFile(cfg.dds.cyclone_config, &options.cyclone_xml);
    }
    if (s.ok()) s = transport::Connection::Open(options, &out->connection);
  }
  if (s.code() == StatusCode::kNotFound) {
    PyErr_SetString(PyExc_FileNotFoundError, ("Connection: " + s.ToString()).c_str());
    throw py::error_already_set();
  }
  Check(s, "Connection");
  return out;
}

// ---- Publisher ----

class PyPublisher {
 public:
  PyPublisher(std::shared_ptr<PyConnection> connection, uint32_t producer, double write_timeout,
              bool restate_on_restart, const py::object& double_coordinates)
      : connection_(std::move(connection)) {
    if (producer == 0 || producer > 65535) {
      throw py::value_error("Publisher: producer must be in 1..65535, got " +
                            std::to_string(producer));
    }
    double_ = double_coordinates.is_none() ? connection_->double_coordinates
                                           : double_coordinates.cast<bool>();
    client::PublisherOptions options;
    options.write_timeout = Millis(write_timeout, "Publisher");
    options.restate_on_restart = restate_on_restart;
    WithoutGil("Publisher", [&] {
      return client::UpdatePublisher::Create(*connection_->connection, producer, options, &pub_);
    });
  }

  void WaitForDaemon(double timeout) {
    const auto t = Millis(timeout, "wait_for_daemon");
    WithoutGil("Publisher.wait_for_daemon", [&] { return pub_->WaitForDaemon(t); });
  }

  // Publishes one batch; returns its frame number.
  uint64_t Publish(const py::object& insert_ids, const py::object& insert_lo,
                   const py::object& insert_hi, const py::object& category, const py::object& mask,
                   const py::object& is_static, const py::object& update_ids,
                   const py::object& update_lo, const py::object& update_hi,
                   const py::object& erase_ids, bool end_of_frame, const py::object& frame) {
    const int k = connection_->dims;
    wire::UpdateBatch batch;
    batch.set_dim(static_cast<uint32_t>(k));
    batch.set_end_of_frame(end_of_frame);
    batch.set_frame(frame.is_none() ? next_frame_
                                    : IntArg(frame, "publish: frame", 0, ~uint64_t{0}));
    if (!insert_ids.is_none()) {
      const auto ids = LocalIds(insert_ids, "publish: insert_ids");
      Boxes(ids, insert_lo, insert_hi, "publish: insert", batch.mutable_inserts());
      if (!category.is_none() || !mask.is_none() || !is_static.is_none()) {
        const auto cat = PerItemU64(category, "publish: category", ids.size(), 1);
        const auto msk = PerItemU64(mask, "publish: mask", ids.size(), ~uint64_t{0});
        const auto st = PerItemBool(is_static, "publish: static", ids.size());
        for (size_t i = 0; i < ids.size(); ++i) {
          batch.mutable_inserts()->add_category(cat[i]);
          batch.mutable_inserts()->add_mask(msk[i]);
          batch.mutable_inserts()->add_static_flags(st[i] != 0);
        }
      }
    } else if (!insert_lo.is_none() || !insert_hi.is_none() || !category.is_none() ||
               !mask.is_none() || !is_static.is_none()) {
      throw py::value_error(
          "publish: insert_lo, insert_hi, category, mask and static need insert_ids");
    }
    if (!update_ids.is_none()) {
      const auto ids = LocalIds(update_ids, "publish: update_ids");
      Boxes(ids, update_lo, update_hi, "publish: update", batch.mutable_updates());
    } else if (!update_lo.is_none() || !update_hi.is_none()) {
      throw py::value_error("publish: update_lo and update_hi need update_ids");
    }
    if (!erase_ids.is_none()) {
      for (uint64_t id : LocalIds(erase_ids, "publish: erase_ids")) batch.add_erases(id);
    }
    WithoutGil("publish", [&] { return pub_->Publish(&batch); });
    if (end_of_frame) next_frame_ = batch.frame() + 1;
    return batch.frame();
  }

  void WaitForReaders(uint32_t n, double timeout) {
    const auto t = Millis(timeout, "wait_for_readers");
    WithoutGil("Publisher.wait_for_readers", [&] { return pub_->WaitForReaders(n, t); });
  }
  void Flush(double timeout) {
    const auto t = Millis(timeout, "flush");
    WithoutGil("Publisher.flush", [&] { return pub_->Flush(t); });
  }
  void Maintain() {
    WithoutGil("Publisher.maintain", [&] { return pub_->Maintain(); });
  }
  const client::UpdatePublisher& publisher() const { return *pub_; }
  int dims() const { return connection_->dims; }

 private:
  static std::vector<uint64_t> LocalIds(const py::object& obj, const std::string& what) {
    std::vector<uint64_t> ids = Keys(obj, what);
    for (size_t i = 0; i < ids.size(); ++i) {
      if (ids[i] >= service::kLocalIdLimit) {
        throw py::value_error(what + "[" + std::to_string(i) + "] is " + std::to_string(ids[i]) +
                              ": producer-local ids are below 2**48");
      }
    }
    return ids;
  }
  void Boxes(const std::vector<uint64_t>& ids, const py::object& lo_obj, const py::object& hi_obj,
             const std::string& what, wire::BoxArray* out) const {
    const int k = connection_->dims;
    const auto n = static_cast<py::ssize_t>(ids.size());
    for (uint64_t id : ids) out->add_ids(id);
    if (double_) {
      const auto lo = CoordsOf<double>(lo_obj, what + "_lo", n, k);
      const auto hi = CoordsOf<double>(hi_obj, what + "_hi", n, k);
      out->mutable_lo64()->Add(lo.begin(), lo.end());
      out->mutable_hi64()->Add(hi.begin(), hi.end());
    } else {
      const auto lo = CoordsOf<float>(lo_obj, what + "_lo", n, k);
      const auto hi = CoordsOf<float>(hi_obj, what + "_hi", n, k);
      out->mutable_lo32()->Add(lo.begin(), lo.end());
      out->mutable_hi32()->Add(hi.begin(), hi.end());
    }
  }

  std::shared_ptr<PyConnection> connection_;
  std::unique_ptr<client::UpdatePublisher> pub_;
  bool double_ = false;
  uint64_t next_frame_ = 1;
};

// ---- Subscribers ----

class PyEventSubscriber {
 public:
  PyEventSubscriber(std::shared_ptr<PyConnection> connection, int32_t depth, uint64_t interest)
      : connection_(std::move(connection)) {
    if (depth < 1) throw py::value_error("EventSubscriber: depth must be >= 1");
    WithoutGil("EventSubscriber", [&] {
      return client::EventSubscriber::Create(*connection_->connection, depth, &sub_, interest);
    });
  }
  void WaitForDaemon(double timeout) {
    const auto t = Millis(timeout, "wait_for_daemon");
    WithoutGil("EventSubscriber.wait_for_daemon", [&] { return sub_->WaitForDaemon(t); });
  }
  std::vector<wire::EventBatch> PollRaw(double timeout) {
    const auto t = Millis(timeout, "poll");
    std::vector<wire::EventBatch> got;
    WithoutGil("poll", [&] { return sub_->Poll(t, &got); });
    return got;
  }
  std::vector<EventPart> Poll(double timeout) {
    std::vector<EventPart> out;
    for (const auto& b : PollRaw(timeout)) out.push_back(PartOf(b));
    return out;
  }
  uint64_t gaps() const { return sub_->gaps(); }
  uint64_t malformed() const { return sub_->malformed(); }

 private:
  std::shared_ptr<PyConnection> connection_;
  std::unique_ptr<client::EventSubscriber> sub_;
};

// An OverlapView fed by its own subscriber, asking for snapshots when it needs one (again after
// a second without one).
class PyOverlapView {
 public:
  PyOverlapView(std::shared_ptr<PyConnection> connection, int32_t depth, uint64_t interest)
      : connection_(connection), events_(connection, depth, interest), interest_(interest) {
    WithoutGil("OverlapView", [&] {
      return client::SnapshotRequester::Create(*connection_->connection, &requester_);
    });
  }
  void WaitForDaemon(double timeout) { events_.WaitForDaemon(timeout); }
  // Applies what arrives within timeout; returns the parts applied.
  std::vector<EventPart> Poll(double timeout) {
    std::vector<EventPart> out;
    for (const auto& b : events_.PollRaw(timeout)) {
      view_.Apply(b);
      out.push_back(PartOf(b));
    }
    const auto now = std::chrono::steady_clock::now();
    if (view_.wants_snapshot() && now - last_request_ >= std::chrono::seconds(1)) {
      last_request_ = now;
      WithoutGil("OverlapView: snapshot request", [&] {
        return requester_->Request(view_.resyncs() == 0 ? "join" : "resync", interest_);
      });
    }
    return out;
  }
  void WaitSynced(double timeout) {
    const auto deadline =
        std::chrono::steady_clock::now() + Millis(timeout, "OverlapView.wait_synced");
    while (!view_.synced()) {
      if (std::chrono::steady_clock::now() >= deadline) {
        PyErr_SetString(PyExc_TimeoutError,
                        ("OverlapView.wait_synced: no complete snapshot within " +
                         std::to_string(timeout) + " s")
                            .c_str());
        throw py::error_already_set();
      }
      Poll(0.05);
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    }
  }
  py::array Pairs() const {
    std::vector<uint64_t> flat;
    for (const auto& [a, b] : view_.SortedPairs()) {
      flat.push_back(a);
      flat.push_back(b);
    }
    return Matrix(flat.data(), flat.size() / 2, 2);
  }
  const client::OverlapView& view() const { return view_; }
  const PyEventSubscriber& events() const { return events_; }

 private:
  std::shared_ptr<PyConnection> connection_;
  PyEventSubscriber events_;
  uint64_t interest_;
  client::OverlapView view_;
  std::unique_ptr<client::SnapshotRequester> requester_;
  std::chrono::steady_clock::time_point last_request_{};
};

class PyStatusSubscriber {
 public:
  PyStatusSubscriber(std::shared_ptr<PyConnection> connection, int32_t depth)
      : connection_(std::move(connection)) {
    WithoutGil("StatusSubscriber", [&] {
      return client::StatusSubscriber::Create(*connection_->connection, depth, &sub_);
    });
  }
  py::list Poll(double timeout) {
    const auto t = Millis(timeout, "poll");
    std::vector<wire::DaemonStatus> got;
    WithoutGil("StatusSubscriber.poll", [&] { return sub_->Poll(t, &got); });
    py::list out;
    for (const auto& m : got) out.append(ToDict(m));
    return out;
  }

 private:
  std::shared_ptr<PyConnection> connection_;
  std::unique_ptr<client::StatusSubscriber> sub_;
};

// ---- Interests ----

class PyInterestClient {
 public:
  explicit PyInterestClient(std::shared_ptr<PyConnection> connection)
      : connection_(std::move(connection)) {
    Status s;
    {
      py::gil_scoped_release release;
      s = client::InterestClient::Create(*connection_->connection, &client_);
      if (s.ok()) s = client::StatusSubscriber::Create(*connection_->connection, 16, &status_);
    }
    Check(s, "InterestClient");
  }
  void WaitForDaemon(double timeout) {
    const auto t = Millis(timeout, "wait_for_daemon");
    WithoutGil("InterestClient.wait_for_daemon", [&] { return client_->WaitForDaemon(t); });
  }
  uint64_t Declare(const py::object& regions_lo, const py::object& regions_hi, double leave_margin,
                   bool pairs_inside, const py::object& keys, const py::object& producers,
                   uint64_t category_mask, const py::object& id) {
    const int k = connection_->dims;
    wire::Interest in;
    in.set_id(id.is_none() ? client::InterestClient::NewInterestId()
                           : IntArg(id, "declare: id", 1, ~uint64_t{0}));
    in.set_dim(static_cast<uint32_t>(k));
    if (!regions_lo.is_none() || !regions_hi.is_none()) {
      if (regions_lo.is_none() || regions_hi.is_none()) {
        throw py::value_error("declare: regions need both regions_lo and regions_hi");
      }
      const auto lo = CoordsOf<double>(regions_lo, "declare: regions_lo", -1, k, true);
      const auto hi = CoordsOf<double>(regions_hi, "declare: regions_hi",
                                       static_cast<py::ssize_t>(lo.size()) / k, k, true);
      in.mutable_region_lo()->Add(lo.begin(), lo.end());
      in.mutable_region_hi()->Add(hi.begin(), hi.end());
    }
    in.set_leave_margin(leave_margin);
    in.set_pairs_inside(pairs_inside);
    if (!keys.is_none()) {
      for (uint64_t key : Keys(keys, "declare: keys")) in.add_keys(key);
    }
    if (!producers.is_none()) {
      for (uint64_t p : Keys(producers, "declare: producers")) {
        if (p == 0 || p > 65535) {
          throw py::value_error("declare: producer " + std::to_string(p) + " is outside 1..65535");
        }
        in.add_producers(static_cast<uint32_t>(p));
      }
    }
    in.set_category_mask(category_mask);
    WithoutGil("declare", [&] { return client_->Declare(in); });
    return in.id();
  }
  void Drop(uint64_t id) {
    WithoutGil("drop", [&] { return client_->Drop(id); });
  }
  // Reads the daemon's reports: declares the interests again after a restart or a drop; returns
  // the refusals addressed to this client.
  py::list Maintain() {
    std::vector<wire::DaemonStatus> got;
    std::vector<wire::InterestRefusal> refusals;
    Status s;
    {
      py::gil_scoped_release release;
      s = status_->Poll(std::chrono::milliseconds(0), &got);
      for (size_t i = 0; s.ok() && i < got.size(); ++i) s = client_->OnStatus(got[i], &refusals);
    }
    Check(s, "InterestClient.maintain");
    py::list out;
    for (const auto& r : refusals) out.append(ToDict(r));
    return out;
  }
  py::tuple Query(const py::object& lo_obj, const py::object& hi_obj, double timeout) {
    const int k = connection_->dims;
    const auto lo = CoordsOf<double>(lo_obj, "query: lo", 1, k, true);
    const auto hi = CoordsOf<double>(hi_obj, "query: hi", 1, k, true);
    const auto t = Millis(timeout, "query");
    std::vector<uint64_t> keys;
    uint64_t frame = 0;
    WithoutGil("query", [&] { return client_->Query(lo, hi, t, &keys, &frame); });
    return py::make_tuple(Vector(keys.data(), keys.size()), frame);
  }
  uint64_t id() const { return client_->id(); }

 private:
  std::shared_ptr<PyConnection> connection_;
  std::unique_ptr<client::InterestClient> client_;
  std::unique_ptr<client::StatusSubscriber> status_;
};

// ---- Recordings ----

py::dict BoxArrayDict(const wire::BoxArray& a, uint32_t dim, const std::string& prefix,
                      py::dict d) {
  const auto n = static_cast<size_t>(a.ids_size());
  const size_t k = dim;
  const auto rows = [&](int values) { return k == 0 ? 0 : static_cast<size_t>(values) / k; };
  d[(prefix + "_ids").c_str()] = Vector(a.ids().data(), n);
  if (a.lo64_size() != 0 || a.hi64_size() != 0) {
    d[(prefix + "_lo").c_str()] = Matrix(a.lo64().data(), rows(a.lo64_size()), k);
    d[(prefix + "_hi").c_str()] = Matrix(a.hi64().data(), rows(a.hi64_size()), k);
  } else {
    d[(prefix + "_lo").c_str()] = Matrix(a.lo32().data(), rows(a.lo32_size()), k);
    d[(prefix + "_hi").c_str()] = Matrix(a.hi32().data(), rows(a.hi32_size()), k);
  }
  if (prefix == "insert") {
    d["category"] = Vector(a.category().data(), static_cast<size_t>(a.category_size()));
    d["mask"] = Vector(a.mask().data(), static_cast<size_t>(a.mask_size()));
    std::vector<uint8_t> st(a.static_flags().begin(), a.static_flags().end());
    d["static"] = Vector(st.data(), st.size()).attr("astype")("bool");
  }
  return d;
}

class PyRecording {
 public:
  explicit PyRecording(const std::string& path) : path_(path) {
    Status s = reader_.Open(path);
    if (s.code() == StatusCode::kNotFound) {
      PyErr_SetString(PyExc_FileNotFoundError, ("Recording: " + s.ToString()).c_str());
      throw py::error_already_set();
    }
    Check(s, "Recording");
  }
  // The next batch as a dict, or None at the end of the file.
  py::object Next() {
    wire::RecordedBatch rec;
    bool end = false;
    WithoutGil("Recording " + path_, [&] { return reader_.Next(&rec, &end); });
    if (end) return py::none();
    py::dict d;
    d["time_ns"] = rec.time_ns();
    wire::UpdateBatch b;
    if (!b.ParseFromString(rec.payload())) {
      d["malformed"] = true;
      d["payload"] = py::bytes(rec.payload());
      return d;
    }
    d["malformed"] = false;
    d["producer"] = b.producer();
    d["frame"] = b.frame();
    d["end_of_frame"] = b.end_of_frame();
    d["dim"] = b.dim();
    d["batch_seq"] = b.batch_seq();
    d["sent_time_ns"] = b.sent_time_ns();
    d["restate"] = b.restate();
    BoxArrayDict(b.inserts(), b.dim(), "insert", d);
    BoxArrayDict(b.updates(), b.dim(), "update", d);
    d["erase_ids"] = Vector(b.erases().data(), static_cast<size_t>(b.erases_size()));
    return d;
  }
  py::dict Header() const { return ToDict(reader_.header()).cast<py::dict>(); }
  uint64_t batches() const { return reader_.batches(); }

 private:
  std::string path_;
  wire::RecordingReader reader_;
};

}  // namespace

void BindClient(py::module_& m) {
  py::class_<EventPart>(m, "EventPart",
                        "One part of a frame's events (or of a snapshot) as received: pairs as "
                        "uint64[m, 2] arrays of global keys (producer << 48 | id).")
      .def_readonly("frame", &EventPart::frame)
      .def_readonly("sequence", &EventPart::sequence)
      .def_readonly("part", &EventPart::part)
      .def_readonly("last_part", &EventPart::last_part)
      .def_readonly("snapshot", &EventPart::snapshot)
      .def_readonly("epoch", &EventPart::epoch)
      .def_readonly("interest", &EventPart::interest)
      .def_readonly("collides", &EventPart::collides)
      .def_readonly("uncollides", &EventPart::uncollides)
      .def_readonly("snapshot_pairs", &EventPart::snapshot_pairs)
      .def_readonly("objects", &EventPart::objects)
      .def_readonly("overlaps", &EventPart::overlaps)
      .def_readonly("source_producer", &EventPart::source_producer)
      .def_readonly("source_frame", &EventPart::source_frame)
      .def_readonly("source_sent_time_ns", &EventPart::source_sent_time_ns)
      .def_readonly("published_time_ns", &EventPart::published_time_ns)
      .def("__repr__", [](const EventPart& p) {
        return "EventPart(frame=" + std::to_string(p.frame) + ", part=" + std::to_string(p.part) +
               (p.snapshot ? ", snapshot" : "") +
               ", collides=" + std::to_string(p.collides.shape(0)) +
               ", uncollides=" + std::to_string(p.uncollides.shape(0)) + ")";
      });

  py::class_<PyConnection, std::shared_ptr<PyConnection>>(
      m, "Connection",
      "A DDS participant joined to a broadphase deployment. Connection(config=None, *, domain, "
      "partition, cyclone_config, dims): config is the daemon's YAML file (the deployment is "
      "read from its dds section, dims and coordinates from its engine section); the keywords "
      "override it (without a file: domain 0, the default partition, Cyclone's default "
      "configuration, 3-D).")
      .def(py::init(&OpenConnection), py::arg("config") = py::none(), py::kw_only(),
           py::arg("domain") = py::none(), py::arg("partition") = py::none(),
           py::arg("cyclone_config") = py::none(), py::arg("dims") = py::none())
      .def_property_readonly("dims", [](const PyConnection& c) { return c.dims; })
      .def_property_readonly("partition", [](const PyConnection& c) { return c.partition; });

  py::class_<PyPublisher>(
      m, "Publisher",
      "Publishes a producer's boxes to the daemon. Publisher(connection, producer, *, "
      "write_timeout=5.0, restate_on_restart=False, double=None): producer 1..65535; ids are "
      "producer-local (below 2**48; events carry producer << 48 | id); double chooses float64 "
      "coordinates on the wire (default: the config's engine.coordinate). With "
      "restate_on_restart the publisher keeps what it published and states it again to a "
      "restarted daemon.")
      .def(py::init<std::shared_ptr<PyConnection>, uint32_t, double, bool, py::object>(),
           py::arg("connection").none(false), py::arg("producer"), py::kw_only(),
           py::arg("write_timeout") = 5.0, py::arg("restate_on_restart") = false,
           py::arg("double") = py::none())
      .def("wait_for_daemon", &PyPublisher::WaitForDaemon, py::arg("timeout") = 10.0,
           "Waits until the daemon's reader matched, so that no batch is lost to discovery.")
      .def("publish", &PyPublisher::Publish, py::kw_only(), py::arg("insert_ids") = py::none(),
           py::arg("insert_lo") = py::none(), py::arg("insert_hi") = py::none(),
           py::arg("category") = py::none(), py::arg("mask") = py::none(),
           py::arg("static") = py::none(), py::arg("update_ids") = py::none(),
           py::arg("update_lo") = py::none(), py::arg("update_hi") = py::none(),
           py::arg("erase_ids") = py::none(), py::arg("end_of_frame") = true,
           py::arg("frame") = py::none(),
           "Publishes one batch (the daemon applies its erases, then inserts, then updates) and "
           "returns its frame number (counted 1, 2, ... unless given). end_of_frame closes the "
           "frame: the daemon queries and publishes its events. Blocks at most write_timeout on "
           "a daemon that falls behind, then raises TimeoutError (the batch was not sent). "
           "Items the daemon refuses are reported on the status topic.")
      .def("wait_for_readers", &PyPublisher::WaitForReaders, py::arg("n"),
           py::arg("timeout") = 10.0, "Waits until n readers (the daemon, recorders, ...) matched.")
      .def("flush", &PyPublisher::Flush, py::arg("timeout") = 10.0,
           "Waits until every matched reader acknowledged what was published.")
      .def("maintain", &PyPublisher::Maintain,
           "With restate_on_restart: restates now if the daemon restarted (publish does it too).")
      .def_property_readonly("producer",
                             [](const PyPublisher& p) { return p.publisher().producer(); })
      .def_property_readonly("published",
                             [](const PyPublisher& p) { return p.publisher().published(); })
      .def_property_readonly("restates",
                             [](const PyPublisher& p) { return p.publisher().restates(); })
      .def_property_readonly("dims", &PyPublisher::dims);

  py::class_<PyEventSubscriber>(
      m, "EventSubscriber",
      "Receives the daemon's events: EventSubscriber(connection, depth=256, interest=0); with "
      "an interest id, that interest's stream only. poll(timeout) returns the EventParts "
      "received; parts() iterates over them.")
      .def(py::init<std::shared_ptr<PyConnection>, int32_t, uint64_t>(),
           py::arg("connection").none(false), py::arg("depth") = 256, py::arg("interest") = 0)
      .def("wait_for_daemon", &PyEventSubscriber::WaitForDaemon, py::arg("timeout") = 10.0)
      .def("poll", &PyEventSubscriber::Poll, py::arg("timeout") = 0.1,
           "The parts that arrive within timeout seconds (possibly none).")
      .def_property_readonly("gaps", &PyEventSubscriber::gaps,
                             "Parts missed (the subscriber fell more than depth behind).")
      .def_property_readonly("malformed", &PyEventSubscriber::malformed);

  py::class_<PyOverlapView>(
      m, "OverlapView",
      "The exact current overlap set (of the world, or of an interest), kept from the events "
      "with snapshots after a late join, a gap or a daemon restart. OverlapView(connection, "
      "depth=256, interest=0); call poll() regularly (it asks for snapshots when needed).")
      .def(py::init<std::shared_ptr<PyConnection>, int32_t, uint64_t>(),
           py::arg("connection").none(false), py::arg("depth") = 256, py::arg("interest") = 0)
      .def("wait_for_daemon", &PyOverlapView::WaitForDaemon, py::arg("timeout") = 10.0)
      .def("poll", &PyOverlapView::Poll, py::arg("timeout") = 0.1,
           "Applies what arrives within timeout; returns the parts applied.")
      .def("wait_synced", &PyOverlapView::WaitSynced, py::arg("timeout") = 10.0,
           "Polls until the view holds the daemon's set (TimeoutError otherwise).")
      .def("pairs", &PyOverlapView::Pairs,
           "The pairs, uint64[p, 2], sorted (empty while unsynced).")
      .def("contains",
           [](const PyOverlapView& v, uint64_t a, uint64_t b) { return v.view().Contains(a, b); })
      .def("__len__", [](const PyOverlapView& v) { return v.view().size(); })
      .def_property_readonly("synced", [](const PyOverlapView& v) { return v.view().synced(); })
      .def_property_readonly("frame", [](const PyOverlapView& v) { return v.view().frame(); })
      .def_property_readonly("epoch", [](const PyOverlapView& v) { return v.view().epoch(); })
      .def_property_readonly("resyncs", [](const PyOverlapView& v) { return v.view().resyncs(); })
      .def_property_readonly("snapshots",
                             [](const PyOverlapView& v) { return v.view().snapshots(); })
      .def_property_readonly("last_loss",
                             [](const PyOverlapView& v) { return v.view().last_loss(); })
      .def_property_readonly("gaps", [](const PyOverlapView& v) { return v.events().gaps(); });

  py::class_<PyStatusSubscriber>(
      m, "StatusSubscriber",
      "The daemon's status reports (health, objects, frame times, rejections, interests) as "
      "dicts with the schema's field names.")
      .def(py::init<std::shared_ptr<PyConnection>, int32_t>(), py::arg("connection").none(false),
           py::arg("depth") = 16)
      .def("poll", &PyStatusSubscriber::Poll, py::arg("timeout") = 0.1,
           "The reports that arrive within timeout seconds.");

  py::class_<PyInterestClient>(
      m, "InterestClient",
      "Declares interests (only the events one needs) and asks spot queries. Receive an "
      "interest's events with EventSubscriber or OverlapView(connection, interest=id).")
      .def(py::init<std::shared_ptr<PyConnection>>(), py::arg("connection").none(false))
      .def("wait_for_daemon", &PyInterestClient::WaitForDaemon, py::arg("timeout") = 10.0)
      .def("declare", &PyInterestClient::Declare, py::kw_only(), py::arg("regions_lo") = py::none(),
           py::arg("regions_hi") = py::none(), py::arg("leave_margin") = 0.0,
           py::arg("pairs_inside") = false, py::arg("keys") = py::none(),
           py::arg("producers") = py::none(), py::arg("category_mask") = 0,
           py::arg("id") = py::none(),
           "Declares an interest (or changes it: the same id) and returns its id: regions "
           "[r, dims] (region-object pairs; with pairs_inside also the pairs inside a region; "
           "leave_margin: objects leave only beyond it), keys (global), producers, "
           "category_mask. Refusals arrive on the status topic (maintain()).")
      .def("drop", &PyInterestClient::Drop, py::arg("id"))
      .def("maintain", &PyInterestClient::Maintain,
           "Reads the daemon's reports: declares the interests again after a daemon restart or "
           "a drop; returns the refusals of this client's declarations (dicts).")
      .def("query", &PyInterestClient::Query, py::arg("lo"), py::arg("hi"),
           py::arg("timeout") = 5.0,
           "The keys whose boxes overlap [lo, hi] as of the daemon's last frame, sorted, and "
           "that frame: (uint64[k], frame).")
      .def_property_readonly("id", &PyInterestClient::id);

  py::class_<PyRecording>(
      m, "Recording",
      "A recording of the update stream (bpctl record), read front to back: each batch as a "
      "dict of arrays (insert_ids, insert_lo, insert_hi, category, mask, static, update_ids, "
      "update_lo, update_hi, erase_ids) and fields (time_ns, producer, frame, end_of_frame, "
      "dim, batch_seq, sent_time_ns, restate; malformed: True with the payload if it does not "
      "parse). Iterate over it, or over frames() for the batches grouped by end of frame.")
      .def(py::init<const std::string&>(), py::arg("path"))
      .def("next", &PyRecording::Next, "The next batch, or None at the end.")
      .def_property_readonly("header", &PyRecording::Header)
      .def_property_readonly("batches", &PyRecording::batches);
}

}  // namespace bp::python
