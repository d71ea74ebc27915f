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

from amfe.dataset.parts import parts_dir
from amfe.io.bedfile import write_bed
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


# --------------------------------------------------------------------------- #
# Round two (issue 31): SIGHUP and SIGQUIT, the imports, a signal inside MPI_Init
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGQUIT])
def test_sighup_and_sigquit_end_a_solve_with_one_line(bed, tmp_path, sig):
    """They gave PETSc's "Caught signal" banner and MPI_ABORT; now as SIGINT: one line."""
    out = tmp_path / "r.json"
    run = Run(["homogenize", bed, "-o", out, "--solver", "gamg"])
    run.wait_for(run.seen("solver:"))
    os.kill(run.proc.pid, sig)
    code, _, lines = run.finish(timeout=120)
    assert code == 128 + sig
    _assert_one_line(lines, "homogenize", sig)
    assert not any("PETSC" in line or "MPI_ABORT" in line for line in lines), "\n".join(lines)
    assert os.listdir(tmp_path) == []


KICK = """
import importlib.abc, os, signal, sys
class Kick(importlib.abc.MetaPathFinder):   # SIGINT while the subcommand's module is imported
    def find_spec(self, name, path, target=None):
        if name == "amfe.cli.homogenize":
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, Kick())
from amfe.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigint_during_the_imports_is_one_line(bed):
    """Ctrl-C in the first 0.3 s gave a KeyboardInterrupt traceback from the imports."""
    p = subprocess.run([sys.executable, "-c", KICK, "homogenize", bed], cwd=ROOT, env=MPI_ENV,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 130
    assert p.stderr.splitlines() == [LINE.format(command="homogenize", name="SIGINT")], p.stderr


HALF_STARTED = """
import os, signal, sys
from amfe.cli.interrupt import Interrupted, end_interrupted, signals_raise
from mpi4py import MPI
if MPI.COMM_WORLD.rank == 1:
    MPI.COMM_WORLD.barrier()   # waits for rank 0, as rank 1 waits in the first collective
    sys.exit(0)
del sys.modules["mpi4py.MPI"]   # as when the signal arrives inside `from mpi4py import MPI`
with signals_raise():
    try:
        os.kill(os.getpid(), signal.SIGINT)
        sum(range(1000))
    except Interrupted as exc:
        sys.exit(end_interrupted("homogenize", exc))
"""


@pytest.mark.mpi
def test_a_signal_inside_mpi_init_ends_every_rank():
    """SIGINT to rank 0 of `mpirun -n 2 amfe homogenize --solver gamg` at 0.7 s (inside
    MPI_Init): rank 0 printed its line, then waited in MPI_Finalize for rank 1, which waited in
    its first collective, and mpirun never ended. Now rank 0 leaves at once and mpirun ends
    the job."""
    proc = subprocess.Popen(["mpirun", "-n", "2", sys.executable, "-c", HALF_STARTED], cwd=ROOT,
                            env=MPI_ENV, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert proc.returncode == 130
    assert sum(LINE.format(command="homogenize", name="SIGINT") in line
               for line in err.splitlines()) == 1


@pytest.mark.mpi
def test_sigint_to_rank_0_during_a_gamg_solve_ends_every_rank(bed, tmp_path):
    """The issue's command: `mpirun -n 2 amfe homogenize ... --solver gamg`, SIGINT to rank 0
    once the solve has started; every rank ends within 10 s of mpirun's exit."""
    run = Run(["homogenize", bed, "-o", tmp_path / "r.json", "--solver", "gamg"], ranks=2)
    run.wait_for(run.seen("solver:"))
    pids = run.ranks()
    os.kill(pids[0], signal.SIGINT)
    code, _, lines = run.finish(timeout=60)
    assert code == 130
    _assert_one_line(lines, "homogenize", signal.SIGINT)
    deadline = time.time() + 10
    while any(_alive(pid) for pid in pids.values()):
        assert time.time() < deadline, f"ranks still running: {pids}"
        time.sleep(0.1)


# --------------------------------------------------------------------------- #
# A signal inside scipy's qhull (amfe.signals): held until the hull is built
# --------------------------------------------------------------------------- #
def test_signals_deferred_delivers_the_signal_when_the_block_ends():
    """Inside the block a SIGTERM is held; at its end the old handler runs once, with it."""
    from amfe.cli.interrupt import Interrupted, signals_raise
    from amfe.signals import signals_deferred
    done = []
    with signals_raise():
        handler = signal.getsignal(signal.SIGTERM)
        with pytest.raises(Interrupted) as exc:
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGTERM)
                sum(range(10_000))   # Python would run a handler here
                done.append(True)
        assert done == [True] and exc.value.signum == signal.SIGTERM
        assert signal.getsignal(signal.SIGTERM) is handler


def test_a_signal_during_the_hull_waits_for_qhull(monkeypatch):
    """`amfe dataset` ended 59 (PETSc's SEGV banner) in 1 of 30 SIGTERMs: the signal's
    exception cut scipy's ConvexHull in the middle (scipy issue 19383), which crashed at exit.
    hull_of now lets qhull finish first; the interrupt comes after it."""
    from scipy.spatial import ConvexHull

    from amfe.cli.interrupt import Interrupted, signals_raise
    from amfe.model import averages
    finished = []

    def hull_hit_by_a_signal(points, **kw):
        os.kill(os.getpid(), signal.SIGTERM)
        sum(range(10_000))
        hull = ConvexHull(points, **kw)
        finished.append(hull)
        return hull

    monkeypatch.setattr(averages, "ConvexHull", hull_hit_by_a_signal)
    cube = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    with signals_raise(), pytest.raises(Interrupted):
        averages.hull_of(cube)
    assert len(finished) == 1
