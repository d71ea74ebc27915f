/* The bond finder of amfe.model.bonds.find_pairs, compiled (amfe/model/native.py loads it).

   amfe_bonded_pairs finds the pairs i < j with |x_j - x_i|^2 < (R_i + R_j)^2 and their
   lengths, sorted by (i, j): find_pairs' pairs and contact_geometry's lengths bit for bit.
   d.d is summed in the order numpy's einsum sums it on this machine (``order``, probed by
   amfe.model.pairkernel.einsum_order), from d = x_j - x_i (a square does not see the sign).

   A cell list of side 2 max(R) (a bond joins neighbouring cells); each pair of
   neighbouring cells is visited once (the cell itself and the 13 cells after it), then a
   counting sort by i and an insertion sort of each i's few partners put the bonds in order.
*/
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

static double sum3(double xx, double yy, double zz, int order)
{
    if (order == 0) return (xx + yy) + zz;
    if (order == 1) return (xx + zz) + yy;
    return xx + (yy + zz);
}

/* Append the bonds between particles [a0, a1) and [b0, b1) (cell order; one cell when
   a0 == b0) from m; returns the new m, -1 at a pair closer than near x max(R), -2 when
   cap is reached. */
static int64_t cell_pair(const double *cs, const double *rs, const int64_t *members,
                         int64_t a0, int64_t a1, int64_t b0, int64_t b1, double near,
                         int order, int64_t cap, int64_t *pi, int64_t *pj, double *pd,
                         int64_t m)
{
    for (int64_t p = a0; p < a1; p++) {
        int64_t q0 = (b0 == a0) ? p + 1 : b0;
        double xp = cs[3 * p], yp = cs[3 * p + 1], zp = cs[3 * p + 2], rp = rs[p];
        for (int64_t q = q0; q < b1; q++) {
            double dx = cs[3 * q] - xp, dy = cs[3 * q + 1] - yp, dz = cs[3 * q + 2] - zp;
            double d2 = sum3(dx * dx, dy * dy, dz * dz, order);
            double reach = rp + rs[q];
            if (d2 < reach * reach) {
                double tiny = near * (rs[q] > rp ? rs[q] : rp);
                if (d2 <= tiny * tiny) return -1;
                if (m == cap) return -2;
                int64_t u = members[p], v = members[q];
                pi[m] = u < v ? u : v;
                pj[m] = u < v ? v : u;
                pd[m] = d2;
                m++;
            }
        }
    }
    return m;
}

/* The pairs (pi, pj, pd) sorted by (i, j) into (oi, oj, length = sqrt(d2)). */
static int by_first(int64_t n, int64_t m, const int64_t *pi, const int64_t *pj,
                    const double *pd, int64_t *oi, int64_t *oj, double *od)
{
    int64_t *start = calloc((size_t)n + 1, sizeof(int64_t));
    int64_t *fill = malloc(((size_t)n + 1) * sizeof(int64_t));
    if (!start || !fill) {
        free(start);
        free(fill);
        return -3;
    }
    for (int64_t q = 0; q < m; q++) start[pi[q] + 1]++;
    for (int64_t k = 0; k < n; k++) start[k + 1] += start[k];
    for (int64_t k = 0; k <= n; k++) fill[k] = start[k];
    for (int64_t q = 0; q < m; q++) {
        int64_t slot = fill[pi[q]]++;
        oi[slot] = pi[q];
        oj[slot] = pj[q];
        od[slot] = pd[q];
    }
    for (int64_t k = 0; k < n; k++) {
        for (int64_t a = start[k] + 1; a < start[k + 1]; a++) {
            int64_t vj = oj[a];
            double vd = od[a];
            int64_t b = a - 1;
            while (b >= start[k] && oj[b] > vj) {
                oj[b + 1] = oj[b];
                od[b + 1] = od[b];
                b--;
            }
            oj[b + 1] = vj;
            od[b + 1] = vd;
        }
    }
    for (int64_t q = 0; q < m; q++) od[q] = sqrt(od[q]);
    free(start);
    free(fill);
    return 0;
}

/* c (n, 3) [m] and r (n,) [m], C order; returns the number of bonds m (written to oi, oj,
   olen, (cap,) each), -1 where the caller must take the numpy path (a pair closer than
   near x max(R_i, R_j), or more than 8 n + 64 cells), -2 for more than cap bonds, -3 when
   memory runs out. */
int64_t amfe_bonded_pairs(int64_t n, const double *c, const double *r, double near,
                          int order, int64_t cap, int64_t *oi, int64_t *oj, double *olen)
{
    if (n <= 0) return 0;
    double rmax = r[0];
    for (int64_t k = 1; k < n; k++)
        if (r[k] > rmax) rmax = r[k];
    double side = 2.0 * rmax, lo[3], hi[3], extent = 1.0;
    int64_t dims[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = hi[a] = c[a];
        for (int64_t k = 1; k < n; k++) {
            double v = c[3 * k + a];
            if (v < lo[a]) lo[a] = v;
            if (v > hi[a]) hi[a] = v;
        }
        extent *= (hi[a] - lo[a]) / side + 1.0;
    }
    if (extent > (double)(8 * n + 64)) return -1;   /* in floats: far-flung beds overflow */
    for (int a = 0; a < 3; a++) dims[a] = (int64_t)((hi[a] - lo[a]) / side) + 1;
    int64_t n_cells = dims[0] * dims[1] * dims[2];

    int64_t *flat = malloc((size_t)n * sizeof(int64_t));
    int64_t *start = calloc((size_t)n_cells + 1, sizeof(int64_t));
    int64_t *fill = malloc(((size_t)n_cells + 1) * sizeof(int64_t));
    int64_t *members = malloc((size_t)n * sizeof(int64_t));
    double *cs = malloc((size_t)n * 3 * sizeof(double));
    double *rs = malloc((size_t)n * sizeof(double));
    int64_t *pi = malloc((size_t)cap * sizeof(int64_t));
    int64_t *pj = malloc((size_t)cap * sizeof(int64_t));
    double *pd = malloc((size_t)cap * sizeof(double));
    int64_t m = 0;
    if (!flat || !start || !fill || !members || !cs || !rs || !pi || !pj || !pd) {
        m = -3;
        goto done;
    }
    for (int64_t k = 0; k < n; k++) {
        int64_t q = 0;
        for (int a = 0; a < 3; a++) {
            int64_t cell = (int64_t)((c[3 * k + a] - lo[a]) / side);
            q = q * dims[a] + (cell < dims[a] - 1 ? cell : dims[a] - 1);
        }
        flat[k] = q;
        start[q + 1]++;
    }
    for (int64_t q = 0; q < n_cells; q++) start[q + 1] += start[q];
    for (int64_t q = 0; q <= n_cells; q++) fill[q] = start[q];
    for (int64_t k = 0; k < n; k++) members[fill[flat[k]]++] = k;   /* index order per cell */
    for (int64_t p = 0; p < n; p++) {
        int64_t k = members[p];
        cs[3 * p] = c[3 * k];
        cs[3 * p + 1] = c[3 * k + 1];
        cs[3 * p + 2] = c[3 * k + 2];
        rs[p] = r[k];
    }
    for (int64_t x = 0; x < dims[0]; x++)
        for (int64_t y = 0; y < dims[1]; y++)
            for (int64_t z = 0; z < dims[2]; z++) {
                int64_t a = (x * dims[1] + y) * dims[2] + z;
                for (int ox = 0; ox <= 1; ox++)
                    for (int oy = -1; oy <= 1; oy++)
                        for (int oz = -1; oz <= 1; oz++) {
                            /* the cell itself and the 13 after it, (ox, oy, oz) > 0 */
                            if (ox == 0 && (oy < 0 || (oy == 0 && oz < 0))) continue;
                            int64_t bx = x + ox, by = y + oy, bz = z + oz;
                            if (bx >= dims[0] || by < 0 || by >= dims[1] || bz < 0
                                || bz >= dims[2])
                                continue;
                            int64_t b = (bx * dims[1] + by) * dims[2] + bz;
                            m = cell_pair(cs, rs, members, start[a], start[a + 1], start[b],
                                          start[b + 1], near, order, cap, pi, pj, pd, m);
                            if (m < 0) goto done;
                        }
            }
    if (by_first(n, m, pi, pj, pd, oi, oj, olen) != 0) m = -3;
done:
    free(flat);
    free(start);
    free(fill);
    free(members);
    free(cs);
    free(rs);
    free(pi);
    free(pj);
    free(pd);
    return m;
}
