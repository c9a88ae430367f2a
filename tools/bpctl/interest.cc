// bpctl's interests: the interest a watch declares (--region, --key, --producer, --category) and
// bpctl query (a spot query).
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <sstream>

#include "common.h"
#include "engine_host.h"

#include "bp/client/interests.h"

namespace bp::bpctl {
namespace {

bool ParseNumbers(const std::string& text, std::vector<double>* out) {
  out->clear();
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || end != item.c_str() + item.size() || errno != 0 || !std::isfinite(v)) {
      return false;
    }
    out->push_back(v);
  }
  return true;
}

}  // namespace

bool ParseBox(const std::string& text, std::vector<double>* lo, std::vector<double>* hi,
              std::string* error) {
  std::vector<double> v;
  if (!ParseNumbers(text, &v) || (v.size() != 4 && v.size() != 6)) {
    *error = "'" + text + "' is not a box: x0,y0,x1,y1 (2-D) or x0,y0,z0,x1,y1,z1 (3-D), finite";
    return false;
  }
  const size_t k = v.size() / 2;
  lo->assign(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k));
  hi->assign(v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  for (size_t a = 0; a < k; ++a) {
    if ((*lo)[a] > (*hi)[a]) {
      *error = "'" + text + "': lo > hi on axis " + std::to_string(a);
      return false;
    }
  }
  return true;
}

bool BuildInterest(const WatchOptions& options, wire::Interest* out, std::string* error) {
  out->Clear();
  if (options.regions.empty() && options.keys.empty() && options.producers.empty() &&
      options.category_mask == 0) {
    if (options.leave_margin != 0 || options.pairs_inside) {
      *error = "--leave-margin and --pairs-inside need a --region";
      return false;
    }
    return true;  // the whole world
  }
  if (!std::isfinite(options.leave_margin) || options.leave_margin < 0) {
    *error = "--leave-margin must be finite and >= 0";
    return false;
  }
  if ((options.leave_margin != 0 || options.pairs_inside) && options.regions.empty()) {
    *error = "--leave-margin and --pairs-inside need a --region";
    return false;
  }
  std::vector<double> lo, hi;
  for (const std::string& r : options.regions) {
    if (!ParseBox(r, &lo, &hi, error)) {
      *error = "--region " + *error;
      return false;
    }
    if (out->dim() != 0 && out->dim() != lo.size()) {
      *error = "--region '" + r + "' has another dimension than the first region";
      return false;
    }
    out->set_dim(static_cast<uint32_t>(lo.size()));
    out->mutable_region_lo()->Add(lo.begin(), lo.end());
    out->mutable_region_hi()->Add(hi.begin(), hi.end());
  }
  out->set_leave_margin(options.leave_margin);
  out->set_pairs_inside(options.pairs_inside);
  for (const std::string& k : options.keys) {
    const size_t colon = k.find(':');
    uint64_t producer = 0, id = 0;
    const char* end = k.data() + k.size();
    if (colon == std::string::npos ||
        std::from_chars(k.data(), k.data() + colon, producer).ptr != k.data() + colon ||
        std::from_chars(k.data() + colon + 1, end, id).ptr != end || producer == 0 ||
        producer > 65535 || id >= service::kLocalIdLimit) {
      *error = "--key '" + k + "' is not producer:id (producer 1..65535, id < 2^48)";
      return false;
    }
    out->add_keys(service::GlobalKey(static_cast<uint32_t>(producer), id));
  }
  for (uint32_t p : options.producers) out->add_producers(p);
  out->set_category_mask(options.category_mask);
  out->set_id(client::InterestClient::NewInterestId());
  return true;
}

int Query(const Common& common, const QueryOptions& options) {
  std::vector<double> lo, hi;
  std::string error;
  if (!ParseBox(options.box, &lo, &hi, &error)) {
    std::fprintf(stderr, "bpctl query: --box %s\n", error.c_str());
    return 2;
  }
  auto connection = Connect(common);
  if (!connection) return 1;
  std::unique_ptr<client::InterestClient> interests;
  if (Status s = client::InterestClient::Create(*connection, &interests); !s.ok()) {
    std::fprintf(stderr, "bpctl query: %s\n", s.ToString().c_str());
    return 1;
  }
  if (Status s = WaitInterruptibly(
          common.wait_s, [&](std::chrono::milliseconds t) { return interests->WaitForDaemon(t); });
      !s.ok()) {
    std::fprintf(stderr, "bpctl query: no daemon on domain %u partition '%s' (%s)\n",
                 common.config.dds.domain, common.config.dds.partition.c_str(),
                 s.ToString().c_str());
    return 1;
  }
  std::vector<uint64_t> keys;
  uint64_t frame = 0;
  const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(options.timeout_s * 1000));
  if (Status s = interests->Query(lo, hi, timeout, &keys, &frame); !s.ok()) {
    std::fprintf(stderr, "bpctl query: %s\n", s.ToString().c_str());
    return 1;
  }
  for (uint64_t key : keys) std::printf("%s\n", KeyName(key).c_str());
  std::fflush(stdout);
  std::fprintf(stderr, "bpctl query: %zu object%s overlap the box at frame %llu\n", keys.size(),
               keys.size() == 1 ? "" : "s", static_cast<unsigned long long>(frame));
  return 0;
}

}  // namespace bp::bpctl
