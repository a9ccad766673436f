"""The run's output writer: files are written by a thread while the solver steps.

The stepping thread takes what an output needs from the solver (numpy copies: `Simulation.particles()`,
`get_state()`, a diagnostics row) and hands it over with `submit(kind, fn, *args)`; one writer thread runs the
jobs in the order they came (a snapshot's VTU before the series file that names it, before the checkpoint that
counts it), so the files on disk are always those of a prefix of the run. The queue is bounded (`depth` jobs:
a few snapshots' data), and the stepping thread waits only when it is full; `wait_seconds` is that time.

Every file is still written atomically (files.atomic_write / atomic_path: a temporary renamed over the real
name), so a run stopped at any moment leaves complete files behind. A job's failure (disk full, a link in the
way) is raised in the stepping thread at its next `submit` or at `drain`, and later jobs are dropped: nothing is
written after a failed write. `drain()` waits until every job is done: the runner calls it before it reports a
stop (Ctrl-C, SIGTERM, a numerical failure) and at the end of the run.

`Writer(threaded=False)` runs each job at once in the caller's thread (output.writer: inline): the same files,
in the same order, without the thread. The writer never calls Taichi: jobs get numpy arrays and plain values.
"""
from __future__ import annotations

import queue
import threading
import time
from collections import defaultdict
from typing import Callable

_STOP = object()


class Writer:
    """Runs output jobs in order on one background thread (or inline); seconds per kind in `seconds`."""

    def __init__(self, threaded: bool = True, depth: int = 8, name: str = "taichi-mpm-writer"):
        self.threaded = bool(threaded)
        self.seconds: dict[str, float] = defaultdict(float)   # kind -> seconds its jobs took (in the writer)
        self.counts: dict[str, int] = defaultdict(int)
        self.wait_seconds = 0.0   # time the submitting thread waited for room in the queue or for drain
        self._error: BaseException | None = None   # the first failed job's error (later jobs are dropped)
        self._reported = False
        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        if self.threaded:
            self._queue = queue.Queue(maxsize=max(1, int(depth)))
            self._thread = threading.Thread(target=self._work, name=name, daemon=True)
            self._thread.start()

    # ------------------------------------------------------------ the stepping thread's side
    def submit(self, kind: str, fn: Callable, *args) -> None:
        """Run fn(*args) after every job submitted before it; `kind` names it in the breakdown (snapshot,
        checkpoint, diagnostics, probes, frames). Raises the error of an earlier job, if one failed."""
        self._raise()
        if self._error is not None:
            return   # failed and reported: nothing more is written
        if not self.threaded:
            try:
                self._run(kind, fn, args)
            except BaseException as e:
                self._error, self._reported = e, True
                raise
            return
        if not self._thread.is_alive():
            raise RuntimeError("the output writer has been closed")
        try:
            self._queue.put_nowait((kind, fn, args))
        except queue.Full:
            t0 = time.perf_counter()
            self._queue.put((kind, fn, args))
            self.wait_seconds += time.perf_counter() - t0

    def drain(self) -> None:
        """Wait until every submitted job is done; raise the error of one that failed."""
        if self.threaded and self._thread.is_alive():
            t0 = time.perf_counter()
            self._queue.join()
            self.wait_seconds += time.perf_counter() - t0
        self._raise()

    def close(self) -> None:
        """Drain, then end the thread (idempotent). Raises a job's error like drain."""
        try:
            self.drain()
        finally:
            if self.threaded and self._thread.is_alive():
                self._queue.put((None, _STOP, ()))
                self._thread.join()

    @property
    def pending(self) -> int:
        return self._queue.unfinished_tasks if self.threaded else 0

    # ------------------------------------------------------------ the writer thread
    def _run(self, kind, fn, args):
        t0 = time.perf_counter()
        try:
            fn(*args)
        finally:
            self.seconds[kind] += time.perf_counter() - t0
            self.counts[kind] += 1

    def _work(self):
        while True:
            kind, fn, args = self._queue.get()
            try:
                if fn is _STOP:
                    return
                if self._error is None:   # after a failure nothing more is written (the files stay a prefix)
                    self._run(kind, fn, args)
            except BaseException as e:  # raised in the stepping thread (submit / drain)
                self._error = e
            finally:
                self._queue.task_done()

    def _raise(self):
        """The failed job's error, raised once (the run stops on it; a later drain or close is quiet)."""
        if self._error is not None and not self._reported:
            self._reported = True
            raise self._error
