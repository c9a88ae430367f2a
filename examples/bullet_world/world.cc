#include "world.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <unordered_set>
#include <utility>

#include <btBulletDynamicsCommon.h>

namespace bp::examples {
namespace {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// The daemon receives the boxes as float: Bullet must compute them in float too.
static_assert(sizeof(btScalar) == sizeof(float), "bullet_world needs single-precision Bullet");

constexpr float kStep = 1.0f / 60.0f;
// Ids stay below 2^32: pairs are keyed (a << 32 | b). Spawning stops there.
constexpr uint64_t kIdLimit = uint64_t{1} << 32;
// Spawn cells are this far apart, more than the widest box a body can have (a box of half
// extents 0.5 turned diagonally), so that bodies never spawn inside each other.
constexpr float kCell = 1.8f;
// A cell is used again only after this many steps: by then the body spawned there has fallen
// more than a cell (it starts at 4 m/s downwards).
constexpr uint32_t kCellReuseSteps = 12;

// Bullet's world with its broadphase timed: updateAabbs (every body's AABB, and the
// broadphase's structure with them) and computeOverlappingPairs (the pair cache).
class TimedWorld final : public btDiscreteDynamicsWorld {
 public:
  using btDiscreteDynamicsWorld::btDiscreteDynamicsWorld;
  void updateAabbs() override {
    const auto start = Clock::now();
    btDiscreteDynamicsWorld::updateAabbs();
    broadphase_ms_ += MsSince(start);
  }
  void computeOverlappingPairs() override {
    const auto start = Clock::now();
    btDiscreteDynamicsWorld::computeOverlappingPairs();
    broadphase_ms_ += MsSince(start);
  }
  double TakeBroadphaseMs() { return std::exchange(broadphase_ms_, 0.0); }

 private:
  double broadphase_ms_ = 0;
};

BodyBox BoxOf(const btRigidBody& body, uint64_t id, bool is_static) {
  const btBroadphaseProxy* proxy = body.getBroadphaseHandle();
  BodyBox box;
  box.id = id;
  box.is_static = is_static;
  for (int a = 0; a < 3; ++a) {
    box.lo[static_cast<size_t>(a)] = proxy->m_aabbMin[a];
    box.hi[static_cast<size_t>(a)] = proxy->m_aabbMax[a];
  }
  return box;
}

bool SameBox(const BodyBox& a, const BodyBox& b) { return a.lo == b.lo && a.hi == b.hi; }

// A horizontal lattice of spawn cells around (x, z), `per_side` cells a side, in `layers`
// layers from height y0 up.
void AddCells(float x, float z, int per_side, int layers, float y0,
              std::vector<std::array<float, 3>>* out) {
  const float first = -0.5f * kCell * static_cast<float>(per_side - 1);
  for (int k = 0; k < layers; ++k) {
    for (int i = 0; i < per_side; ++i) {
      for (int j = 0; j < per_side; ++j) {
        out->push_back({x + first + kCell * static_cast<float>(i),
                        y0 + kCell * static_cast<float>(k),
                        z + first + kCell * static_cast<float>(j)});
      }
    }
  }
}

}  // namespace

struct BulletWorld::Body {
  std::unique_ptr<btRigidBody> rigid;
  uint64_t id = 0;
  bool is_static = false;
  bool sent = false;  // the daemon has the body (its insert was listed)
  uint64_t born = 0;  // the step that spawned it
  BodyBox last;       // the box last listed
};

BulletWorld::BulletWorld(const WorldOptions& options)
    : options_(options),
      random_(options.seed),
      config_(std::make_unique<btDefaultCollisionConfiguration>()),
      dispatcher_(std::make_unique<btCollisionDispatcher>(config_.get())),
      broadphase_(std::make_unique<btDbvtBroadphase>()),
      solver_(std::make_unique<btSequentialImpulseConstraintSolver>()) {
  world_ = std::make_unique<TimedWorld>(dispatcher_.get(), broadphase_.get(), solver_.get(),
                                        config_.get());
  world_->setGravity(btVector3(0, -9.81f, 0));
  world_->getSolverInfo().m_numIterations = options_.solver_iterations;

  // Shapes shared by the bodies: spheres of 8 radii, boxes of 4 x 4 x 4 half extents.
  const std::array<float, 4> halves = {0.15f, 0.25f, 0.35f, 0.5f};
  for (int r = 0; r < 8; ++r) {
    shapes_.push_back(std::make_unique<btSphereShape>(0.15f + 0.05f * static_cast<float>(r)));
  }
  for (float x : halves) {
    for (float y : halves) {
      for (float z : halves) shapes_.push_back(std::make_unique<btBoxShape>(btVector3(x, y, z)));
    }
  }

  // About 2 bodies per square metre once poured in, in bins of 4 m: heaps a body or two deep,
  // in islands small enough to fall asleep within seconds (one moving body keeps its whole
  // island awake).
  side_ = std::max(10.0, std::sqrt(static_cast<double>(options_.bodies) / 2.0));
  const auto half = static_cast<float>(side_ / 2);
  const int bins = std::max(1, static_cast<int>(std::lround(side_ / 4.0)));
  const float bin = static_cast<float>(side_) / static_cast<float>(bins);
  AddStatic({0, -0.5f, 0}, {half + 1, 0.5f, half + 1});  // the ground
  for (float sign : {-1.0f, 1.0f}) {                     // outer walls, high enough to hold all
    AddStatic({sign * (half + 0.25f), 3, 0}, {0.25f, 3, half + 0.5f});
    AddStatic({0, 3, sign * (half + 0.25f)}, {half + 0.5f, 3, 0.25f});
  }
  for (int i = 1; i < bins; ++i) {  // the bins' walls
    const float at = -half + bin * static_cast<float>(i);
    AddStatic({at, 1.25f, 0}, {0.15f, 1.25f, half});
    AddStatic({0, 1.25f, at}, {half, 1.25f, 0.15f});
  }

  // The pour: cells over the whole floor, as many layers as keep each cell free for
  // kCellReuseSteps steps at the fill rate.
  fill_rate_ =
      (options_.bodies + std::max(1u, options_.fill_steps) - 1) / std::max(1u, options_.fill_steps);
  const int per_side = std::max(1, static_cast<int>((side_ - 1.0) / kCell));
  const int fill_layers =
      std::max<int>(1, static_cast<int>((kCellReuseSteps * fill_rate_ +
                                         static_cast<uint32_t>(per_side * per_side) - 1) /
                                        static_cast<uint32_t>(per_side * per_side)));
  AddCells(0, 0, per_side, fill_layers, 7, &fill_cells_);
  // The stream: spouts of 6 x 6 cells (three bins a side) along the diagonal, each fed at most
  // 4 bodies a step, in as many layers as keep each cell free for kCellReuseSteps steps.
  if (options_.stream > 0) {
    const uint32_t spouts = (options_.stream + 3) / 4;
    const uint32_t layers = (kCellReuseSteps * options_.stream + spouts * 36 - 1) / (spouts * 36);
    for (uint32_t s = 0; s < spouts; ++s) {
      const float at = -half + static_cast<float>(side_) * (static_cast<float>(s) + 0.5f) /
                                   static_cast<float>(spouts);
      AddCells(at, at, 6, static_cast<int>(layers), 8, &spout_cells_);
    }
  }
  std::shuffle(fill_cells_.begin(), fill_cells_.end(), random_);
  std::shuffle(spout_cells_.begin(), spout_cells_.end(), random_);
}

BulletWorld::~BulletWorld() {
  // Bullet's world refers to its bodies until they are removed from it.
  for (auto& b : statics_) world_->removeRigidBody(b->rigid.get());
  for (auto& b : dynamics_) world_->removeRigidBody(b->rigid.get());
  for (auto& b : streamed_) world_->removeRigidBody(b->rigid.get());
}

void BulletWorld::AddStatic(const std::array<float, 3>& center, const std::array<float, 3>& half) {
  shapes_.push_back(std::make_unique<btBoxShape>(btVector3(half[0], half[1], half[2])));
  btTransform at;
  at.setIdentity();
  at.setOrigin(btVector3(center[0], center[1], center[2]));
  btRigidBody::btRigidBodyConstructionInfo info(0, nullptr, shapes_.back().get());
  info.m_startWorldTransform = at;
  info.m_friction = 0.8f;
  auto body = std::make_unique<Body>();
  body->rigid = std::make_unique<btRigidBody>(info);
  body->id = next_id_++;
  body->is_static = true;
  body->rigid->setUserPointer(body.get());
  world_->addRigidBody(body->rigid.get());
  statics_.push_back(std::move(body));
}

void BulletWorld::Spawn(const std::array<float, 3>& at, bool streamed) {
  std::uniform_real_distribution<float> unit(0, 1);
  // Half spheres, half boxes (any of the box shapes), turned at random.
  const size_t shape_index = unit(random_) < 0.5f
                                 ? static_cast<size_t>(unit(random_) * 7.999f)
                                 : 8 + static_cast<size_t>(unit(random_) * 63.999f);
  btCollisionShape* shape = shapes_[shape_index].get();
  btTransform pose;
  pose.setIdentity();
  pose.setOrigin(btVector3(at[0], at[1], at[2]));
  btQuaternion turn(btVector3(unit(random_) - 0.5f, unit(random_) - 0.5f, unit(random_) - 0.5f),
                    unit(random_) * 6.283f);
  if (shape_index >= 8) pose.setRotation(turn.normalized());
  btVector3 lo, hi;
  shape->getAabb(btTransform::getIdentity(), lo, hi);
  const btVector3 size = hi - lo;
  const btScalar mass = 500 * size.x() * size.y() * size.z();  // density 500 kg/m3, about
  btVector3 inertia(0, 0, 0);
  shape->calculateLocalInertia(mass, inertia);
  btRigidBody::btRigidBodyConstructionInfo info(mass, nullptr, shape, inertia);
  info.m_startWorldTransform = pose;
  info.m_friction = 0.6f;
  info.m_restitution = 0.1f;
  // Rolling friction and damping let spheres and piles come to rest (and fall asleep).
  info.m_rollingFriction = 0.1f;
  info.m_spinningFriction = 0.1f;
  info.m_linearDamping = 0.1f;
  info.m_angularDamping = 0.5f;
  auto body = std::make_unique<Body>();
  body->rigid = std::make_unique<btRigidBody>(info);
  body->rigid->setLinearVelocity(btVector3(unit(random_) - 0.5f, -4, unit(random_) - 0.5f));
  body->id = next_id_++;
  body->born = step_;
  body->rigid->setUserPointer(body.get());
  world_->addRigidBody(body->rigid.get());
  (streamed ? streamed_ : dynamics_).push_back(std::move(body));
}

void BulletWorld::Remove(std::unique_ptr<Body> body) {
  world_->removeRigidBody(body->rigid.get());
  if (body->sent) erased_.push_back(body->id);
}

StepStats BulletWorld::Step() {
  StepStats stats;
  std::vector<std::unique_ptr<Body>> doomed;
  ++step_;
  // Bodies that left the world over a wall's top (rare) fall for ever: removed.
  for (auto* bodies : {&dynamics_, &streamed_}) {
    for (auto it = bodies->begin(); it != bodies->end();) {
      if ((*it)->rigid->getWorldTransform().getOrigin().y() < -20) {
        doomed.push_back(std::move(*it));
        it = bodies->erase(it);
      } else {
        ++it;
      }
    }
  }
  while (!streamed_.empty() && streamed_.front()->born + options_.lifetime <= step_) {
    doomed.push_back(std::move(streamed_.front()));
    streamed_.pop_front();
  }
  uint32_t spawn = 0;
  bool streamed = false;
  if (poured_ < options_.bodies) {
    spawn = std::min(fill_rate_, options_.bodies - poured_);
    poured_ += spawn;
  } else {
    spawn = options_.stream;
    streamed = true;
  }
  if (!doomed.empty()) {
    // Bullet leaves the bodies that rested on a removed one asleep, in the air: wake those in
    // contact with it, as a simulator that removes bodies does.
    std::unordered_set<const btCollisionObject*> gone;
    for (const auto& b : doomed) gone.insert(b->rigid.get());
    for (int i = 0; i < dispatcher_->getNumManifolds(); ++i) {
      const btPersistentManifold* m = dispatcher_->getManifoldByIndexInternal(i);
      const bool first = gone.count(m->getBody0()) != 0, second = gone.count(m->getBody1()) != 0;
      if (first != second) {
        (first ? m->getBody1() : m->getBody0())->activate();
      }
    }
    stats.removed = static_cast<uint32_t>(doomed.size());
    for (auto& b : doomed) Remove(std::move(b));
  }
  spawn = static_cast<uint32_t>(std::min<uint64_t>(spawn, kIdLimit - next_id_));
  for (uint32_t i = 0; i < spawn; ++i) {
    if (streamed) {
      Spawn(spout_cells_[next_spout_++ % spout_cells_.size()], true);
    } else {
      Spawn(fill_cells_[next_fill_++ % fill_cells_.size()], false);
    }
  }
  stats.spawned = spawn;
  const auto start = Clock::now();
  world_->stepSimulation(kStep, 0);  // one step of exactly kStep
  stats.step_ms = MsSince(start);
  stats.broadphase_ms = static_cast<TimedWorld*>(world_.get())->TakeBroadphaseMs();
  return stats;
}

void BulletWorld::Clear() {
  for (auto& b : statics_) Remove(std::move(b));
  for (auto& b : dynamics_) Remove(std::move(b));
  for (auto& b : streamed_) Remove(std::move(b));
  statics_.clear();
  dynamics_.clear();
  streamed_.clear();
}

void BulletWorld::TakeChanges(WorldChanges* out) {
  out->inserts.clear();
  out->updates.clear();
  out->erases.swap(erased_);
  erased_.clear();
  auto list = [&](Body& b) {
    const BodyBox box = BoxOf(*b.rigid, b.id, b.is_static);
    if (!b.sent) {
      out->inserts.push_back(box);
    } else if (!SameBox(box, b.last)) {
      out->updates.push_back(box);
    } else {
      return;
    }
    b.sent = true;
    b.last = box;
  };
  for (auto& b : statics_) list(*b);
  for (auto& b : dynamics_) list(*b);
  for (auto& b : streamed_) list(*b);
}

void BulletWorld::ExactPairs(std::vector<uint64_t>* out) const {
  out->clear();
  const btBroadphasePairArray& pairs = world_->getPairCache()->getOverlappingPairArray();
  for (int i = 0; i < pairs.size(); ++i) {
    const btBroadphaseProxy* p = pairs[i].m_pProxy0;
    const btBroadphaseProxy* q = pairs[i].m_pProxy1;
    bool overlap = true;
    for (int a = 0; a < 3; ++a) {
      overlap = overlap && p->m_aabbMin[a] <= q->m_aabbMax[a] && q->m_aabbMin[a] <= p->m_aabbMax[a];
    }
    if (!overlap) continue;
    const auto* x = static_cast<const Body*>(
        static_cast<const btCollisionObject*>(p->m_clientObject)->getUserPointer());
    const auto* y = static_cast<const Body*>(
        static_cast<const btCollisionObject*>(q->m_clientObject)->getUserPointer());
    const uint64_t a = std::min(x->id, y->id), b = std::max(x->id, y->id);
    out->push_back(a << 32 | b);
  }
  std::sort(out->begin(), out->end());
}

size_t BulletWorld::awake() const {
  auto awake = [](const auto& b) { return b->rigid->isActive(); };
  return static_cast<size_t>(std::count_if(dynamics_.begin(), dynamics_.end(), awake) +
                             std::count_if(streamed_.begin(), streamed_.end(), awake));
}

}  // namespace bp::examples
