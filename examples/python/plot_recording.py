#!/usr/bin/python3
"""Events per frame of a recorded update stream, plotted with matplotlib.

A recording (bpctl record run.bprec) holds the update batches a daemon received. This script
replays them through the package's own engine, frame by frame, exactly as the daemon applies
them (erases, inserts, updates; keys producer << 48 | id), and plots the collides and uncollides
of each frame:

    bpctl record run.bprec --seconds 30            # while a simulation runs
    scripts/python examples/python/plot_recording.py run.bprec --out events.png
"""

import argparse
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - after the backend is chosen
import numpy as np  # noqa: E402

import broadphase  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("recording")
    p.add_argument("--out", default="events.png")
    p.add_argument("--engine", default="grid_dense")
    args = p.parse_args()

    engine = None
    collides, uncollides, objects = [], [], []
    skipped = 0
    for frame in broadphase.Recording(args.recording).frames():
        for batch in frame:
            if batch["malformed"]:
                skipped += 1
                continue
            if engine is None:
                dtype = batch["insert_lo"].dtype if len(batch["insert_lo"]) else np.float32
                engine = broadphase.Engine(args.engine, dims=batch["dim"], dtype=dtype)
            base = np.uint64(batch["producer"]) << np.uint64(48)
            calls = (  # as the daemon: erases, inserts, updates; a refused item skips only itself
                lambda: engine.erase(base | batch["erase_ids"]),
                lambda: engine.insert(
                    base | batch["insert_ids"], batch["insert_lo"], batch["insert_hi"],
                    category=batch["category"] if len(batch["category"]) else None,
                    mask=batch["mask"] if len(batch["mask"]) else None,
                    static=batch["static"] if len(batch["static"]) else None),
                lambda: engine.update(base | batch["update_ids"], batch["update_lo"],
                                      batch["update_hi"]))
            for call in calls:
                try:
                    call()
                except broadphase.RefusedError as e:
                    skipped += len(e.indices)
        if engine is None:
            continue
        c, u = engine.query()
        collides.append(len(c))
        uncollides.append(len(u))
        objects.append(len(engine))
    if not collides:
        print(f"plot_recording: no frames in {args.recording}", file=sys.stderr)
        return 1
    fig, ax = plt.subplots(figsize=(9, 4))
    frames = np.arange(1, len(collides) + 1)
    ax.plot(frames, collides, label="collides")
    ax.plot(frames, uncollides, label="uncollides")
    ax.set_xlabel("frame")
    ax.set_ylabel("events")
    ax.set_title(f"{args.recording}: {len(frames)} frames, up to {max(objects)} objects")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"plot_recording: {len(frames)} frames, {sum(collides)} collides, "
          f"{sum(uncollides)} uncollides, {skipped} items refused or malformed -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
