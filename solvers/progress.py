"""Progress lines of a solve: today's one line per phase, and on long solves the phases' starts.

Every solve logs one line when a phase ends (the frame, the solver choice, each operator's
assembly and set-up, each load case; :func:`amfe.solvers.driver.homogenize_bed`). On a bed of
more than :data:`PROGRESS_PARTICLES` particles (issue 48: two silent stretches of about 12 s
on the paper's bed) :class:`Progress` adds a line when each phase starts (the frame's bonds
and springs, the element blocks, each operator), numbers the load cases i/n and, after each,
estimates the time left: the cases left times the mean case time so far [s]. The lines go to
the caller's ``log`` (rank 0's logger, :func:`amfe.solvers.driver._progress`); the face
decides whether they print (``amfe homogenize --quiet``, :mod:`amfe.io.console`).
"""
import math
import time

#: Beds with more particles than this get the phases' start lines, the case numbers and the
#: time left (read when a solve starts, so a test may lower it).
PROGRESS_PARTICLES = 50_000

#: [s] at least this long between two block-CG iteration lines (the 6 load cases of a long
#: solve run together in one block CG, :mod:`amfe.solvers.blocksolve`).
ITERATION_EVERY = 2.0


class Progress:
    """A solve's progress lines: ``progress(line)`` logs one of every solve's lines;
    :meth:`phase` logs a start line, on long solves only; :meth:`case` a load case's line.

    log: a callable taking one line (or None: nothing is logged); n_particles: the input
    bed's particle count; n_cases: the load cases of the solve (all groups together).
    """

    def __init__(self, log, n_particles, n_cases=6):
        self.log = log
        self.long = log is not None and n_particles > PROGRESS_PARTICLES
        self.n_cases = n_cases
        self.case_seconds = []   # [s] of each case logged so far
        self.solved = 0          # load cases solved so far
        self.started = {}        # phase name -> perf_counter() at its start line

    def __call__(self, line):
        if self.log is not None:
            self.log(line)

    def phase(self, name, line):
        """On a long solve: log ``line`` as phase ``name``'s start; :meth:`done` times it."""
        self.started[name] = time.perf_counter()
        if self.long:
            self.log(line)

    def done(self, name, line):
        """On a long solve: log ``line`` with the seconds since phase ``name`` started."""
        if self.long:
            self.log(f"{line} in {time.perf_counter() - self.started.pop(name):.2f} s")

    def case(self, case, path, solved=None):
        """Log a load case's line (``case``: a :class:`~amfe.solvers.operator.CaseSolution`,
        ``path``: how it was solved). On a long solve the case is numbered i/n_cases and the
        time left follows: the cases not yet solved (``solved``: how many are, default the
        cases logged) times the mean case time so far, after each case solved one at a time
        and once after the last of a block's cases."""
        self.case_seconds.append(float(case.seconds))
        line = f"{case.iterations} iterations, {case.seconds:.2f} s ({path})"
        if not self.long:
            self(f"load case {case.name}: {line}")
            return
        i = len(self.case_seconds)
        self.solved = max(self.solved, i if solved is None else solved)
        self.log(f"load case {case.name} ({i}/{self.n_cases}): {line}")
        if i == self.solved:
            self.log(f"time left: about {self.time_left():.1f} s "
                     f"({self.n_cases - self.solved} load case(s) left)")

    def live(self, path):
        """A callable logging each case as it is solved (one at a time), or None."""
        return (lambda case: self.case(case, path)) if self.long else None

    def iteration(self, it, ratio):
        """Block CG's iteration ``it`` (0: the start): ``ratio``, the largest residual of a
        running case over its tolerance. Every :data:`ITERATION_EVERY` s a line with the
        iterations and the time left, from the mean rate of convergence so far:
        log(ratio) / log(1 / rate) iterations left, at the mean time of one."""
        if not self.long:
            return
        now = time.perf_counter()
        if it == 0:   # its V-cycles made: the iterations start
            self.first, self.shown = (now, ratio), now
            self.log(f"block CG: started, largest residual {ratio:.3g} x its tolerance")
            return
        start, ratio0 = self.first
        if ratio <= 1.0 or now - self.shown < ITERATION_EVERY:
            return
        self.shown = now
        per = (now - start) / it   # [s] one iteration
        left = "not yet known (no decrease)"
        if 0.0 < ratio < ratio0:
            its_left = math.log(ratio) / (math.log(ratio0 / ratio) / it)
            left = f"about {its_left * per:.1f} s ({math.ceil(its_left)} iterations)"
        self.log(f"block CG: iteration {it}, largest residual {ratio:.3g} x its tolerance; "
                 f"time left: {left}")

    def time_left(self):
        """[s]: the cases not yet solved times the mean case time so far (0 after the last)."""
        left = max(self.n_cases - self.solved, 0)
        mean = sum(self.case_seconds) / len(self.case_seconds) if self.case_seconds else 0.0
        return left * mean
