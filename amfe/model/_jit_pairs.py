"""The compiled bond finder: find_pairs' bonds, bit for bit, in O(N + M) compiled loops.

Imported only by a process that asks for compiled kernels (a bond image of a large bed,
amfe.dataset.pixelkernel.warm in a process that images many beds); once it is loaded,
amfe.model.bonds.find_pairs takes it too. A module of its own, like amfe.dataset._jit,
so that numba's on-disk cache keeps its machine code between processes.
"""
from functools import cache

import numpy as np
from numba import njit

from amfe.model.bonds import COINCIDENT

# the 13 neighbour cells "after" a cell (and the cell itself, first): every pair of
# neighbouring cells is visited once
_FORWARD = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)
                     if (a, b, c) >= (0, 0, 0)], np.int64)


@njit(cache=True)
def _cell_table(c, side, lo, dims):
    """(start (cells+1,), members (N,)): the particles of each cell, in index order."""
    n = c.shape[0]
    flat = np.empty(n, np.int64)
    for k in range(n):
        q = 0
        for a in range(3):
            q = q * dims[a] + min(int((c[k, a] - lo[a]) / side), dims[a] - 1)
        flat[k] = q
    start = np.zeros(dims[0] * dims[1] * dims[2] + 1, np.int64)
    for k in range(n):
        start[flat[k] + 1] += 1
    for q in range(start.size - 1):
        start[q + 1] += start[q]
    members = np.empty(n, np.int64)
    fill = start[:-1].copy()
    for k in range(n):
        members[fill[flat[k]]] = k
        fill[flat[k]] += 1
    return start, members


@njit(cache=True)
def _by_first(n, pi, pj, pd, m):
    """The m pairs (pi, pj) with their d2 pd, sorted by (i, j): a counting sort by i, then each
    i's few partners (about six) by an insertion sort. Returns (i, j, d2), (m,) each."""
    start = np.zeros(n + 1, np.int64)
    for q in range(m):
        start[pi[q] + 1] += 1
    for k in range(n):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    i, j, d2 = np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m)
    for q in range(m):
        slot = fill[pi[q]]
        i[slot], j[slot], d2[slot] = pi[q], pj[q], pd[q]
        fill[pi[q]] += 1
    for k in range(n):
        for a in range(start[k] + 1, start[k + 1]):
            vj, vd = j[a], d2[a]
            b = a - 1
            while b >= start[k] and j[b] > vj:
                j[b + 1], d2[b + 1] = j[b], d2[b]
                b -= 1
            j[b + 1], d2[b + 1] = vj, vd
    return i, j, d2


@njit(cache=True)
def _cell_pair(cs, rs, members, span, near, order, out, m):
    """Append the bonds between the particles span[0]:span[1] and span[2]:span[3] (cell
    order; the same cell when span[0] == span[2]) to out = (i, j, d2) from m; returns the
    new m, or -1 at a pair closer than near x max(R_i, R_j), -2 when out is full."""
    pi, pj, pd = out
    for p in range(span[0], span[1]):
        q0 = p + 1 if span[2] == span[0] else span[2]
        xp, yp, zp, rp = cs[p, 0], cs[p, 1], cs[p, 2], rs[p]
        for q in range(q0, span[3]):
            dx = cs[q, 0] - xp
            dy = cs[q, 1] - yp
            dz = cs[q, 2] - zp
            xx, yy, zz = dx * dx, dy * dy, dz * dz
            if order == 0:
                d2 = (xx + yy) + zz
            elif order == 1:
                d2 = (xx + zz) + yy
            else:
                d2 = xx + (yy + zz)
            reach = rp + rs[q]
            if d2 < reach * reach:
                tiny = near * max(rp, rs[q])
                if d2 <= tiny * tiny:
                    return -1
                if m == pi.size:
                    return -2
                u, v = members[p], members[q]
                pi[m], pj[m], pd[m] = min(u, v), max(u, v), d2
                m += 1
    return m


@njit(cache=True)
def bonded_pairs(c, r, near, order, forward, cap):
    """The bonds of particles c (N,3) [m], r (N,) [m]: i < j with |x_j - x_i|^2 < (R_i + R_j)^2.

    Returns (i (M,), j (M,), L (M,) [m], status), sorted by (i, j). A cell list of side
    2 max(R) (every bond joins neighbouring cells), each pair of neighbouring cells
    visited once (``forward``: the 13 offsets after a cell, and the cell itself), then
    sorted by :func:`_by_first` in O(M). d.d is summed in the order ``order`` names (see
    :func:`bonds`). status 0: done; -1: the caller must take the numpy path (a pair
    closer than near x max(R_i, R_j), which find_pairs names as coincident, or a bed too
    sparse for a dense cell table, more than 8 N + 64 cells); -2: more than ``cap`` bonds.
    """
    n = r.size
    empty = np.empty(0, np.int64)
    side = 2.0 * r.max()
    lo = np.empty(3)
    dims = np.empty(3, np.int64)
    extent = 1.0
    for a in range(3):
        lo[a] = c[:, a].min()
        extent *= (c[:, a].max() - lo[a]) / side + 1.0
    if extent > 8 * n + 64:                # in floats: far-flung beds would overflow int64
        return empty, empty, np.empty(0), -1
    for a in range(3):
        dims[a] = int((c[:, a].max() - lo[a]) / side) + 1
    start, members = _cell_table(c, side, lo, dims)
    cs = np.empty((n, 3))                  # centres and radii in cell order (locality)
    rs = np.empty(n)
    for p in range(n):
        cs[p] = c[members[p]]
        rs[p] = r[members[p]]
    pi, pj, pd = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap)
    m = 0
    for x in range(dims[0]):
        for y in range(dims[1]):
            for z in range(dims[2]):
                a = (x * dims[1] + y) * dims[2] + z
                for o in range(forward.shape[0]):
                    bx, by, bz = x + forward[o, 0], y + forward[o, 1], z + forward[o, 2]
                    if not (0 <= bx < dims[0] and 0 <= by < dims[1] and 0 <= bz < dims[2]):
                        continue
                    b = (bx * dims[1] + by) * dims[2] + bz
                    m = _cell_pair(cs, rs, members, (start[a], start[a + 1], start[b],
                                                     start[b + 1]), near, order, (pi, pj, pd), m)
                    if m < 0:   # -1: coincident centres, -2: more bonds than cap
                        return empty, empty, np.empty(0), m
    i, j, d2 = _by_first(n, pi, pj, pd, m)
    return i, j, np.sqrt(d2), 0


@cache
def einsum_order():
    """The order in which numpy's einsum("ij,ij->i") sums x^2, y^2 and z^2 here: 0 for
    (x + y) + z, 1 for (x + z) + y, 2 for x + (y + z), None for none of them.

    amfe.model.bonds decides a bond and measures its length with that einsum, whose
    order is its SIMD loop's (numpy 1.24 on x86-64: (x + z) + y), so the kernel asks
    rather than assumes. Probed on 3 000 random vectors, at both 8-byte alignments.
    """
    raw = np.random.default_rng(0).normal(size=9_001)
    orders = []
    for d in (raw[:9_000].reshape(-1, 3), raw[1:].reshape(-1, 3)):
        e = np.einsum("ij,ij->i", d, d)
        s = d * d
        sums = ((s[:, 0] + s[:, 1]) + s[:, 2], (s[:, 0] + s[:, 2]) + s[:, 1],
                s[:, 0] + (s[:, 1] + s[:, 2]))
        orders.append({k for k, v in enumerate(sums) if np.array_equal(v, e)})
    both = orders[0] & orders[1]
    return min(both) if both else None


def _first_cap(n):
    """Room for the bonds of n particles at the first try: 8 a particle (about 5 in beds)."""
    return 8 * n + 64


def bonds(centers, radii):
    """(i, j, L) of amfe.model.bonds.find_pairs' bonds and contact_geometry's lengths [m], bit
    for bit, or None where the caller must take the numpy path (coincident centres, a bed
    too sparse for the cell table, an einsum whose order the kernel does not know).

    centers (N, 3) [m], radii (N,) [m]: C-contiguous float64.
    """
    order = einsum_order()
    if order is None or not radii.size:
        return None
    cap = _first_cap(radii.size)
    while True:
        i, j, length, status = bonded_pairs(centers, radii, 2.0 * COINCIDENT, order, _FORWARD,
                                            cap)
        if status != -2:
            return (i, j, length) if status == 0 else None
        cap *= 2
