"""tt_ros.worker: the latest request's work, in a thread of its own."""

import threading

from tt_ros.worker import LatestWorker


def test_work_runs_off_the_caller_and_a_waiting_request_gives_way_to_a_newer_one():
    started, release, done = threading.Event(), threading.Event(), threading.Event()
    ran = []

    def work(request):
        ran.append((request, threading.current_thread().name))
        if request == 1:
            started.set()
            release.wait(10.0)
        if request == 3:
            done.set()

    worker = LatestWorker('test-worker', work)
    try:
        worker.submit(1)
        assert started.wait(10.0)
        worker.submit(2)                 # waits while 1 runs ...
        worker.submit(3)                 # ... and gives way to 3
        release.set()
        assert done.wait(10.0)
    finally:
        worker.stop()
    assert ran == [(1, 'test-worker'), (3, 'test-worker')]


def test_stop_ends_the_thread():
    done = threading.Event()
    worker = LatestWorker('test-worker', lambda request: done.set())
    worker.submit('only')
    assert done.wait(10.0)
    worker.stop()
    assert not worker._thread.is_alive()


def test_an_error_is_told_and_the_next_request_is_worked_on():
    errors, told, done = [], threading.Event(), threading.Event()

    def work(request):
        if request == 'bad':
            raise ValueError('bad request')
        done.set()

    def on_error(exc):
        errors.append(exc)
        told.set()

    worker = LatestWorker('test-worker', work, on_error=on_error)
    try:
        worker.submit('bad')
        assert told.wait(10.0)
        worker.submit('good')
        assert done.wait(10.0)
    finally:
        worker.stop()
    assert [str(e) for e in errors] == ['bad request']


def test_requests_of_other_keys_wait_their_turn_and_each_key_keeps_its_latest():
    # Two balls at once: one slot for all made one track's request replace the other's
    # (strike_node's refreshed in-zone probability, prediction_node's hit covariance).
    started, release, done = threading.Event(), threading.Event(), threading.Event()
    ran = []

    def work(request):
        ran.append(request)
        if request == 'busy':
            started.set()
            release.wait(10.0)
        if len(ran) == 3:
            done.set()

    worker = LatestWorker('test-worker', work)
    try:
        worker.submit('busy', key=6)
        assert started.wait(10.0)
        worker.submit('4 old', key=4)
        worker.submit('5', key=5)
        worker.submit('4 new', key=4)    # replaces 4's waiting one, not 5's
        release.set()
        assert done.wait(10.0)
    finally:
        worker.stop()
    assert ran == ['busy', '5', '4 new']
