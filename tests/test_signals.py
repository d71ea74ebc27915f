"""SIGINT and SIGTERM end a run with one line and 130 / 143, on every rank (issue 18, Signals).

Measured with Open MPI 4.1 (amfe.cli.interrupt): a signal to one rank only,
rank 0 or another, ends every rank through MPI_Abort with the signal's exit
code, which mpirun returns; Open MPI adds its "MPI_ABORT was invoked" banner.
"""
import glob
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from helpers import MPI_ENV, ROOT

from amfe.io.bedfile import write_bed
from amfe.dataset.parts import parts_dir
from amfe.model.bed import generate_bed

LINE = "amfe {command}: interrupted ({name})"


@pytest.fixture(scope="module")
def bed(tmp_path_factory):
    """A bed whose solve takes a few seconds (3 300 particles)."""
    path = tmp_path_factory.mktemp("sig") / "bed.h5"
    write_bed(path, generate_bed(size=(0.4e-3, 0.4e-3, 0.2e-3), seed=0))
    return str(path)


class Run:
    """`amfe ARGS` (under mpirun -n RANKS) in its own session, its stderr collected as it comes."""

    def __init__(self, args, ranks=None, cwd=ROOT):
        cmd = [sys.executable, "-m", "amfe.cli", *map(str, args)]
        if ranks:
            cmd = ["mpirun", "-n", str(ranks), *cmd]
        self.proc = subprocess.Popen(cmd, cwd=cwd, env=MPI_ENV, start_new_session=True,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.lines = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, ready, timeout=120):
        """Wait until ready() holds while the run is still going."""
        t0 = time.time()
        while not ready():
            assert self.proc.poll() is None, "ended before the signal:\n" + "\n".join(self.lines)
            assert time.time() - t0 < timeout
            time.sleep(0.02)

    def seen(self, text):
        return lambda: any(text in line for line in self.lines)

    def ranks(self):
        """{rank: pid} of the MPI processes of this run's session."""
        out = {}
        for env in glob.glob("/proc/[0-9]*/environ"):
            pid = int(env.split("/")[2])
            try:
                if os.getsid(pid) != self.proc.pid:
                    continue
                with open(env, "rb") as fh:
                    items = dict(kv.split(b"=", 1) for kv in fh.read().split(b"\0") if b"=" in kv)
            except OSError:
                continue
            if b"OMPI_COMM_WORLD_RANK" in items and pid != self.proc.pid:
                out[int(items[b"OMPI_COMM_WORLD_RANK"])] = pid
        return out

    def finish(self, timeout):
        """(exit code, seconds to end, stderr lines); kills what is left if it hangs."""
        t0 = time.time()
        try:
            code = self.proc.wait(timeout=timeout)
        finally:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.reader.join(timeout=10)
        return code, time.time() - t0, self.lines


def _assert_one_line(lines, command, sig):
    want = LINE.format(command=command, name=sig.name)
    assert sum(want in line for line in lines) == 1, "\n".join(lines)
    assert not any("Traceback" in line or "Error" in line for line in lines), "\n".join(lines)


def test_sigint_ends_a_solve_with_one_line(bed, tmp_path):
    """Ctrl-C during `amfe homogenize bed.h5 -o r.json`: exit 130, one line, no file."""
    out = tmp_path / "r.json"
    run = Run(["homogenize", bed, "-o", out])
    run.wait_for(run.seen("frame:"))
    os.kill(run.proc.pid, signal.SIGINT)
    code, _, lines = run.finish(timeout=120)
    assert code == 130
    _assert_one_line(lines, "homogenize", signal.SIGINT)
    assert lines[-1] == LINE.format(command="homogenize", name="SIGINT")
    assert os.listdir(tmp_path) == []   # no result, no temp file


def test_sigterm_keeps_the_finished_records(tmp_path):
    """SIGTERM to `amfe dataset`: exit 143, one line; the finished records stay, no temp file."""
    out = tmp_path / "d.h5"
    parts = parts_dir(out)
    run = Run(["dataset", "-o", out, "--count", "60", "--scale", "tiny", "--no-progress"])
    run.wait_for(lambda: len(glob.glob(os.path.join(parts, "rec_*.npz"))) >= 2)
    os.kill(run.proc.pid, signal.SIGTERM)
    code, _, lines = run.finish(timeout=120)
    assert code == 143
    _assert_one_line(lines, "dataset", signal.SIGTERM)
    done = glob.glob(os.path.join(parts, "rec_*.npz"))
    assert 2 <= len(done) < 60 and not out.exists()
    for path in done:   # every finished record is whole
        with np.load(path) as rec:
            assert len(rec.files) > 0
    assert not [p for p in glob.glob(os.path.join(tmp_path, "**", "*"), recursive=True)
                if p.endswith(".tmp")]


@pytest.mark.mpi
@pytest.mark.parametrize("sig, rank", [(signal.SIGINT, 0), (signal.SIGTERM, 1)])
def test_signal_to_one_rank_ends_every_rank(bed, tmp_path, sig, rank):
    """`kill -INT <pid of rank 0>` under mpirun -n 2 gave a traceback, and a signal to one rank
    could leave the other waiting in a collective. Now: every rank ends, exit 128 + signal."""
    out = tmp_path / "r.json"
    run = Run(["homogenize", bed, "-o", out], ranks=2)
    run.wait_for(run.seen("frame:"))
    pids = run.ranks()
    assert sorted(pids) == [0, 1]
    os.kill(pids[rank], sig)
    code, seconds, lines = run.finish(timeout=60)
    assert code == 128 + sig
    _assert_one_line(lines, "homogenize", sig)
    assert seconds < 30
    assert not out.exists()
    deadline = time.time() + 10   # Open MPI ends the ranks: SIGTERM, SIGKILL 1 s later
    while any(_alive(pid) for pid in pids.values()):
        assert time.time() < deadline, f"ranks still running: {pids}"
        time.sleep(0.1)


def _alive(pid):
    """True while ``pid`` runs (a zombie is dead; it waits for its parent to reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False
