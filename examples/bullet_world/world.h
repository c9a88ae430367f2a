// A Bullet rigid-body world, as a simulator beside broadphased runs one: static ground and the
// walls of a grid of bins, then boxes and spheres of mixed sizes poured into the bins, then a
// steady stream of new bodies from spouts above a few bins, each streamed body removed a while
// after it was spawned. Bodies that come to rest fall asleep (Bullet's deactivation) and keep
// their boxes: once the pour has settled, most of the world rests and the spouts' bins move.
//
// Every body has a producer-local id that is never reused, below 2^32 (spawning stops there).
// After each Step:
// - TakeChanges lists what changed since the previous call as the daemon must see it: inserts
//   (bodies added, static geometry flagged static), updates (bodies whose box changed, bit for
//   bit) and erases (bodies removed). A box is the body's broadphase AABB: the box Bullet's own
//   broadphase used in that step (the shape's AABB widened by the contact breaking threshold and
//   joined with the predicted motion).
// - ExactPairs lists the pairs of overlapping boxes according to Bullet: the pairs its
//   broadphase's pair cache holds (a superset: the cache keeps pairs of fattened boxes, and
//   removes stale ones a few at a time), filtered by the exact closed box test on the same boxes.
//   Bullet never pairs two static bodies, nor does the daemon.
//
// Thread safety: none; one thread.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <random>
#include <vector>

class btBroadphaseInterface;
class btCollisionDispatcher;
class btCollisionShape;
class btDefaultCollisionConfiguration;
class btDiscreteDynamicsWorld;
class btRigidBody;
class btSequentialImpulseConstraintSolver;

namespace bp::examples {

struct WorldOptions {
  /// Dynamic bodies poured in at the start.
  uint32_t bodies = 5000;
  /// Steps over which they are poured in.
  uint32_t fill_steps = 120;
  /// Bodies spawned from the spouts per step once the pour is done (0: none).
  uint32_t stream = 4;
  /// Steps a streamed body lives before it is removed.
  uint32_t lifetime = 180;
  /// Seeds the sizes, shapes and spawn order (Bullet itself is deterministic).
  uint64_t seed = 1;
  /// Bullet's constraint solver iterations per step.
  int solver_iterations = 10;
};

/// A box as the daemon receives it (float corners, as Bullet's single precision has them).
struct BodyBox {
  uint64_t id = 0;
  std::array<float, 3> lo{}, hi{};
  bool is_static = false;
};

/// What changed since the previous TakeChanges.
struct WorldChanges {
  std::vector<BodyBox> inserts;
  std::vector<BodyBox> updates;
  std::vector<uint64_t> erases;
};

/// What one Step did and cost.
struct StepStats {
  uint32_t spawned = 0, removed = 0;
  double step_ms = 0;        ///< the whole stepSimulation call
  double broadphase_ms = 0;  ///< Bullet's broadphase in it: AABB updates and pair finding
};

class BulletWorld {
 public:
  explicit BulletWorld(const WorldOptions& options);
  ~BulletWorld();
  BulletWorld(const BulletWorld&) = delete;
  BulletWorld& operator=(const BulletWorld&) = delete;

  /// Removes the bodies due (oldest, fallen out), spawns new ones, and steps 1/60 s.
  StepStats Step();
  /// Removes every body, static geometry included (the next TakeChanges erases them all).
  void Clear();
  /// The changes since the previous call (the first call lists the static geometry too).
  void TakeChanges(WorldChanges* out);
  /// The overlapping pairs after the last Step, each as (a << 32 | b) with ids a < b, sorted.
  void ExactPairs(std::vector<uint64_t>* out) const;
  /// Bodies in the world, static geometry included.
  size_t bodies() const { return statics_.size() + dynamics_.size() + streamed_.size(); }
  /// Dynamic bodies awake (not deactivated) after the last Step.
  size_t awake() const;
  /// The world's extent on x and z (the ground is y = 0, up is +y).
  double side() const { return side_; }

 private:
  struct Body;
  struct Shape;
  void AddStatic(const std::array<float, 3>& center, const std::array<float, 3>& half);
  void Spawn(const std::array<float, 3>& at, bool streamed);
  void Remove(std::unique_ptr<Body> body);

  WorldOptions options_;
  double side_ = 0;
  std::mt19937_64 random_;
  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btBroadphaseInterface> broadphase_;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver_;
  std::unique_ptr<btDiscreteDynamicsWorld> world_;
  std::vector<std::unique_ptr<btCollisionShape>> shapes_;
  std::vector<std::unique_ptr<Body>> statics_;
  std::deque<std::unique_ptr<Body>> dynamics_;  // poured in
  std::deque<std::unique_ptr<Body>> streamed_;  // from the spouts, oldest first
  uint64_t step_ = 0;
  std::vector<std::array<float, 3>> fill_cells_, spout_cells_;
  size_t next_fill_ = 0, next_spout_ = 0;
  uint32_t fill_rate_ = 0;  // bodies poured per step until `bodies` are in
  uint32_t poured_ = 0;
  uint64_t next_id_ = 1;
  std::vector<uint64_t> erased_;  // ids removed since the last TakeChanges, as sent before
};

}  // namespace bp::examples
