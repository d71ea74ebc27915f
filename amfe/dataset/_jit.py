"""The numba-compiled loops of imaging (amfe.dataset.pixelkernel), imported only when they run.

A module of its own so that numba's on-disk cache (cache=True) keeps the
machine code between processes: only the first run on a machine compiles
(about 10 s); later ones load it (well under 1 s).
"""
import hashlib
import inspect
import math
from functools import cache

import numpy as np
from numba import njit
from numba.extending import register_jitable

from amfe.model import springs as springs_model

_Q_BITS = 17   # bits of a chord end in a key (amfe.dataset.images._Q_BITS)


@njit(cache=True)
def _sort_run(keys, a, b):
    """Sort keys[a:b] in place: a line holds a few chords (about six in a generated bed).

    Insertion without branches on the data: inserting v into the sorted
    keys[a:m] gives new[q] = min(keys[q], max(keys[q-1], v)), so every step is
    a min and a max (no mispredicted jumps, which made a plain insertion sort
    a third of the kernel's time). Long runs go to np.sort.
    """
    if b - a > 32:
        keys[a:b] = np.sort(keys[a:b])
        return
    for m in range(a + 1, b):
        v = keys[m]
        keys[m] = max(keys[m - 1], v)
        for q in range(m - 1, a, -1):
            keys[q] = min(keys[q], max(keys[q - 1], v))
        keys[a] = min(keys[a], v)


@njit(cache=True)
def _layer_of(s, z_edges, t):
    """The layer of a chord starting at s [m]: floor((s - z_0) / t), clipped (the numpy path's)."""
    return min(max(int(math.floor((s - z_edges[0]) / t)), 0), z_edges.size - 2)


@njit(cache=True)
def _row_chords(c, r, span, y, xs, z, buf):
    """Chords of spheres span = (lo, hi) through the sample lines at y; returns their count.

    xs = (xmid, j0): column samples [m] and each sphere's first column at or
    right of its centre; z = (z_edges, t, z_lo, z_hi, scale, ...): layer faces
    [m], thickness [m], the box in z [m], quantisation levels per metre; buf
    = (group, key) arrays to fill. The covered columns of a row are one run
    (dx^2 grows away from the centre), scanned out from j0 while
    (R^2 - dx^2) - dy^2 > 0, the numpy path's test in its order. Each chord is
    cut at the layer faces it crosses; a piece of layer l in column ix is
    group l * columns + ix with key qs << 17 | qe, as the numpy path keys it.
    The layer of a chord's start lies between those of max(z_c - sqrt(R^2), z_lo)
    and max(z_c, z_lo) (the start does, and the layer is monotone in it): where
    they agree, no division is needed.
    """
    xmid, j0 = xs
    z_edges, t, z_lo, z_hi, scale = z[0], z[1], z[2], z[3], z[4]
    group, keys = buf
    nx = xmid.size
    top_layer = z_edges.size - 2
    m = 0
    for k in range(span[0], span[1]):
        dy = y - c[k, 1]
        dy2 = dy * dy
        rr = r[k] * r[k]
        if dy2 >= rr:
            continue
        cx, zc = c[k, 0], c[k, 2]
        l_lo = _layer_of(max(zc - math.sqrt(rr), z_lo), z_edges, t)   # half <= sqrt(rr)
        sure = l_lo == _layer_of(max(zc, z_lo), z_edges, t)
        for step in (1, -1):
            ix = j0[k] if step == 1 else j0[k] - 1
            while 0 <= ix < nx:
                dx = xmid[ix] - cx
                half2 = (rr - dx * dx) - dy2
                if not half2 > 0.0:
                    break
                half = math.sqrt(half2)
                s = max(zc - half, z_lo)
                e = min(zc + half, z_hi)
                if e > s:
                    layer = l_lo if sure else _layer_of(s, z_edges, t)
                    while True:
                        face = z_edges[layer + 1]
                        top = face if (layer < top_layer and e > face) else e
                        bottom = z_edges[layer]
                        qs = np.int64(np.rint((s - bottom) * scale))
                        qe = np.int64(np.rint((top - bottom) * scale))
                        group[m] = layer * nx + ix
                        keys[m] = (qs << _Q_BITS) | qe
                        m += 1
                        if top == e:
                            break
                        s = face
                        layer += 1
                ix += step
    return m


@njit(cache=True)
def _row_lines(buf, m, start, keys, weights, pix, part):
    """Merge the m keyed pieces of one sample row and add each line's volume to part.

    A counting sort by group (layer, column) into keys, a sort of each
    group's run, the running maximum of the union, and the covered length
    [m] x weights[g] [m^2] added to part[pix[g]], groups in order (the numpy
    path's np.bincount order). start: (groups + 1,) scratch.
    """
    n_groups = start.size - 1
    quantum = weights[-1]
    mask = (1 << _Q_BITS) - 1
    start[:] = 0
    for q in range(m):
        start[buf[0][q] + 1] += 1
    for g in range(n_groups):
        start[g + 1] += start[g]
    fill = start[:-1].copy()
    for q in range(m):
        g = buf[0][q]
        keys[fill[g]] = buf[1][q]
        fill[g] += 1
    for g in range(n_groups):
        a, b = start[g], start[g + 1]
        if a == b:
            continue
        _sort_run(keys, a, b)
        line = 0.0
        reach = np.int64(-1)
        for q in range(a, b):
            qs, qe = keys[q] >> _Q_BITS, keys[q] & mask
            line += np.float64(max(qe - max(qs, reach), 0)) * quantum
            reach = max(reach, qe)
        line *= weights[g]
        part[pix[g]] += line


@njit(cache=True)
def union_rows(c, r, xgrid, ygrid, z, shape, image):
    """Add the union volume [m^3] of spheres c (C,3), r (C,), sorted by c[:, 1], to image.

    xgrid = (mid, w, cell_of, h), ygrid = (mid, w, cell_of): the sample grids of
    amfe.dataset.images._Axis (sample positions [m], widths [m], cells; spacing [m]);
    z = (z_edges, t, z_lo, z_hi, scale, quantum); shape = (rows per strip,
    H, W). Row by row of samples, the chords of the spheres within max(R) of
    the row go through _row_chords and _row_lines; a strip's pixel sums are
    added to ``image`` when it ends, as the numpy path adds them.
    """
    xmid, xw, xcell, xh = xgrid
    ymid, yw, ycell = ygrid
    rows, H, W = shape
    z_edges, t = z[0], z[1]
    nx, n = xmid.size, r.size
    n_layers = z_edges.size - 1
    j0 = np.searchsorted(xmid, c[:, 0])        # first column with its sample at or right of x_c
    buf = (np.empty(1 << 16, np.int64), np.empty(1 << 16, np.int64))
    keys = np.empty(1 << 16, np.int64)
    start = np.zeros(n_layers * nx + 1, np.int64)
    weights = np.empty(n_layers * nx + 1)
    weights[-1] = z[5]
    pix = np.empty(n_layers * nx, np.int64)
    part = np.zeros(image.size)
    reach_y = 1.01 * r.max()
    lo = 0
    hi = 0
    for iy in range(ymid.size):
        y = ymid[iy]
        while lo < n and c[lo, 1] < y - reach_y:
            lo += 1
        while hi < n and c[hi, 1] <= y + reach_y:
            hi += 1
        bound = 0.0   # chords the spheres can give this row: columns x layers they span
        for k in range(lo, hi):
            bound += min(2.0 * r[k] / xh + 3.0, nx) * min(2.0 * r[k] / t + 2.0, n_layers)
        need = int(bound)
        if need > keys.size:
            buf = (np.empty(need, np.int64), np.empty(need, np.int64))
            keys = np.empty(need, np.int64)
        m = _row_chords(c, r, (lo, hi), y, (xmid, j0), z, buf)
        if m:
            for layer in range(n_layers):
                for ix in range(nx):
                    g = layer * nx + ix
                    weights[g] = yw[iy] * xw[ix]
                    pix[g] = (layer * H + ycell[iy]) * W + xcell[ix]
            _row_lines(buf, m, start, keys, weights, pix, part)
        if (iy + 1) % rows == 0 or iy == ymid.size - 1:
            for p in range(image.size):
                image[p] += part[p]
                part[p] = 0.0


def _stamp(model):
    """A name for ``model``'s compiled springs that changes when its source file does."""
    digest = hashlib.sha256()
    for fn in (model.springs, model.coefficients, *model.helpers):
        with open(inspect.getsourcefile(fn), "rb") as source:
            digest.update(source.read())
    return f"amfe.springs.{model.name}.{digest.hexdigest()}"


@cache
def _helper(fn):
    """Let compiled code call the plain function ``fn`` (numba compiles it where it is called)."""
    return register_jitable(fn)


@cache
def compiled_springs(name="paper"):
    """The spring model ``name``'s own springs function (amfe.model.springs), compiled.

    error_model "numpy": a division by zero gives inf instead of a check on
    every divisor, so the springs a caller does not use are dropped as dead
    code (the kernel needs only k_n; measured 14 % faster than checked
    divisions). Its uuid is set from the model's source (:func:`_stamp`):
    numba keys a cached caller by its closure's pickle, which holds this uuid,
    so the caller's machine code is reused across processes and compiled
    afresh when the formula changes (a cache keyed by _jit.py alone would keep
    an edited formula's old code).
    """
    model = springs_model.spring_model(name)
    for fn in model.helpers:
        _helper(fn)
    springs = njit(model.springs, error_model="numpy")
    springs._set_uuid(_stamp(model))
    return springs


@cache
def bond_sums_for(name="paper"):
    """:func:`bond_sums` compiled against the spring model ``name`` (amfe.model.springs).

    The model's own springs function (:func:`compiled_springs`) is called, and
    inlined by LLVM: the kernel has no copy of the formula.
    """
    springs = compiled_springs(name)

    @njit(cache=True)
    def bond_sums(c, r, bonds, consts, box, image):
        """Add k_n L^2 [N m] of every bond to the flat image cell of its midpoint; False if unfit.

        bonds = (i, j, L): the bonds of amfe.model.bonds.find_pairs, in its order, and their
        lengths [m] as contact_geometry computes them; consts = (the model's coefficients,
        the refused a* from, COINCIDENT); box = (lo, hi, cell, n): (3,) [m] each and the cell
        counts (3,). The contact geometry is contact_geometry's in its order and k_n the
        model's springs function itself (docs/model.md, section 3), with a = a* R_eff as
        bond_springs passes it, so the sums are bond_image_of's np.bincount bit for bit. A
        bond those functions refuse (coincident centres, a contact plane outside the
        segment, a* past the limit) returns False at once: the caller takes the numpy path,
        which names it.
        """
        i, j, L_all = bonds
        coef, limit, coincident = consts
        lo, hi, cell, n = box
        for b in range(i.size):
            p, q, L = i[b], j[b], L_all[b]
            Ri, Rj = r[p], r[q]
            if L <= coincident * max(Ri, Rj):
                return False
            d_i = ((L * L + Ri * Ri) - Rj * Rj) / (2.0 * L)
            if d_i <= 0.0 or L - d_i <= 0.0:
                return False
            heron = (((Ri + Rj - L) * (L + Ri - Rj)) * (L - Ri + Rj)) * (Ri + Rj + L)
            a = math.sqrt(max(heron, 0.0)) / (2.0 * L)
            r_eff = Ri * Rj / (Ri + Rj)
            a_star = a / r_eff
            if not a_star < limit:
                return False
            k_n = springs(a_star * r_eff, r_eff, coef)[0]
            flat = 0
            inside = True
            for ax in (2, 1, 0):
                mid = 0.5 * (c[p, ax] + c[q, ax])
                inside = inside and lo[ax] <= mid < hi[ax]
                flat = flat * n[ax] + min(int(math.floor((mid - lo[ax]) / cell[ax])), n[ax] - 1)
            if inside:
                image[flat] += k_n * (L * L)
        return True

    return bond_sums
