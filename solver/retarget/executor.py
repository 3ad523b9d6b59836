"""Running independent per-frame tasks in parallel and keeping every result as soon as it exists.

Frames of a retarget are solved independently (§3.4.2), so they are plain tasks: a function applied to
data shared by all frames (the target hand, weights) and to one frame's data. :func:`run_frames` runs
them in worker processes on this machine, or on an existing Dask distributed cluster, and writes each
result to a :class:`FrameStore` the moment it arrives. A run that is interrupted (Ctrl+C, a crash, a
lost cluster) loses nothing: run it again with the same store and it solves only the missing frames.

The shared data travels once per worker, not once per frame: worker processes receive it in their
initializer; a Dask cluster receives it scattered to every worker.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import signal
import zipfile
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from geodesics.files import atomic_file, write_atomically

from ..errors import SolverError, check_count

#: A frame's result: named arrays and numbers (what an .npz holds).
Result = Mapping[str, Any]


class FrameStore:
    """One folder of per-frame results of one stage of one run, an ``.npz`` per frame, written atomically.

    Parameters
    ----------
    folder : path-like
        Created if needed.
    run : mapping
        What identifies the run (input file digest, target hand, weights...), JSON-serializable. A folder
        that already holds results of a different run is refused, so results never mix.
    """

    def __init__(self, folder, run: Mapping[str, Any]):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        identity = json.dumps(run, sort_keys=True)
        stamp = self.folder / "run.json"
        if stamp.exists():
            stored = stamp.read_text(encoding="utf-8")
            if stored != identity:
                raise SolverError(
                    f"{self.folder} holds results of another run ({_digest(stored)} ≠ {_digest(identity)}); "
                    "use a new output folder or delete this one"
                )
        else:
            write_atomically(stamp, identity)

    def path(self, frame: int) -> Path:
        """Where frame ``frame``'s result is stored (``000012.npz``)."""
        return self.folder / f"{int(frame):06d}.npz"

    def done(self) -> set[int]:
        """Frames whose results are stored."""
        return {int(p.stem) for p in self.folder.glob("[0-9]*.npz")}

    def save(self, frame: int, result: Result) -> None:
        """Store frame ``frame``'s result atomically, each value as an array of its own shape (a number as a
        0-d array). Values must be numbers or arrays of them: :meth:`load` reads no pickled objects, so one
        is refused here rather than stored as a file that would read back as damaged."""
        arrays = {name: np.asarray(value) for name, value in result.items()}
        pickled = [name for name, a in arrays.items() if a.dtype.hasobject]
        if pickled:
            raise SolverError(f"frame {frame}: cannot store {', '.join(pickled)}: objects, not numbers")
        with atomic_file(self.path(frame)) as f:
            np.savez(f, **arrays)

    def load(self, frame: int) -> dict[str, np.ndarray]:
        """Frame ``frame``'s stored result: each array by name, of the shape it was saved with (numbers as
        0-d arrays); raises SolverError for a damaged file."""
        try:
            with np.load(self.path(frame), allow_pickle=False) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
            raise SolverError(
                f"{self.path(frame)}: the stored result is damaged ({err}); delete it to re-solve"
            ) from None


def _digest(text: str) -> str:
    return hashlib.blake2b(text.encode(), digest_size=6).hexdigest()


# Each worker process holds the run's shared data, set once by the pool's initializer.
_worker_shared: Any = None


def _start_worker(shared: Any) -> None:
    """A worker's start: it keeps the shared data, and leaves Ctrl-C and SIGTERM to the process that
    started it. A terminal's Ctrl-C reaches every process of its group, and so does the SIGTERM of
    ``timeout`` or of a service manager: workers would die mid-frame, each with its own traceback, and
    the frames queued for them would fill the pipe to them, which then no process reads, so that the
    caller could not shut the pool down. Instead the caller stops handing out frames, the workers finish
    those already sent to them, and the pool's shutdown ends them: each then reads its end-of-work
    marker (also when another worker died and the pool is broken)."""
    global _worker_shared
    _worker_shared = shared
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _call_with_worker_shared(solve: Callable[[Any, Any], Result], task: Any) -> Result:
    return solve(_worker_shared, task)


def run_frames(
    solve: Callable[[Any, Any], Result],
    shared: Any,
    tasks: Mapping[int, Any],
    store: FrameStore,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[int, dict[str, np.ndarray]]:
    """Solve every frame of ``tasks`` not yet in ``store``; return all frames' results.

    Parameters
    ----------
    solve : callable
        ``solve(shared, task) -> result``, a module-level function (it is sent to other processes).
    shared : picklable
        Data every frame needs, sent once per worker.
    tasks : mapping of frame -> picklable task
    store : FrameStore
        Where results go as they finish; frames already there are not solved again.
    workers : int, optional
        Worker processes on this machine, at least 1 (default: one per CPU; 1 solves in this process).
    scheduler : str, optional
        Address of a Dask distributed scheduler (``"tcp://host:8786"``) to send the tasks to instead.
    progress : callable, optional
        ``progress(done, total)`` after each frame (frames found in the store count as done).
    """
    check_workers(workers)
    done = store.done() & set(tasks)
    todo = [f for f in tasks if f not in done]
    total = len(tasks)
    report = progress or (lambda _done, _total: None)
    report(len(done), total)
    if todo:
        if scheduler is not None:
            _run_on_cluster(solve, shared, tasks, todo, store, scheduler, report, total, len(done))
        else:
            _run_locally(
                solve, shared, tasks, todo, store, workers or os.cpu_count() or 1, report, total, len(done)
            )
    return {f: store.load(f) for f in sorted(tasks)}


def check_workers(workers) -> None:
    """Refuse a worker count that is not a whole number of at least 1 (None, the default, is fine): 0
    is not "the default", nor a negative count one process."""
    if workers is not None:
        check_count(workers, "workers", note=" or None for one per CPU")


def _run_locally(solve, shared, tasks, todo, store, workers, report, total, done) -> None:
    if workers <= 1:
        for f in todo:
            store.save(f, solve(shared, tasks[f]))
            done += 1
            report(done, total)
        return
    # Spawned workers (not forked) behave the same on every platform and inherit no threads or locks.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        workers, mp_context=context, initializer=_start_worker, initargs=(shared,)
    ) as pool:
        pending = {pool.submit(_call_with_worker_shared, solve, tasks[f]): f for f in todo}
        try:
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    store.save(pending.pop(future), future.result())
                    done += 1
                    report(done, total)
        except BrokenProcessPool as err:
            for future in pending:
                future.cancel()
            raise SolverError(
                "a worker process ended before finishing its frame. From a script, call this under "
                '`if __name__ == "__main__":`: each worker starts by importing the script (Python\'s '
                "spawn start method), and would otherwise run it again"
            ) from err
        except BaseException:
            for future in pending:
                future.cancel()
            raise


def _run_on_cluster(solve, shared, tasks, todo, store, scheduler, report, total, done) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise SolverError(
            'sending frames to a Dask cluster needs dask.distributed: pip install -e ".[cluster]" in the '
            "checkout"
        ) from None
    try:
        client = Client(scheduler, timeout="10s")
    except OSError as err:
        raise SolverError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
    with client:
        [shared_future] = client.scatter([shared], broadcast=True)
        futures = {client.submit(solve, shared_future, tasks[f], pure=False): f for f in todo}
        try:
            for future in as_completed(futures):
                store.save(futures[future], future.result())
                done += 1
                report(done, total)
        except BaseException:
            client.cancel(list(futures))
            raise
