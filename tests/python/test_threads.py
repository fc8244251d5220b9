"""Shading from several Python threads at once equals one thread; progress callbacks run on the
calling thread; an exception in a callback or Ctrl-C cancels the work."""
import _thread
import threading
import time

import numpy as np
import pytest

import pbgi
from conftest import axis_receivers


def receivers(count, seed):
    rng = np.random.default_rng(seed)
    positions = np.stack([rng.uniform(-1.2, 1.2, count), rng.uniform(-1.2, 1.2, count),
                          rng.uniform(-0.5, 0.9, count)], axis=1)
    normals = rng.normal(size=(count, 3))
    normals[:, 2] = np.abs(normals[:, 2]) + 0.1
    return positions, normals


def test_python_threads_at_once_equal_one_thread(disk_db):
    db = pbgi.open(disk_db[0])
    batches = [receivers(400, seed) for seed in range(4)]
    serial = [db.shade(p, n, threads=1) for p, n in batches]
    results = [None] * len(batches)
    errors = []

    def work(i):
        try:
            p, n = batches[i]
            results[i] = db.shade(p, n, threads=2)
            g = db.gather(p[0], n[0])  # per-thread readers of db.gather
            assert len(g) > 0
        except Exception as e:  # reported below, on the test's thread
            errors.append(e)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(batches))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for a, b in zip(serial, results):
        np.testing.assert_array_equal(a.occlusion, b.occlusion)
        np.testing.assert_array_equal(a.irradiance, b.irradiance)
        assert np.all((a.occlusion >= 0) & (a.occlusion <= 1))
    assert any(np.any(a.occlusion > 0.1) for a in serial)


def test_one_reader_shared_by_threads_gives_the_same_cuts(disk_db):
    db = pbgi.open(disk_db[0])
    reader = db.reader()
    p, n = receivers(64, 9)
    want = [len(reader.gather(p[i], n[i])) for i in range(len(p))]
    got = [None] * len(p)

    def work(k):
        for i in range(k, len(p), 4):
            got[i] = len(reader.gather(p[i], n[i]))

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert got == want


def test_shading_releases_the_gil(disk_db):
    db = pbgi.open(disk_db[0])
    p, n = receivers(20000, 3)
    ticks = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.005)

    t = threading.Thread(target=count)
    t.start()
    start = time.monotonic()
    db.shade(p, n, mode="occlusion", threads=1)
    end = time.monotonic()
    stop.set()
    t.join()
    during = [x for x in ticks if start < x < end]
    # A thread holding the GIL for the whole call would let the counter tick at most once.
    assert end - start > 0.05
    assert len(during) >= 0.25 * (end - start) / 0.005


def test_progress_runs_on_the_calling_thread(disk_db):
    db = pbgi.open(disk_db[0])
    p, n = receivers(20000, 4)
    calls = []
    db.shade(p, n, mode="occlusion", threads=2, progress_interval=0.01,
             progress=lambda done, total: calls.append((done, total, threading.get_ident())))
    assert calls[-1][:2] == (len(p), len(p))
    assert {c[2] for c in calls} == {threading.get_ident()}
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))
    assert len(calls) >= 2  # some before the end


def test_progress_true_works_with_or_without_tqdm(disk_db, capsys):
    db = pbgi.open(disk_db[0])
    p, n, _ = axis_receivers(32)
    out = db.shade(p, n, mode="occlusion", progress=True)
    assert out.occlusion.shape == (32,)


def test_an_exception_in_the_callback_cancels(disk_db):
    db = pbgi.open(disk_db[0])
    p, n = receivers(100000, 5)

    def boom(done, total):
        raise RuntimeError("stop here")

    start = time.monotonic()
    with pytest.raises(RuntimeError, match="stop here"):
        db.shade(p, n, mode="occlusion", threads=1, progress=boom, progress_interval=0.02)
    assert time.monotonic() - start < 1.5  # the whole batch takes several seconds


def test_ctrl_c_cancels_a_shade(disk_db):
    db = pbgi.open(disk_db[0])
    p, n = receivers(100000, 6)
    # SIGINT as Ctrl-C sends it, from the first progress call (on the calling thread, while the
    # batch runs): the next poll sees the signal, cancels the batch and raises.
    interrupted = []

    def interrupt(done, total):
        if not interrupted:
            interrupted.append(done)
            _thread.interrupt_main()

    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        db.shade(p, n, mode="occlusion", threads=1, progress=interrupt, progress_interval=0.02)
    assert time.monotonic() - start < 1.5
    assert interrupted and interrupted[0] < len(p)
    # The database is still usable.
    q, m, _ = axis_receivers(4)
    assert db.shade(q, m, mode="occlusion").occlusion.shape == (4,)
