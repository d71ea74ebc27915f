"""Fuzz the output path with special files (issue 31): FIFOs, links, loops, empty names.

The generator of tests/test_fuzz.py (kept in its own file: that one is near the 400-line
limit) draws ``-o`` of `amfe homogenize` and `amfe predict` from special paths in a temporary
directory and checks, besides the two allowed endings of check_run (exit 0 with a finite
result, or exit 2 with one line and no file written), that the special file is still what it
was: a FIFO stays a FIFO and its reader gets the JSON, a link stays a link and its target
gets the JSON, and nothing is ever replaced.
"""
import errno
import json
import os
import stat
import tempfile
import threading

from hypothesis import given
from hypothesis import strategies as st
from test_fuzz import (
    FUZZ,
    _base,
    _copy_writer,
    _homogenize_ok,
    _predict_ok,
    _strict_json,
    check_run,
    tiny,  # noqa: F401 - a fixture, used by name
)

SPECIAL = ["FIFO", "LINK", "DANGLING", "LINK_TO_FIFO", "LINK_TO_DIR", "LOOP", "EMPTY",
           "LINK_INTO_MISSING_DIR"]


class Special:
    """One special output path in directory ``d``; after the run, :meth:`check` says it kept
    its kind, and returns the JSON text written through it (None if nothing was)."""

    def __init__(self, kind, d):
        self.kind, self.d, self.text = kind, d, None
        fifo, target = os.path.join(d, "fifo"), os.path.join(d, "target.json")
        self.path = {"FIFO": fifo, "EMPTY": ""}.get(kind, os.path.join(d, "out.json"))
        self.target = {"FIFO": fifo, "LINK_TO_FIFO": fifo, "LINK": target,
                       "DANGLING": target}.get(kind)
        if kind in ("FIFO", "LINK_TO_FIFO"):
            os.mkfifo(fifo)
            self.reader = threading.Thread(target=self._read, daemon=True)
            self.reader.start()
        if kind == "LINK":
            with open(target, "w") as fh:
                fh.write("old")
        link_to = {"LINK": target, "DANGLING": target, "LINK_TO_FIFO": fifo, "LINK_TO_DIR": d,
                   "LOOP": os.path.join(d, "loop"),
                   "LINK_INTO_MISSING_DIR": os.path.join(d, "no", "x.json")}.get(kind)
        if link_to:
            os.symlink(link_to, self.path)
        if kind == "LOOP":
            os.symlink(self.path, os.path.join(d, "loop"))
        self.links = {n: os.readlink(os.path.join(d, n)) for n in os.listdir(d)
                      if os.path.islink(os.path.join(d, n))}

    def _read(self):
        with open(self.target, "rb") as fh:
            self.text = fh.read().decode()

    def check(self):
        if self.kind in ("FIFO", "LINK_TO_FIFO"):
            if self.reader.is_alive():   # nothing was written: let the reader see the end
                try:
                    os.close(os.open(self.target, os.O_WRONLY | os.O_NONBLOCK))
                except OSError as exc:   # ENXIO: no reader left, it has just read all and ends
                    if exc.errno != errno.ENXIO:
                        raise
            self.reader.join(timeout=60)
            assert stat.S_ISFIFO(os.lstat(self.target).st_mode), "the FIFO was replaced"
        elif self.target and os.path.exists(self.target):
            with open(self.target) as fh:
                self.text = fh.read()
        for name, to in self.links.items():   # every link kept, pointing where it did
            assert os.readlink(os.path.join(self.d, name)) == to, f"{name} was replaced"
        return None if self.text in (None, "", "old") else self.text


def fuzz_special(command, data, bed, extra, ok):
    kind = data.draw(st.sampled_from(SPECIAL), label="-o")
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "bed.h5")
        _copy_writer(_base(bed))(path)
        out = Special(kind, d)
        code = check_run(command, [path, *extra, "-o", out.path], d, [path], None,
                         lambda stdout, output: None, kind)
        text = out.check()
        if code == 0:   # written through the special file, never beside it
            assert kind in ("FIFO", "LINK", "DANGLING", "LINK_TO_FIFO"), kind
            ok(text)
        else:
            assert kind in ("LINK_TO_DIR", "LOOP", "EMPTY", "LINK_INTO_MISSING_DIR"), kind
            assert text is None


@FUZZ
@given(data=st.data())
def test_fuzz_homogenize_special_outputs(tiny, data):
    fuzz_special("homogenize", data, tiny[1], ["--quiet"],
                 lambda text: _as_file(text, lambda f: _homogenize_ok(None, f)))


@FUZZ
@given(data=st.data())
def test_fuzz_predict_special_outputs(tiny, data):
    fuzz_special("predict", data, tiny[1], ["--model", tiny[0]],
                 lambda text: _as_file(text, lambda f: _predict_ok("", f)))


def _as_file(text, check):
    """check(path) of the JSON ``text`` in a file (the checks of tests/test_fuzz.py read one)."""
    _strict_json(text)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "out.json")
        with open(path, "w") as fh:
            json.dump(json.loads(text), fh)
        check(path)
