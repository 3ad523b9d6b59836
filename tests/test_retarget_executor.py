"""Per-frame tasks run serially, in worker processes and on a Dask cluster give the same results, and a
run that stops part-way resumes without solving any frame twice."""

import os
import signal

import numpy as np
import pytest

from solver import SolverError
from solver.retarget.executor import FrameStore, run_frames

RUN = {"motion": "abc", "target": "human"}


def square_plus_offset(shared, task):
    """A stand-in for a frame solve: module level, so worker processes can import it."""
    return {"theta": np.asarray(task) ** 2 + shared["offset"], "pid": np.int64(os.getpid())}


def ctrl_c_handler(shared, task):
    """What a worker does on Ctrl-C (SIGINT) and on SIGTERM: whether it ignores each, as numbers."""
    return {
        "ignored": np.int64(signal.getsignal(signal.SIGINT) == signal.SIG_IGN),
        "sigterm_ignored": np.int64(signal.getsignal(signal.SIGTERM) == signal.SIG_IGN),
    }


def die(shared, task):
    """A worker that ends without answering, as one re-running a script's unguarded main code does."""
    os._exit(3)


def tasks(n=12):
    return {f: np.arange(3.0) + f for f in range(n)}


def expected(f):
    return (np.arange(3.0) + f) ** 2 + 0.5


def test_serial_and_process_runs_agree_and_store_every_frame(tmp_path):
    serial = run_frames(
        square_plus_offset, {"offset": 0.5}, tasks(), FrameStore(tmp_path / "a", RUN), workers=1
    )
    seen = []
    parallel = run_frames(
        square_plus_offset, {"offset": 0.5}, tasks(), FrameStore(tmp_path / "b", RUN), workers=2,
        progress=lambda done, total: seen.append((done, total)),
    )  # fmt: skip
    for f in range(12):
        assert np.array_equal(serial[f]["theta"], expected(f))
        assert np.array_equal(parallel[f]["theta"], expected(f))
    assert os.getpid() not in {int(r["pid"]) for r in parallel.values()}  # worker processes did the work
    assert seen[0] == (0, 12) and seen[-1] == (12, 12) and len(seen) == 13
    assert sorted(FrameStore(tmp_path / "b", RUN).done()) == list(range(12))


def test_a_result_holding_python_objects_is_refused_not_stored_unreadable(tmp_path):
    store = FrameStore(tmp_path, RUN)
    with pytest.raises(SolverError, match=r"frame 3: cannot store names: objects, not numbers"):
        store.save(3, {"theta": np.zeros(4), "names": np.array(["a", None], dtype=object)})
    assert not store.done() and not store.path(3).exists()
    store.save(3, {"theta": np.zeros(4), "status": np.array("converged")})  # text is not pickled
    assert store.load(3)["status"] == "converged"


def test_an_interrupted_run_resumes_with_only_the_missing_frames(tmp_path):
    store = FrameStore(tmp_path, RUN)
    calls = []

    def flaky(shared, task):
        calls.append(int(task[0]))
        if len(calls) == 5:
            raise KeyboardInterrupt  # the user stops the run during the fifth frame
        return square_plus_offset(shared, task)

    with pytest.raises(KeyboardInterrupt):
        run_frames(flaky, {"offset": 0.5}, tasks(), store, workers=1)
    assert sorted(store.done()) == [0, 1, 2, 3]
    solved = []
    results = run_frames(
        lambda s, t: solved.append(int(t[0])) or square_plus_offset(s, t),
        {"offset": 0.5},
        tasks(),
        store,
        workers=1,
    )
    assert solved == list(range(4, 12))  # only the frames the interrupted run had not stored
    assert all(np.array_equal(results[f]["theta"], expected(f)) for f in range(12))
    seen = []
    again = run_frames(
        lambda s, t: seen.append(t) or square_plus_offset(s, t), {"offset": 0.5}, tasks(), store
    )
    assert seen == [] and sorted(again) == list(range(12))  # nothing left to solve


def test_a_folder_of_another_run_or_a_damaged_result_is_refused(tmp_path):
    run_frames(square_plus_offset, {"offset": 0.5}, tasks(2), FrameStore(tmp_path, RUN), workers=1)
    with pytest.raises(SolverError, match="holds results of another run"):
        FrameStore(tmp_path, {**RUN, "target": "witch"})
    FrameStore(tmp_path, RUN).path(1).write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(SolverError, match=r"000001\.npz: the stored result is damaged"):
        FrameStore(tmp_path, RUN).load(1)


def test_dask_cluster_gets_the_same_tasks(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        results = run_frames(
            square_plus_offset,
            {"offset": 0.5},
            tasks(),
            FrameStore(tmp_path, RUN),
            scheduler=cluster.scheduler_address,
        )
    assert all(np.array_equal(results[f]["theta"], expected(f)) for f in range(12))
    with pytest.raises(SolverError, match="cannot reach the Dask scheduler"):
        run_frames(
            square_plus_offset, {}, {99: 1.0}, FrameStore(tmp_path / "x", RUN), scheduler="tcp://127.0.0.1:9"
        )


def test_workers_leave_ctrl_c_and_sigterm_to_the_process_that_started_them(tmp_path):
    """A terminal's Ctrl-C reaches every process of its group, and so does ``timeout``'s SIGTERM: workers
    ignore both (they would die mid-frame, each with a traceback, and leave the frames queued for them
    in a pipe no process reads, which hung the pool's shutdown), the caller gets KeyboardInterrupt (the
    command line raises one on SIGTERM) and stops handing out frames."""
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    results = run_frames(ctrl_c_handler, None, tasks(4), FrameStore(tmp_path, RUN), workers=2)
    assert all(int(r["ignored"]) == 1 and int(r["sigterm_ignored"]) == 1 for r in results.values())
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # untouched here


def test_a_worker_that_dies_is_a_clear_error_naming_the_main_guard(tmp_path):
    with pytest.raises(SolverError, match='if __name__ == "__main__"'):
        run_frames(die, None, tasks(2), FrameStore(tmp_path, RUN), workers=2)


@pytest.mark.parametrize("workers", [0, -2, 1.5, True])
def test_a_worker_count_below_one_is_refused_not_taken_for_the_default(tmp_path, workers):
    """Issue 39: ``workers=0`` used to mean one per CPU and a negative count one process."""
    with pytest.raises(SolverError, match=f"workers must be a whole number of at least 1 .*got {workers!r}"):
        run_frames(square_plus_offset, {"offset": 0.5}, tasks(2), FrameStore(tmp_path, RUN), workers=workers)
    assert not list(tmp_path.glob("*.npz"))  # nothing solved


def test_a_retarget_refuses_a_bad_worker_count_before_any_stage():
    from solver.retarget import retarget

    with pytest.raises(SolverError, match="workers must be a whole number of at least 1"):
        retarget(None, None, None, workers=0)  # checked before the motion, hand or annotation is looked at
