"""Memory estimates, checked before any large allocation (bed generation, reading, solving).

An absurd request (``amfe pack --size 100 100 100``, a bed file declaring 2e9
particles) is refused with its estimate before anything is allocated, instead
of running the machine out of memory. The constants below are measured peak
resident set sizes (Linux ru_maxrss or VmHWM minus the interpreter's) on
generated beds of 900 to 130 000 particles, rounded up by about 10 %:

- generation (:func:`amfe.model.bed.generate_bed`, a* limiting included):
  0.55-0.62 kB per lattice site on 4 000-142 000 sites (1.0-1.3 kB until
  the a* limit's checking pass stopped rebuilding every bond's geometry),
  plus the index grid of :func:`amfe.model.bed.hcp_lattice` (about 120 B
  per grid point);
- reading a bed: its float64 arrays, twice (a converted copy);
- homogenizing (frame, assembly, GAMG, six solves, averages): 17.4-17.7 kB
  per particle on one rank, 13.9-14.9 kB per particle on each of two ranks:
  every rank builds the whole frame (about 11.3 kB per particle, replicated)
  and holds its share of the matrices and the preconditioner (6.2 kB per
  particle in all);
- a sparse Cholesky solve (one rank, CHOLMOD): the frame and assembly as
  above plus the factor, 143-222 B per unit of predicted fill x (particles +
  bonds) (:func:`amfe.solvers.choice.solve_features`) and about 10 MB fixed;
  34-91 kB per particle on beds of 900-20 000 particles, fill 11-77.

The default limit is half the machine's physical memory (in total over the
ranks; with several machines, half of each machine's memory summed).
"""
import math
import os

from amfe.errors import AmfeError

SITE_BYTES = 700
"""Bytes per lattice site generated, beside the grid (measured 0.55-0.62 kB)."""
GRID_BYTES = 128
"""Bytes per point of the lattice index grid (int64 indices, coordinates, masks)."""
READ_BYTES = 64
"""Bytes per particle read from a bed file (centres and radius, float64, converted once)."""
FRAME_BYTES = 12_500
"""Bytes per particle that every rank holds for the frame (measured 11.3 kB)."""
SOLVE_BYTES = 7_000
"""Bytes per particle of the distributed matrices, preconditioner and vectors, over all
ranks (measured 6.2 kB)."""
FACTOR_BYTES = 220
"""Bytes of a Cholesky factor per unit of fill ratio x (particles + bonds) (measured 143-222)."""
FACTOR_OVERHEAD = 16 * 2**20
"""Fixed bytes of a factorisation (workspace; about 10 MB measured on a 900-particle bed)."""

GIB = 2.0**30
UNITS = {"": 1, "B": 1, "K": 2**10, "KB": 2**10, "KIB": 2**10, "M": 2**20, "MB": 2**20,
         "MIB": 2**20, "G": 2**30, "GB": 2**30, "GIB": 2**30, "T": 2**40, "TB": 2**40,
         "TIB": 2**40}


def machine_memory():
    """Physical memory of this machine [bytes] (0 when the system does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return 0


def default_limit(memory=None):
    """The default limit: half of ``memory`` [bytes] (default: this machine's)."""
    memory = machine_memory() if memory is None else memory
    return memory / 2 if memory > 0 else math.inf


def parse_size(text):
    """Bytes of a size such as '8G', '500M', '1.5GiB' or '123456' (AmfeError if malformed)."""
    s = str(text).strip().upper().replace(" ", "")
    number = s.rstrip("KMGTIB")
    unit = s[len(number):]
    try:
        value = float(number)
    except ValueError:
        value = math.nan
    if unit not in UNITS or not (math.isfinite(value) and value > 0):
        raise AmfeError(f"--max-memory needs a positive size such as 8G, 500M or 1.5GiB, "
                        f"got {text!r}")
    return value * UNITS[unit]


def lattice_counts(size, r0):
    """(grid points, upper bound on sites) of :func:`amfe.model.bed.hcp_lattice` (exact ints).

    Python integers, so a box of 1e300 m gives a huge number, not an overflow.
    """
    dz, dy = 2.0 * r0 * math.sqrt(2.0 / 3.0), math.sqrt(3.0) * r0
    grid, sites = 1, 1
    for length, spacing, pad in ((size[0], 2.0 * r0, 4), (size[1], dy, 4), (size[2], dz, 2)):
        steps = length / spacing
        if not math.isfinite(steps):
            return math.inf, math.inf
        grid *= int(math.ceil(steps)) + pad
        sites *= max(int(math.floor(max(length - 2.0 * r0, 0.0) / spacing)) + 2, 0)
    return grid, sites


def generation_bytes(size, r0):
    """Estimated peak bytes of generating the bed of box ``size`` [m] and base radius r0 [m]."""
    grid, sites = lattice_counts(size, r0)
    return GRID_BYTES * grid + SITE_BYTES * sites


def solve_bytes(n_particles, ranks=1):
    """Estimated peak bytes, summed over ``ranks``, of homogenizing ``n_particles``."""
    return n_particles * (FRAME_BYTES * ranks + SOLVE_BYTES)


def direct_bytes(n_particles, n_bonds, fill_ratio):
    """Estimated peak bytes of a one-rank Cholesky solve of a frame (fill: predicted fill ratio)."""
    return (n_particles * (FRAME_BYTES + SOLVE_BYTES) + FACTOR_OVERHEAD
            + FACTOR_BYTES * fill_ratio * (n_particles + n_bonds))


def check_memory(estimate, limit, what, default=None, fix="make it smaller"):
    """Raise AmfeError when ``estimate`` [bytes] exceeds ``limit`` [bytes].

    limit None: ``default`` (default: :func:`default_limit`, half this
    machine's memory). ``what`` says what would be allocated (e.g.
    "generating a bed of 1.3e+11 lattice sites"); ``fix``: how to make it smaller.
    """
    given = limit is not None
    limit = float(limit) if given else (default_limit() if default is None else default)
    if estimate <= limit:
        return
    whose = "the limit given" if given else "half of the machine's memory, the default limit"
    raise AmfeError(f"{what} needs about {_gib(estimate)} of memory, more than {_gib(limit)} "
                    f"({whose}); {fix}, or raise the limit with --max-memory "
                    "(max_memory= in Python) if the machine has the memory")


def _gib(nbytes):
    try:
        return f"{float(nbytes) / GIB:.3g} GiB"
    except OverflowError:  # a Python int beyond float range (a box of 1e300 m)
        return f"10^{len(str(int(nbytes))) - 10} GiB"
