"""Progress lines on long solves (issue 48, item 5): the phases' starts, the case count and
the time left on beds above amfe.solvers.progress.PROGRESS_PARTICLES; --quiet silences them.

The threshold is lowered for the test's small beds (it is read when a solve starts).
"""
import json
import re
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

from amfe.io.bedfile import write_bed
from amfe.model.bed import Bed, generate_bed
from amfe.solvers import progress
from tests.cli_fixtures import run_main
from tests.test_golden import blank_timings

Case = namedtuple("Case", "name iterations seconds")
STAMP = re.compile(r"^\[\s*\d+\.\d\d s\] ")   # the console's seconds since the start
CASE = re.compile(r"^load case (\w+) \((\d)/6\): (\d+) iterations, (\d+\.\d\d) s \(([\w ]+)\)$")
LEFT = re.compile(r"^time left: about (\d+\.\d) s \((\d) load case\(s\) left\)$")


@pytest.fixture(scope="module")
def beds(tmp_path_factory):
    """(a small bed's file, the same bed with a floating pair that is removed, with a warning)."""
    d = tmp_path_factory.mktemp("progress")
    bed = generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), seed=1)
    r = float(bed.radii.mean())
    far = bed.centers.max(axis=0) + [10 * r, 0, 0]   # two bonded particles off the bed
    floating = Bed(centers=np.vstack([bed.centers, far, far + [1.5 * r, 0, 0]]),
                   radii=np.concatenate([bed.radii, [r, r]]))
    paths = str(d / "bed.h5"), str(d / "floating.h5")
    write_bed(paths[0], bed)
    write_bed(paths[1], floating)
    return paths


def homogenize(path, out, *flags):
    code, stdout, err = run_main(["homogenize", path, "-o", out, "--rtol", "1e-8", *flags])
    assert code == 0, err
    lines = [STAMP.sub("", line) for line in err.splitlines()]
    with open(out) as fh:   # the JSON, its timings blanked (as the golden test does)
        return stdout, lines, json.dumps(blank_timings(json.load(fh)))


def test_long_solve_logs_each_phase_the_case_count_and_the_time_left(beds, tmp_path,
                                                                     monkeypatch):
    short_out, short, short_json = homogenize(beds[0], tmp_path / "short.json")
    monkeypatch.setattr(progress, "PROGRESS_PARTICLES", 10)
    long_out, lines, long_json = homogenize(beds[0], tmp_path / "long.json")
    assert long_json == short_json            # the JSON does not depend on the lines
    def timeless(text):
        return [re.sub(r"\d+(\.\d+)?(e[-+]?\d+)? s", "T s", s) for s in text]
    # nor does the table on stdout (but for its timings)
    assert timeless(long_out.replace("long.json", "short.json").splitlines()) == \
        timeless(short_out.splitlines())
    # below the threshold: today's lines only (no start line, no count, no time left)
    assert not any("building" in s or "time left" in s or "/6)" in s for s in short)
    # above it: today's lines in the same order, the cases numbered, and the new lines between
    numbered = timeless(re.sub(r" \(\d/6\):", ":", s) for s in lines)
    assert [s for s in numbered if s in timeless(short)] == timeless(short)
    phases = [r"frame: building it from 28 particles \(", r"frame: \d+ contacts found in T s$",
              r"frame: 28 load-carrying particles; evaluating the springs of \d+ bonds$",
              r"frame: springs evaluated in T s$", r"frame: 28 load-carrying particles \(0 ",
              r"solver: ", r"assembly: the element blocks of \d+ bonds$",
              r"assembly: element blocks made in T s$",
              r"operator for xx, yy, zz, yz, xz, xy: assembling the matrix, then setting up",
              r"operator for xx, yy, zz, yz, xz, xy: assembled in T s, \w+ set up in T s$",
              r"load case\(s\) xx, yy, zz, yz, xz, xy: solving$", r"load case xx: "]
    found = [next(i for i, s in enumerate(numbered) if re.match(p, s)) for p in phases]
    assert found == sorted(found), lines      # in the order the phases run
    cases = [CASE.match(s) for s in lines if CASE.match(s)]
    lefts = [LEFT.match(s) for s in lines if LEFT.match(s)]
    assert [int(m[2]) for m in cases] == [1, 2, 3, 4, 5, 6]
    assert [int(m[2]) for m in lefts] == [5, 4, 3, 2, 1, 0]
    # each time left follows its case: the cases left times the mean case time so far
    for k, (case, left) in enumerate(zip(cases, lefts), start=1):
        assert lines.index(left[0]) == lines.index(case[0]) + 1
        mean = np.mean([float(m[4]) for m in cases[:k]])
        assert float(left[1]) == pytest.approx((6 - k) * mean, abs=0.06 * (6 - k) + 0.05)
    assert float(lefts[-1][1]) == 0.0
    times = [float(m[1]) for m in lefts]
    assert all(t >= 0 for t in times)


def test_time_left_is_cases_left_times_the_mean(monkeypatch):
    logged = []
    monkeypatch.setattr(progress, "PROGRESS_PARTICLES", 0)
    p = progress.Progress(logged.append, 1, n_cases=3)
    for seconds, left in ((2.0, 4.0), (4.0, 3.0), (3.0, 0.0)):
        p.case(Case("xx", 1, seconds), "one at a time")
        assert p.time_left() == pytest.approx(left)
    assert logged[-1] == "time left: about 0.0 s (0 load case(s) left)"
    assert logged[0] == "load case xx (1/3): 1 iterations, 2.00 s (one at a time)"
    assert logged[1] == "time left: about 4.0 s (2 load case(s) left)"
    # a block of 2 solved together, 1 case left: one time-left line, after the block
    block, p = [], progress.Progress(None, 1, n_cases=3)
    p.log, p.long = block.append, True
    for name in ("xx", "yy"):
        p.case(Case(name, 5, 1.5), "block", solved=2)
    assert block == ["load case xx (1/3): 5 iterations, 1.50 s (block)",
                     "load case yy (2/3): 5 iterations, 1.50 s (block)",
                     "time left: about 1.5 s (1 load case(s) left)"]
    quiet = []
    small = progress.Progress(quiet.append, 0, n_cases=3)   # not above the threshold
    small.phase("x", "start")
    small.case(Case("xx", 1, 1.0), "block")
    assert quiet == ["load case xx: 1 iterations, 1.00 s (block)"]


def test_block_cg_lines_estimate_the_time_left_from_the_rate(monkeypatch):
    """Residual 1e4 x the tolerance falling tenfold an iteration: 4 - it iterations left."""
    logged, clock = [], iter(np.arange(0.0, 10.0))
    monkeypatch.setattr(progress, "PROGRESS_PARTICLES", 0)
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    p = progress.Progress(logged.append, 1)
    for it in range(5):
        p.iteration(it, 10.0 ** (4 - it))   # 1 s an iteration; done (ratio 1) at it 4
    assert logged[0] == "block CG: started, largest residual 1e+04 x its tolerance"
    # every 2 s: iteration 2 (1 and 3: too soon); 100 x, two more tenfold steps, 2 s
    assert logged[1:] == ["block CG: iteration 2, largest residual 100 x its tolerance; "
                          "time left: about 2.0 s (2 iterations)"], logged


def test_quiet_silences_the_progress_lines_and_keeps_the_warnings(beds, tmp_path, monkeypatch):
    monkeypatch.setattr(progress, "PROGRESS_PARTICLES", 10)
    _, loud, loud_json = homogenize(beds[1], tmp_path / "loud.json")
    _, quiet, quiet_json = homogenize(beds[1], tmp_path / "quiet.json", "--quiet")
    assert quiet_json == loud_json
    warnings = [s for s in loud if s.startswith("amfe: warning: ")]
    assert len(warnings) == 1 and "2 particles (6.7 %" in warnings[0], loud
    assert any(LEFT.match(s) for s in loud) and any(s.startswith("frame: building") for s in loud)
    assert quiet == warnings                  # --quiet: the warnings alone
def test_block_cg_of_a_long_solve_logs_its_iterations(tmp_path, monkeypatch):
    """GAMG's block CG (the six cases together): iteration lines with a time left >= 0, the
    cases numbered, and one time-left line after the block, 0 s."""
    path = str(tmp_path / "gamg.h5")
    write_bed(path, generate_bed(size=(0.2e-3, 0.2e-3, 0.12e-3), seed=2))
    monkeypatch.setattr(progress, "PROGRESS_PARTICLES", 10)
    monkeypatch.setattr(progress, "ITERATION_EVERY", 0.0)
    _, lines, _ = homogenize(path, tmp_path / "r.json", "--solver", "gamg")
    iters = [re.match(r"^block CG: iteration (\d+), largest residual (\S+) x its tolerance; "
                      r"time left: about (\d+\.\d) s \((\d+) iterations\)$", s) for s in lines]
    iters = [m for m in iters if m]
    assert len(iters) >= 3 and [int(m[1]) for m in iters] == list(range(1, len(iters) + 1))
    assert all(float(m[3]) >= 0 and float(m[2]) > 1 for m in iters)
    cases = [CASE.match(s) for s in lines if CASE.match(s)]
    assert [int(m[2]) for m in cases] == [1, 2, 3, 4, 5, 6] and cases[0][5] == "block"
    assert lines.index(iters[-1][0]) < lines.index(cases[0][0])
    assert lines.index(iters[0][0]) == 1 + lines.index(next(s for s in lines if s.startswith(
        "block CG: started, largest residual ")))
    assert max(int(m[3]) for m in cases) == len(iters) + 1   # the last iteration ends it
    assert [s for s in lines if LEFT.match(s)] == ["time left: about 0.0 s (0 load case(s) left)"]
    assert lines.index(cases[-1][0]) + 1 == lines.index("time left: about 0.0 s (0 load case(s) "
                                                        "left)")


def test_help_and_docs_give_the_threshold():
    code, out, _ = run_main(["homogenize", "--help"])
    shown = f"{progress.PROGRESS_PARTICLES:,}".replace(",", " ")   # 50 000
    assert code == 0 and shown in " ".join(out.split()) and "--quiet" in out
    with open(Path(__file__).resolve().parents[1] / "docs" / "diagnostics.md") as fh:
        assert f"more than {shown} particles" in fh.read()


def test_a_warning_on_a_closed_stderr_does_not_fail_the_work(monkeypatch):
    """A rank whose mpirun was killed has no reader on stderr: its warnings raise
    BrokenPipeError on write. The console drops them instead of raising into the solve,
    which `amfe dataset` recorded as a failed bed and kept on resume (tests/
    test_dataset_faults.py caught it on a fast machine)."""
    import io
    import logging

    from amfe.io.console import LOGGER, Console

    class Closed(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr("sys.stderr", Closed())
    logger = logging.getLogger(LOGGER)
    handler = Console()
    logger.addHandler(handler)
    try:
        logger.warning("a warning nobody can read")    # raised BrokenPipeError before
        handler.emit(logging.makeLogRecord({"msg": "direct", "levelno": logging.WARNING}))
    finally:
        logger.removeHandler(handler)
