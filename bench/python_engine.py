#!/usr/bin/python3
"""The Python package's engine against the C++ bpbench, and against what a Python user would
otherwise use, on the scenes of docs/WORKLOADS.md.

  bench/python_engine.py [--scenarios S1-100k,S1-200k] [--frames 60] [--rounds 3]
                         [--peer-frames 5] [--build build/release] [--out FILE]

Two measurements, one JSON line each (also appended to --out):
  - "engine": per scene, alternating rounds of broadphase.Engine("grid_dense") driven from Python
    with the scene's arrays (erase, update, insert, query per frame, timed together; the scene is
    generated before the clock starts) and of bpbench on the same scene and frames, both pinned
    to the same CPU; the median frame of each and the ratio python/C++ per round.
  - "peers": per scene, in this one process, frames per second of the engine, of rtree
    (libspatialindex: the moved, erased and inserted boxes deleted and reinserted, then the moved
    and inserted ones queried again, one call per box; "rtree_rebuild": the index bulk-loaded
    anew each frame instead, then the same queries) and of scipy's cKDTree (rebuilt on the
    box centres each frame, query_pairs with the largest width under the max-norm, then the
    exact box test and the difference with the last frame's pairs, all in numpy). Every peer's
    pair set is compared with the engine's after its last frame ("exact").
The package is imported from <build>/python; bpbench is <build>/bench/bpbench.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np


def pin_cpu():
    cpus = sorted(os.sched_getaffinity(0))
    cpu = cpus[-1]
    os.sched_setaffinity(0, {cpu})
    return cpu


def frames_of(broadphase, name, frames):
    scene = broadphase.Scene(name)
    initial = scene.initial()
    return initial, [scene.next_frame() for _ in range(frames)]


def run_engine(broadphase, initial, frames):
    """Median frame time (ms) of the engine over frames, and the engine after them."""
    engine = broadphase.Engine("grid_dense", dims=initial[1].shape[1], dtype="float32")
    engine.insert(*initial)
    engine.query()
    times = []
    for f in frames:
        t0 = time.perf_counter()
        engine.erase(f["erase"])
        engine.update(f["update_keys"], f["update_lo"], f["update_hi"])
        engine.insert(f["insert_keys"], f["insert_lo"], f["insert_hi"])
        engine.query()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), engine


def run_bpbench(bpbench, name, frames, cpu):
    out = subprocess.run(["taskset", "-c", str(cpu), bpbench, "-s", name, "-e", "grid_dense",
                          "-f", str(frames), "-r", "1"],
                         check=True, capture_output=True, text=True).stdout
    row = json.loads(out.strip().splitlines()[-1])
    return row["median_ms"]


class RtreePeer:
    """An rtree index of every box; per frame the changed boxes are deleted and reinserted, then
    each moved or inserted box is queried and its partners compared with the last ones."""

    def __init__(self, keys, lo, hi, pairs):
        from rtree import index
        prop = index.Property()
        prop.dimension = lo.shape[1]
        self.box = {int(k): tuple(lo[i].tolist()) + tuple(hi[i].tolist())
                    for i, k in enumerate(keys)}
        self.index = index.Index(((k, b, None) for k, b in self.box.items()), properties=prop)
        self.partners = {k: set() for k in self.box}
        for a, b in pairs.tolist():
            self.partners[a].add(b)
            self.partners[b].add(a)

    def frame(self, f):
        collides, uncollides = [], []
        self._erase(f, uncollides, delete=True)
        changed = []
        for keys, lo, hi in ((f["update_keys"], f["update_lo"], f["update_hi"]),
                             (f["insert_keys"], f["insert_lo"], f["insert_hi"])):
            for i, k in enumerate(keys.tolist()):
                if k in self.box:
                    self.index.delete(k, self.box[k])
                else:
                    self.partners[k] = set()
                self.box[k] = tuple(lo[i].tolist()) + tuple(hi[i].tolist())
                self.index.insert(k, self.box[k])
                changed.append(k)
        self._requery(changed, collides, uncollides)
        return collides, uncollides

    def _erase(self, f, uncollides, delete):
        """The erased boxes out of the partner sets (and of the index, if delete)."""
        for k in f["erase"].tolist():
            box = self.box.pop(k)
            if delete:
                self.index.delete(k, box)
            for x in self.partners.pop(k):
                self.partners[x].discard(k)
                uncollides.append((min(k, x), max(k, x)))

    def _requery(self, changed, collides, uncollides):
        """Each changed box queried again; its partners' differences are the events."""
        for k in changed:
            now = set(self.index.intersection(self.box[k]))
            now.discard(k)
            then = self.partners[k]
            for x in now - then:
                self.partners[x].add(k)
                collides.append((min(k, x), max(k, x)))
            for x in then - now:
                self.partners[x].discard(k)
                uncollides.append((min(k, x), max(k, x)))
            self.partners[k] = now

    def pairs(self):
        return {(a, b) for a, ps in self.partners.items() for b in ps if a < b}


class RtreeRebuildPeer(RtreePeer):
    """As RtreePeer, but the index is bulk-loaded anew each frame (libspatialindex deletes one
    box in about a millisecond, so rebuilding wins once many boxes move)."""

    def __init__(self, keys, lo, hi, pairs):
        super().__init__(keys, lo, hi, pairs)
        self.prop = self.index.properties

    def frame(self, f):
        from rtree import index
        collides, uncollides = [], []
        self._erase(f, uncollides, delete=False)
        changed = []
        for keys, lo, hi in ((f["update_keys"], f["update_lo"], f["update_hi"]),
                             (f["insert_keys"], f["insert_lo"], f["insert_hi"])):
            rows = np.concatenate([lo, hi], axis=1).tolist()
            for k, row in zip(keys.tolist(), rows):
                if k not in self.box:
                    self.partners[k] = set()
                self.box[k] = tuple(row)
                changed.append(k)
        self.index = index.Index(((k, b, None) for k, b in self.box.items()),
                                 properties=self.prop)
        self._requery(changed, collides, uncollides)
        return collides, uncollides


class KdTreePeer:
    """scipy's cKDTree on the box centres, rebuilt each frame; candidates within the largest
    box width under the max-norm, then the exact box test; events as set differences."""

    def __init__(self, keys, lo, hi):
        order = np.argsort(keys)
        self.keys, self.lo, self.hi = keys[order], lo[order].copy(), hi[order].copy()
        self.last = self._pairs()

    def _pairs(self):
        from scipy.spatial import cKDTree
        centre = (self.lo + self.hi) * 0.5
        width = float(np.max(self.hi - self.lo))
        cand = cKDTree(centre).query_pairs(width, p=np.inf, output_type="ndarray")
        i, j = cand[:, 0], cand[:, 1]
        ok = np.all((self.lo[i] <= self.hi[j]) & (self.lo[j] <= self.hi[i]), axis=1)
        a, b = self.keys[i[ok]], self.keys[j[ok]]
        return np.minimum(a, b) << np.uint64(32) | np.maximum(a, b)

    def frame(self, f):
        keep = ~np.isin(self.keys, f["erase"])
        self.keys, self.lo, self.hi = self.keys[keep], self.lo[keep], self.hi[keep]
        rows = np.searchsorted(self.keys, f["update_keys"])
        self.lo[rows], self.hi[rows] = f["update_lo"], f["update_hi"]
        keys = np.concatenate([self.keys, f["insert_keys"]])
        order = np.argsort(keys)
        self.keys = keys[order]
        self.lo = np.concatenate([self.lo, f["insert_lo"]])[order]
        self.hi = np.concatenate([self.hi, f["insert_hi"]])[order]
        now = self._pairs()
        collides = np.setdiff1d(now, self.last)
        uncollides = np.setdiff1d(self.last, now)
        self.last = now
        return collides, uncollides

    def pairs(self):
        return {(int(p >> 32), int(p & 0xFFFFFFFF)) for p in self.last.tolist()}


def peers(broadphase, name, peer_frames):
    initial, frames = frames_of(broadphase, name, peer_frames)
    row = {"bench": "peers", "scenario": name, "frames": peer_frames}
    ms, engine = run_engine(broadphase, initial, frames)
    row["engine_ms"], row["engine_fps"] = ms, 1e3 / ms
    truth = {(int(a), int(b)) for a, b in engine.overlaps().tolist()}
    start = broadphase.Engine("grid_dense", dims=initial[1].shape[1])
    start.insert(*initial)
    start.query()
    for label, make in (("rtree", lambda: RtreePeer(*initial, start.overlaps())),
                        ("rtree_rebuild", lambda: RtreeRebuildPeer(*initial, start.overlaps())),
                        ("ckdtree", lambda: KdTreePeer(*initial))):
        peer = make()
        times = []
        for f in frames:
            t0 = time.perf_counter()
            peer.frame(f)
            times.append((time.perf_counter() - t0) * 1e3)
        ms = statistics.median(times)
        row[label + "_ms"], row[label + "_fps"] = ms, 1e3 / ms
        row[label + "_vs_engine"] = ms / row["engine_ms"]
        row[label + "_exact"] = peer.pairs() == truth
    return row


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="S1-100k,S1-200k")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--peer-frames", type=int, default=5)
    p.add_argument("--build", default="build/release")
    p.add_argument("--out")
    args = p.parse_args()
    sys.path.insert(0, os.path.join(args.build, "python"))
    import broadphase  # noqa: E402 - from the build tree
    bpbench = os.path.join(args.build, "bench", "bpbench")
    cpu = pin_cpu()
    rows = []
    for name in args.scenarios.split(","):
        initial, frames = frames_of(broadphase, name, args.frames)
        py_ms, cpp_ms, ratios = [], [], []
        for r in range(args.rounds):
            first_python = r % 2 == 0
            if not first_python:
                cpp_ms.append(run_bpbench(bpbench, name, args.frames, cpu))
            py_ms.append(run_engine(broadphase, initial, frames)[0])
            if first_python:
                cpp_ms.append(run_bpbench(bpbench, name, args.frames, cpu))
            ratios.append(py_ms[-1] / cpp_ms[-1])
            print(f"python_engine: {name} round {r + 1}/{args.rounds}: python {py_ms[-1]:.3f} ms,"
                  f" C++ {cpp_ms[-1]:.3f} ms", file=sys.stderr)
        rows.append({"bench": "engine", "scenario": name, "engine": "grid_dense",
                     "frames": args.frames, "rounds": args.rounds, "cpu": cpu,
                     "python_ms": statistics.median(py_ms), "cpp_ms": statistics.median(cpp_ms),
                     "ratio": statistics.median(ratios), "ratio_min": min(ratios),
                     "ratio_max": max(ratios)})
        print(json.dumps(rows[-1]), flush=True)
        del initial, frames
        rows.append(peers(broadphase, name, args.peer_frames))
        print(json.dumps(rows[-1]), flush=True)
    if args.out:
        with open(args.out, "a") as f:
            for row in rows:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
