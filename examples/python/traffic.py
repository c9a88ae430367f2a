#!/usr/bin/python3
"""Traffic on a ring of lanes: a few thousand cars as a producer of broadphased, reacting to its
collide events.

Each car drives along its lane (x grows, wrapping at the ring's length) and publishes its box
every step. The daemon's events say which boxes touch: a car whose box touches another's brakes
hard for a moment, and one that touches nothing speeds back up towards its own cruising speed.
Cars change lanes now and then, so they meet. Every update and every reaction is an array
operation: no per-car Python loop.

Run a daemon, then this (scripts/python puts the package on the path):

    build/release/service/broadphased --config config/broadphased.yaml &
    scripts/python examples/python/traffic.py --config config/broadphased.yaml --seconds 20

It prints a line a second: cars, touching pairs, braking cars, mean speed, update->event
latency. A 2-D daemon gets 2-D boxes; a 3-D one gets the same boxes with z in [0, 1].
"""

import argparse
import sys
import time

import numpy as np

import broadphase


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="config/broadphased.yaml", help="the daemon's YAML file")
    p.add_argument("--cars", type=int, default=3000)
    p.add_argument("--lanes", type=int, default=60)
    p.add_argument("--rate", type=float, default=30.0, help="steps per second")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--producer", type=int, default=7)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()

    conn = broadphase.Connection(args.config)
    dims = conn.dims
    publisher = broadphase.Publisher(conn, args.producer)
    events = broadphase.EventSubscriber(conn)
    publisher.wait_for_daemon(10)
    events.wait_for_daemon(10)

    rng = np.random.default_rng(args.seed)
    n = args.cars
    length = 25.0 * n / args.lanes          # ring length: about one car per 25 m of lane
    ids = np.arange(n, dtype=np.uint64)
    x = rng.uniform(0, length, n)
    lane = rng.integers(0, args.lanes, n).astype(np.float64)
    cruise = rng.uniform(10, 30, n)         # m/s
    speed = cruise.copy()
    braking = np.zeros(n)                   # seconds of braking left
    car = np.array([4.5, 1.8])              # length, width
    dt = 1.0 / args.rate
    key_of = np.uint64(args.producer) << np.uint64(48)

    def boxes():
        lo = np.stack([x, lane * 3.5 + 0.85], axis=1)
        hi = lo + car
        if dims == 3:
            lo = np.concatenate([lo, np.zeros((n, 1))], axis=1)
            hi = np.concatenate([hi, np.ones((n, 1))], axis=1)
        return lo, hi

    lo, hi = boxes()
    publisher.publish(insert_ids=ids, insert_lo=lo, insert_hi=hi)
    touching = 0
    latency_ms = []
    start = last_print = time.monotonic()
    step = 0
    try:
        while time.monotonic() - start < args.seconds:
            # React to the events received: both cars of a new pair brake for a second.
            for part in events.poll(0):
                if part.snapshot or part.source_producer != args.producer:
                    continue
                pairs = part.collides
                touching += len(pairs) - len(part.uncollides)
                if len(pairs):
                    mine = pairs[(pairs >> np.uint64(48)) == np.uint64(args.producer)]
                    hit = (mine & ~key_of).astype(np.int64).ravel()
                    braking[hit[hit < n]] = 1.0
                if part.last_part and part.source_sent_time_ns:
                    latency_ms.append((time.time_ns() - part.source_sent_time_ns) / 1e6)
            # Drive: brake, or accelerate back to cruise; change lanes now and then.
            braking = np.maximum(braking - dt, 0)
            target = np.where(braking > 0, cruise * 0.3, cruise)
            speed += np.clip(target - speed, -8 * dt, 3 * dt)
            x = (x + speed * dt) % length
            change = rng.random(n) < 0.02 * dt
            lane = np.where(change, (lane + rng.choice([-1, 1], n)) % args.lanes, lane)
            lo, hi = boxes()
            publisher.publish(update_ids=ids, update_lo=lo, update_hi=hi)
            step += 1
            now = time.monotonic()
            if now - last_print >= 1.0:
                lat = f"{np.median(latency_ms):.1f} ms" if latency_ms else "-"
                print(f"step {step}: {n} cars, {touching} touching pairs, "
                      f"{int((braking > 0).sum())} braking, mean speed {speed.mean():.1f} m/s, "
                      f"update->event {lat}", flush=True)
                latency_ms.clear()
                last_print = now
            time.sleep(max(0.0, start + step * dt - time.monotonic()))
    except KeyboardInterrupt:
        pass
    publisher.publish(erase_ids=ids)
    publisher.flush(5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
