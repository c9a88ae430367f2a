"""broadphase: an exact, event-based broadphase for simulation and virtual reality.

Axis-aligned boxes go in; *collide* and *uncollide* events come out: the pairs that started or
stopped overlapping since the last query. Batches are numpy arrays; no per-object Python loop
runs anywhere on the way in or out.

    import numpy as np
    import broadphase

    engine = broadphase.Engine("grid_dense", dims=3, dtype="float32")
    engine.insert(keys, lo, hi)          # keys uint64[n]; lo, hi float32[n, 3]
    collides, uncollides = engine.query()

The engine:
  Engine            every engine of the library by name, 2-D or 3-D, float32/float64/int32
  Events            the result of Engine.query(): collides and uncollides, uint64[m, 2]
  RefusedError      some items of a batch were refused (the rest applied)
  Scene, golden     the benchmark scenes of docs/WORKLOADS.md as arrays, their golden values
  set_hash          the set hash the golden values use
The service (broadphased over Cyclone DDS):
  Connection        a participant of a deployment (from the daemon's YAML file)
  Publisher         publishes a producer's inserts, updates, erases and ends of frame
  EventSubscriber   receives event parts (EventPart); parts() iterates
  OverlapView       the exact current overlap set, resynced from snapshots
  StatusSubscriber  the daemon's status reports as dicts
  InterestClient    declares interests (regions, keys, producers, categories); spot queries
  Recording         reads a recorded update stream, batch by batch or frame by frame
"""

import time as _time

from ._broadphase import (Connection, Engine, EventPart, EventSubscriber, Events,
                          InterestClient, OverlapView, Publisher, Recording, RefusedError, Scene,
                          StatusSubscriber, golden, set_hash)

__all__ = ["Connection", "Engine", "EventPart", "EventSubscriber", "Events", "InterestClient",
           "OverlapView", "Publisher", "Recording", "RefusedError", "Scene", "StatusSubscriber",
           "golden", "set_hash"]


def _parts(self, timeout=None, poll=0.1):
    """Yields the event parts as they arrive; stops after `timeout` seconds without one (None:
    never)."""
    quiet_since = _time.monotonic()
    while True:
        got = self.poll(poll)
        for part in got:
            yield part
        if got:
            quiet_since = _time.monotonic()
        elif timeout is not None and _time.monotonic() - quiet_since >= timeout:
            return


EventSubscriber.parts = _parts


def _recording_iter(self):
    """The recording's batches, in order (dicts of arrays)."""
    while True:
        batch = self.next()
        if batch is None:
            return
        yield batch


def _recording_frames(self):
    """The recording's batches grouped into frames: lists of consecutive batches, each list
    ending with a batch that closes a frame (end_of_frame), the last possibly not."""
    frame = []
    for batch in self:
        frame.append(batch)
        if batch.get("end_of_frame"):
            yield frame
            frame = []
    if frame:
        yield frame


Recording.__iter__ = _recording_iter
Recording.frames = _recording_frames
