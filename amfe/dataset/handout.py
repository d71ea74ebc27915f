"""The hand-out of records to rank groups (an MPI window of two counters) and the progress bar.

World rank 0 exposes two int64 counters in an MPI RMA window
(``Win.Allocate``): NEXT, the next position in the list of records still to
do, and FINISHED, the number of records finished in this run. A group leader
takes a position with an atomic ``Fetch_and_op(+1, MPI.SUM)`` under a shared
passive-target lock. :meth:`Window.stop` adds STOP to NEXT, so that every
later take is past the end of any list: the groups finish the beds they hold
and leave the loop (used when a record cannot be written, e.g. a full disk).
"""
import sys
import threading

import numpy as np
from tqdm import tqdm

NEXT, FINISHED = 0, 1   # the two counters of the hand-out window
STOP = 2**40            # added to NEXT by stop(): past the end of any to-do list (< 2**62 / ranks)


class Window:
    """The two hand-out counters, in world rank 0's memory."""

    def __init__(self, MPI, world):
        self.MPI = MPI
        self.win = MPI.Win.Allocate(16 if world.rank == 0 else 0, 8, comm=world)
        self.local = None
        if world.rank == 0:
            self.local = np.frombuffer(self.win.tomemory(), dtype=np.int64)
            self.win.Lock(0, MPI.LOCK_EXCLUSIVE)
            self.local[:] = 0
            self.win.Unlock(0)
        world.Barrier()
        self._out = np.zeros(1, np.int64)

    def fetch_add(self, slot, amount=1):
        """Atomically add ``amount`` to counter ``slot``; returns its value before."""
        MPI = self.MPI
        self.win.Lock(0, MPI.LOCK_SHARED)
        self.win.Fetch_and_op(np.array([amount], np.int64), self._out, 0, target_disp=slot,
                              op=MPI.SUM)
        self.win.Unlock(0)
        return int(self._out[0])

    def stop(self):
        """Hand out nothing more (every later take of NEXT is past the end)."""
        self.fetch_add(NEXT, STOP)

    def peek_finished(self):
        """World rank 0 only: the finished counter, read from local memory (unified model)."""
        return int(self.local[FINISHED])

    def free(self):
        self.win.Free()


class Progress:
    """tqdm bar on world rank 0, fed by a thread that reads the finished counter."""

    def __init__(self, enabled, total, initial, window):
        self.bar = None
        self.window = window
        self.initial = initial
        self._stop = threading.Event()
        self._thread = None
        if not enabled:
            return
        self.bar = tqdm(total=total, initial=initial, unit="bed", file=sys.stderr,
                        dynamic_ncols=True, mininterval=0.5, smoothing=0.05,
                        desc="amfe dataset")
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _update(self):
        n = self.initial + self.window.peek_finished()
        if n > self.bar.n:
            self.bar.update(n - self.bar.n)

    def _run(self):
        while not self._stop.wait(0.5):
            self._update()

    def close(self):
        if self.bar is None:
            return
        self._stop.set()
        self._thread.join()
        self._update()
        self.bar.close()
