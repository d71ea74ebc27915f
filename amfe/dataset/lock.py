"""The exclusive lock of a data-set output: ``DATA.h5.lock``, one writer at a time.

``amfe dataset -o DATA.h5`` (and ``--add-bond-images DATA.h5``) create
``DATA.h5.lock`` with O_CREAT | O_EXCL before touching anything else of
DATA.h5: its parts, its temporary files, the file itself. The lock holds, as
JSON, world rank 0's pid, host and start time, the pids of every rank with
their hosts and process start ticks (from /proc, so that a reused pid is not
taken for the writer), and the command line. It is removed when the run ends,
by success or by an AmfeError.

A second run on the same output is refused with a line naming the holder.
A kill (SIGKILL, a lost node) leaves the lock behind. It is then *stale*:
every rank it names ran on this host and none runs any more. A stale lock is
reported with the command that removes it, never removed silently: the ranks
of a killed ``mpirun`` can outlive it by seconds, and a lock of another host
cannot be checked from here. See docs/datasets.md, "One writer per file".
"""
import datetime
import json
import os
import shlex
import sys
import time

from amfe.errors import AmfeError
from amfe.io.atomic import host_name, is_no_space, no_space_error, pid_running

LOCK_SUFFIX = ".lock"


def lock_path(output):
    """The lock file of data-set file ``output``: ``OUTPUT.lock``."""
    return os.fspath(output) + LOCK_SUFFIX


def _start_ticks(pid):
    """The start time of process ``pid`` in clock ticks since boot, or None (no /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return int(fh.read().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _boot_id():
    try:
        with open("/proc/sys/kernel/random/boot_id") as fh:
            return fh.read().strip()
    except OSError:
        return None


def this_process():
    """[host, pid, start ticks] of this process: what a rank contributes to the lock."""
    return [host_name(), os.getpid(), _start_ticks(os.getpid())]


def _alive(proc, boot):
    """Whether the process [host, pid, ticks] of a lock may run: True, False or None (unknown)."""
    host, pid, ticks = proc
    if host != host_name():
        return None
    if boot is not None and boot != _boot_id():
        return False
    if not pid_running(int(pid)):
        return False
    now = _start_ticks(int(pid))
    return ticks is None or now is None or now == ticks


class DatasetLock:
    """The lock of one output; ``acquire`` on world rank 0, ``release`` when done.

    output: the data-set file; ranks: [[host, pid, ticks], ...] of every rank
    of the run (world rank 0 first), from :func:`this_process`.
    """

    def __init__(self, output, ranks=None):
        self.output = os.fspath(output)
        self.path = lock_path(self.output)
        self.ranks = [list(r) for r in (ranks or [this_process()])]
        self.token = None

    def acquire(self):
        """Create the lock file; AmfeError naming the holder if it exists."""
        host, pid, _ = self.ranks[0]
        self.token = {
            "pid": pid, "host": host,
            "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "ranks": self.ranks, "boot_id": _boot_id(), "command": sys.argv,
            "output": os.path.abspath(self.output),
        }
        data = (json.dumps(self.token) + "\n").encode()
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            self.token = None
            raise AmfeError(self._held_message()) from None
        except OSError as exc:
            self.token = None
            if is_no_space(exc):
                raise no_space_error(self.path, False) from None
            raise AmfeError(f"cannot create the lock file {self.path}: "
                            f"{exc.strerror or exc}") from None
        try:
            os.write(fd, data)
            os.fsync(fd)
        except OSError as exc:
            os.close(fd)
            os.remove(self.path)
            self.token = None
            if is_no_space(exc):
                raise no_space_error(self.path, False) from None
            raise
        os.close(fd)
        return self

    def release(self):
        """Remove the lock file if it is still this run's."""
        if self.token is None:
            return
        token, self.token = self.token, None
        if read_lock(self.path) == token:
            try:
                os.remove(self.path)
            except FileNotFoundError:
                pass

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()

    def _held_message(self):
        holder = read_lock(self.path, wait=1.0)
        rm = f"rm {shlex.quote(self.path)}"
        if holder is None and not os.path.exists(self.path):
            return (f"{self.output} was locked by another amfe dataset that has just ended; run "
                    "the command again")
        if holder is None:
            return (f"{self.output} is locked ({self.path} exists but cannot be read); if no amfe "
                    f"dataset is writing {self.output}, remove the lock: {rm}")
        who = (f"pid {holder.get('pid')} on host {holder.get('host')}, started "
               f"{holder.get('started')}")
        try:
            alive = [_alive(p, holder.get("boot_id")) for p in holder.get("ranks") or
                     [[holder.get("host"), holder.get("pid"), None]]]
        except (TypeError, ValueError):   # a lock file that is not ours: say so
            return (f"{self.output} is locked ({self.path} holds no amfe lock: "
                    f"{json.dumps(holder)[:200]}); if no amfe dataset is writing {self.output}, "
                    f"remove the lock: {rm}")
        if any(a is None for a in alive) and not any(alive):
            return (f"{self.output} is locked by an amfe dataset on another host ({who}; lock "
                    f"{self.path}); wait for it to end; if it is dead, remove the lock: {rm}")
        if any(alive):
            return (f"{self.output} is being written by another amfe dataset ({who}, "
                    f"{sum(bool(a) for a in alive)} of its {len(alive)} rank(s) running); wait "
                    f"for it to end, or write another -o (lock {self.path})")
        pids = ",".join(str(p[1]) for p in holder.get("ranks") or [[None, holder.get("pid")]])
        return (f"stale lock {self.path}: the amfe dataset that took it ({who}) has ended "
                f"without removing it (killed?); the records it finished are kept. Check that "
                f"none of its ranks is left (ps -p {pids}), then remove the lock and run the "
                f"command again: {rm}")


def read_lock(path, wait=0.0):
    """The JSON content of a lock file, or None (absent or unreadable after ``wait`` s).

    A lock just created by O_EXCL is empty for a moment: reading is retried
    for ``wait`` seconds.
    """
    deadline = time.monotonic() + wait
    while True:
        try:
            with open(path) as fh:
                data = json.load(fh)
            if isinstance(data, dict):
                return data
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            pass
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.05)
