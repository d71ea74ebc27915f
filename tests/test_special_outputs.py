"""Outputs that are not regular files: written through or refused, never replaced (issue 31).

`amfe homogenize bed.h5 -o /dev/full` exited 0 and replaced the device with a regular file;
`-o /dev/stdout > s.json` left s.json empty and replaced the /dev/stdout link; `-o ''` exited
0 and wrote nothing. Tested with FIFOs and symbolic links in a temporary directory; devices
only through a mock of the file's kind (a real device is never touched).
"""
import errno
import json
import os
import stat
import subprocess
import sys
import threading

import pytest
from helpers import MPI_ENV, ROOT, cubic_lattice

import amfe.io.atomic as atomic
from amfe.errors import AmfeError
from amfe.io.atomic import NoSpaceError, atomic_write, write_json
from amfe.io.bedfile import write_bed
from amfe.io.paths import check_output
from amfe.model.bed import Bed

DATA = {"a": [1, 2, 3], "b": "x" * 100_000}   # more than a pipe buffer (64 KiB)


class FifoReader:
    """Reads a FIFO to its end in a thread (a FIFO's writer blocks until a reader opens it)."""

    def __init__(self, path):
        self.data = None
        self.thread = threading.Thread(target=self._read, args=(path,), daemon=True)
        self.thread.start()

    def _read(self, path):
        with open(path, "rb") as fh:
            self.data = fh.read()

    def text(self):
        self.thread.join(timeout=120)
        assert not self.thread.is_alive()
        return self.data.decode()


def test_a_fifo_is_written_through(tmp_path):
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    reader = FifoReader(fifo)
    write_json(fifo, DATA)
    assert json.loads(reader.text()) == DATA
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert os.listdir(tmp_path) == ["out.json"]   # no temporary file left


def test_a_link_is_kept_and_its_target_written(tmp_path):
    target = tmp_path / "run5.json"
    target.write_text("old")
    link = tmp_path / "latest.json"
    link.symlink_to(target.name)
    write_json(link, DATA)
    assert os.path.islink(link) and os.readlink(link) == "run5.json"
    assert json.loads(target.read_text()) == DATA
    dangling = tmp_path / "new.json"
    dangling.symlink_to("made.json")   # `echo > link` makes the target
    write_json(dangling, DATA)
    assert os.path.islink(dangling) and json.loads((tmp_path / "made.json").read_text()) == DATA
    assert sorted(os.listdir(tmp_path)) == ["latest.json", "made.json", "new.json", "run5.json"]


def test_a_link_to_a_fifo_is_written_through(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    link = tmp_path / "out.h5"
    link.symlink_to(fifo)
    reader = FifoReader(fifo)
    write_bed(link, Bed(*cubic_lattice(3)))   # h5py writes by name: through a temporary file
    assert reader.thread.join(120) is None and reader.data[:8] == b"\x89HDF\r\n\x1a\n"
    assert os.path.islink(link) and stat.S_ISFIFO(os.stat(link).st_mode)


def _as_device(monkeypatch, path, mode):
    """Make amfe see the regular file ``path`` as a device of ``mode`` (S_IFCHR, S_IFBLK)."""
    real = os.stat

    def fake_stat(p, *args, **kw):
        st = real(p, *args, **kw)
        if os.fspath(p) == os.fspath(path):
            fields = list(st)
            fields[0] = mode | 0o666
            return os.stat_result(fields)
        return st
    monkeypatch.setattr(atomic.os, "stat", fake_stat)


def test_a_character_device_is_written_through_not_replaced(tmp_path, monkeypatch):
    dev = tmp_path / "null"
    dev.write_bytes(b"")
    inode = os.stat(dev).st_ino
    _as_device(monkeypatch, dev, stat.S_IFCHR)
    assert check_output(dev) == str(dev)
    write_json(dev, DATA)
    assert os.stat(dev).st_ino == inode and json.loads(dev.read_text()) == DATA


def test_a_full_device_is_an_error_and_stays(tmp_path, monkeypatch):
    """/dev/full: every write is ENOSPC. The run must fail with one line, the device kept."""
    dev = tmp_path / "full"
    dev.write_bytes(b"")
    inode = os.stat(dev).st_ino
    _as_device(monkeypatch, dev, stat.S_IFCHR)

    def enospc(src, dst, *args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(atomic.shutil, "copyfileobj", enospc)
    with pytest.raises(NoSpaceError, match=f"no space left on {dev}"):
        write_json(dev, DATA)
    assert os.stat(dev).st_ino == inode and os.listdir(tmp_path) == ["full"]


@pytest.mark.parametrize("mode, kind", [(stat.S_IFBLK, "block device"),
                                        (stat.S_IFSOCK, "socket")])
def test_block_devices_and_sockets_are_refused(tmp_path, monkeypatch, mode, kind):
    dev = tmp_path / "sda"
    dev.write_bytes(b"keep")
    _as_device(monkeypatch, dev, mode)
    with pytest.raises(AmfeError, match=f"-o {dev}: it is a {kind}"):
        check_output(dev)
    with pytest.raises(AmfeError, match=f"it is a {kind}"):
        atomic_write(dev, lambda fh: fh.write(b"x"))
    assert dev.read_bytes() == b"keep"


def test_an_empty_name_is_refused():
    with pytest.raises(AmfeError, match="empty name"):
        write_json("", DATA)
    with pytest.raises(AmfeError, match="-o needs a file name"):
        check_output("")


# --------------------------------------------------------------------------- #
# The command line
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def bed(tmp_path_factory):
    path = tmp_path_factory.mktemp("special") / "bed.h5"
    write_bed(path, Bed(*cubic_lattice(3)))
    return str(path)


def _amfe(args, **kw):
    return subprocess.run([sys.executable, "-m", "amfe.cli", *args], cwd=ROOT, env=MPI_ENV,
                          timeout=120, **kw)


def test_cli_output_to_a_fifo(bed, tmp_path):
    fifo = tmp_path / "r.json"
    os.mkfifo(fifo)
    reader = FifoReader(fifo)
    p = _amfe(["homogenize", bed, "-o", fifo, "--quiet"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert json.loads(reader.text())["properties"]["Ex"] > 0
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_cli_output_to_a_link_to_stdout(bed, tmp_path):
    """`-o /dev/stdout > s.json`, with the link in a temporary directory: s.json gets the JSON
    (the table goes to stderr, as with -o -), the link stays."""
    link = tmp_path / "stdout"
    link.symlink_to("/proc/self/fd/1")
    out = tmp_path / "s.json"
    with open(out, "wb") as fh:
        p = _amfe(["homogenize", bed, "-o", link, "--quiet"], stdout=fh, stderr=subprocess.PIPE,
                  text=True)
    assert p.returncode == 0, p.stderr
    assert json.loads(out.read_text())["properties"]["Ex"] > 0
    assert "Ex" in p.stderr and os.readlink(link) == "/proc/self/fd/1"


@pytest.mark.parametrize("option, what", [("-o", "file"), ("--vtu", "directory")])
def test_cli_empty_output_name_is_an_error(bed, option, what):
    """`-o ''` (and `--vtu ''`) exited 0 and wrote nothing."""
    p = _amfe(["homogenize", bed, option, "", "--quiet"], capture_output=True, text=True)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines()[-1] == (f"amfe homogenize: error: {option} needs a "
                                                 f"{what} name, got ''")


def test_cli_bounds_to_stdout_writes_no_file_named_dash(bed, tmp_path):
    """`amfe homogenize bed.h5 --bc all -o -` wrote a file named "-" (and said "wrote -"); now
    the JSON alone on stdout, as for one condition."""
    p = subprocess.run([sys.executable, "-m", "amfe.cli", "homogenize", bed, "--bc", "all",
                        "-o", "-", "--quiet"], cwd=tmp_path, env=MPI_ENV, timeout=120,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert sorted(json.loads(p.stdout)["conditions"]) == ["kubc", "subc"]
    assert "== bounds" in p.stderr and os.listdir(tmp_path) == []
