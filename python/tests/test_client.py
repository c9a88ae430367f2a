"""The client classes through a real broadphased on loopback DDS (domain 17): events against the
package's own engine frame by frame, the overlap view, status, interests and spot queries, and a
recording made by bpctl read back."""

import os
import signal
import sys
import subprocess
import tempfile
import time

import numpy as np
import pytest

import broadphase
from oracle import Oracle, as_set, sorted_pairs

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DAEMON = os.environ.get("BP_DAEMON", os.path.join(ROOT, "build/release/service/broadphased"))
BPCTL = os.environ.get("BP_BPCTL", os.path.join(ROOT, "build/release/tools/bpctl/bpctl"))
DOMAIN = 17
PRODUCER = 5


@pytest.fixture(scope="module")
def deployment():
    """A daemon of its own (partition per test process) and its config file."""
    work = tempfile.mkdtemp(prefix="bp-python-")
    config = os.path.join(work, "d.yaml")
    with open(config, "w") as f:
        f.write(f"""engine:
  threads: 1
dds:
  domain: {DOMAIN}
  cyclone_config: {ROOT}/config/cyclonedds-loopback.xml
  partition: python-{os.getpid()}
producers:
  lease_s: 2
logging:
  summary_interval_s: 0
""")
    log = open(os.path.join(work, "daemon.log"), "w")
    daemon = subprocess.Popen([DAEMON, "--config", config], stdout=log, stderr=subprocess.STDOUT)
    try:
        yield config, work
    finally:
        daemon.send_signal(signal.SIGINT)
        try:
            daemon.wait(10)
        except subprocess.TimeoutExpired:
            daemon.kill()
        log.close()


def local_boxes(rng, n, side=30.0):
    lo = rng.uniform(0, side, size=(n, 3)).astype(np.float32)
    return lo, lo + rng.uniform(0.5, 3.0, size=(n, 3)).astype(np.float32)


def global_keys(ids):
    return (np.uint64(PRODUCER) << np.uint64(48)) | np.asarray(ids, np.uint64)


def collect_frame(sub, frame, timeout=10.0):
    """The collides and uncollides of daemon parts up to the last part of a frame whose source
    frame is `frame`."""
    collides, uncollides = [], []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for part in sub.poll(0.1):
            if part.snapshot:
                continue
            collides.append(part.collides)
            uncollides.append(part.uncollides)
            if part.last_part and part.source_frame == frame:
                return (np.concatenate(collides).reshape(-1, 2),
                        np.concatenate(uncollides).reshape(-1, 2))
    raise TimeoutError(f"no events of frame {frame}")


def test_round_trip_matches_the_oracle_frame_by_frame(deployment):
    config, work = deployment
    conn = broadphase.Connection(config)
    assert conn.dims == 3
    sub = broadphase.EventSubscriber(conn)
    view = broadphase.OverlapView(conn)
    status = broadphase.StatusSubscriber(conn)
    pub = broadphase.Publisher(conn, PRODUCER)
    pub.wait_for_daemon(10)
    sub.wait_for_daemon(10)
    view.wait_for_daemon(10)
    rng = np.random.default_rng(1)
    oracle = Oracle(3)
    ids = np.arange(150, dtype=np.uint64)
    lo, hi = local_boxes(rng, len(ids))
    frame = pub.publish(insert_ids=ids, insert_lo=lo, insert_hi=hi)
    oracle.insert(global_keys(ids), lo, hi)
    before = set()
    for step in range(8):
        c, u = collect_frame(sub, frame)
        after = as_set(oracle.pairs())
        np.testing.assert_array_equal(c, sorted_pairs(after - before))   # canonical order
        np.testing.assert_array_equal(u, sorted_pairs(before - after))
        before = after
        moved = rng.choice(np.array(sorted(int(k) & (2**48 - 1) for k in oracle.boxes), np.uint64),
                           size=40, replace=False)
        mlo, mhi = local_boxes(rng, len(moved))
        gone = np.setdiff1d(np.array([int(k) & (2**48 - 1) for k in oracle.boxes], np.uint64),
                            moved)[:3]
        new = np.arange(3, dtype=np.uint64) + np.uint64(1000 + 10 * step)
        nlo, nhi = local_boxes(rng, 3)
        frame = pub.publish(update_ids=moved, update_lo=mlo, update_hi=mhi, erase_ids=gone,
                            insert_ids=new, insert_lo=nlo, insert_hi=nhi)
        oracle.update(global_keys(moved), mlo, mhi)
        oracle.erase(global_keys(gone))
        oracle.insert(global_keys(new), nlo, nhi)
    collect_frame(sub, frame)
    assert sub.gaps == 0 and sub.malformed == 0
    # The view: synced from a snapshot, then equal to the oracle's set.
    view.wait_synced(15)
    deadline = time.monotonic() + 10
    while view.frame < frame and time.monotonic() < deadline:
        view.poll(0.1)
    np.testing.assert_array_equal(view.pairs(), oracle.pairs())
    assert len(view) == len(oracle.pairs()) and view.snapshots >= 1
    # Status: the daemon's reports name our objects.
    reports = []
    deadline = time.monotonic() + 10
    while not reports and time.monotonic() < deadline:
        reports = status.poll(0.5)
    assert reports and reports[-1]["dim"] == 3 and reports[-1]["engine"] == "grid_dense"
    assert isinstance(reports[-1]["objects"], int)
    # Bad input: refused here, before anything is sent.
    with pytest.raises(ValueError, match="below 2\\*\\*48"):
        pub.publish(erase_ids=[2**50])
    with pytest.raises(ValueError, match="expected shape"):
        pub.publish(update_ids=[1], update_lo=[[0, 0]], update_hi=[[1, 1]])
    # Spot query: the objects overlapping a box now.
    spot = broadphase.InterestClient(conn)
    spot.wait_for_daemon(10)
    qlo, qhi = np.array([5, 5, 5.0]), np.array([20, 20, 20.0])
    keys, at = spot.query(qlo, qhi)
    inside = [k for k, (l, h, *_rest) in oracle.boxes.items()
              if np.all(l <= qhi) and np.all(qlo <= h)]
    np.testing.assert_array_equal(keys, np.array(sorted(inside), np.uint64))
    assert at >= frame


def test_interest_stream_and_refusal(deployment):
    config, work = deployment
    conn = broadphase.Connection(config)
    pub = broadphase.Publisher(conn, PRODUCER + 1)
    client = broadphase.InterestClient(conn)
    pub.wait_for_daemon(10)
    client.wait_for_daemon(10)
    region_lo, region_hi = np.array([[100, 100, 100]]), np.array([[110, 110, 110]])
    interest = client.declare(regions_lo=region_lo, regions_hi=region_hi)
    view = broadphase.OverlapView(conn, interest=interest)
    view.wait_for_daemon(10)
    view.wait_synced(15)
    key = (np.uint64(PRODUCER + 1) << np.uint64(48)) | np.uint64(7)
    pub.publish(insert_ids=[7, 8], insert_lo=[[105, 105, 105], [200, 200, 200]],
                insert_hi=[[106, 106, 106], [201, 201, 201]])
    deadline = time.monotonic() + 10
    seen = []
    while len(view) == 0 and time.monotonic() < deadline:
        seen += view.poll(0.1)
    assert len(view) == 1, (seen, view.synced, view.resyncs, view.last_loss, view.frame)
    np.testing.assert_array_equal(view.pairs(), [[0, key]])   # region 0 and object 7
    pub.publish(update_ids=[7], update_lo=[[150, 150, 150]], update_hi=[[151, 151, 151]])
    deadline = time.monotonic() + 10
    while len(view) != 0 and time.monotonic() < deadline:
        view.poll(0.1)
    assert len(view) == 0
    # A bad declaration is refused on the status topic, naming the reason.
    bad = client.declare(regions_lo=[[1, 1, 1]], regions_hi=[[0, 0, 0]])
    refusals = []
    deadline = time.monotonic() + 10
    while not refusals and time.monotonic() < deadline:
        refusals = client.maintain()
        time.sleep(0.1)
    assert refusals and refusals[0]["interest"] == bad
    client.drop(interest)


def test_recording_read_back(deployment):
    config, work = deployment
    path = os.path.join(work, "run.bprec")
    recorder = subprocess.Popen([BPCTL, "--config", config, "record", path, "--seconds", "6"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    conn = broadphase.Connection(config)
    pub = broadphase.Publisher(conn, PRODUCER + 2)
    pub.wait_for_daemon(10)
    pub.wait_for_readers(2, 10)   # the daemon and the recorder
    sent = []
    for f in range(5):
        ids = np.arange(4, dtype=np.uint64) + np.uint64(10 * f)
        lo = np.full((4, 3), f, np.float32)
        pub.publish(insert_ids=ids, insert_lo=lo, insert_hi=lo + 1)
        sent.append(ids)
    pub.flush(5)
    recorder.wait(20)
    rec = broadphase.Recording(path)
    assert rec.header["magic"] == "broadphase-recording"
    frames = [fr for fr in rec.frames() if fr[-1].get("producer") == PRODUCER + 2]
    assert len(frames) == 5
    for f, fr in enumerate(frames):
        b = fr[-1]
        np.testing.assert_array_equal(b["insert_ids"], sent[f])
        assert b["insert_lo"].shape == (4, 3) and b["insert_lo"].dtype == np.float32
        assert b["end_of_frame"] and not b["malformed"]
    with pytest.raises(FileNotFoundError):
        broadphase.Recording(os.path.join(work, "missing.bprec"))


def test_examples_run(deployment):
    """examples/python: the traffic producer against the daemon, then a recording of it plotted."""
    config, work = deployment
    path = os.path.join(work, "traffic.bprec")
    env = dict(os.environ)
    recorder = subprocess.Popen([BPCTL, "--config", config, "record", path, "--seconds", "8"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1)
    run = subprocess.run([sys.executable, os.path.join(ROOT, "examples/python/traffic.py"),
                          "--config", config, "--cars", "400", "--lanes", "8", "--seconds", "3",
                          "--producer", str(PRODUCER + 3)],
                         capture_output=True, text=True, timeout=60, env=env)
    assert run.returncode == 0, run.stderr
    assert "touching pairs" in run.stdout
    recorder.wait(30)
    png = os.path.join(work, "events.png")
    run = subprocess.run([sys.executable, os.path.join(ROOT, "examples/python/plot_recording.py"),
                          path, "--out", png], capture_output=True, text=True, timeout=120,
                         env=env)
    assert run.returncode == 0, run.stderr
    assert os.path.getsize(png) > 0 and "frames" in run.stdout


def test_arguments_are_checked_before_anything_is_joined():
    with pytest.raises(TypeError):
        broadphase.Publisher(None, 3)
    with pytest.raises(TypeError):
        broadphase.EventSubscriber(None)
    with pytest.raises(ValueError, match="domain"):
        broadphase.Connection(domain=-1)
    with pytest.raises(FileNotFoundError):
        broadphase.Connection("/nonexistent/broadphased.yaml")
    with pytest.raises(FileNotFoundError):
        broadphase.Connection(domain=DOMAIN, cyclone_config="/nonexistent/cyclone.xml")
