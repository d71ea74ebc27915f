/* The union volume of spheres per image cell, compiled (amfe/model/native.py loads it).

   The numpy path of amfe.dataset.images (its _union_numpy) generates every (sphere,
   sample line) chord as array elements and sorts them by one int64 key. This kernel does
   the same arithmetic one chord at a time, and the same float operations in the same
   order, so the images are identical bit for bit (tests/test_pixelkernel.py):

   * the spheres are bucketed by the sample row at or above their centre (a counting
     sort), and each sphere's first layer and first sample column are found once;
   * row by row of samples, each sphere of the nearby buckets with dy^2 < R^2 gives its
     chords by scanning out from the sample column nearest its centre while
     (R^2 - dx^2) - dy^2 > 0 (the covered columns of a row are one run), cut at the layer
     faces and quantised as the numpy path quantises them;
   * a counting sort by (layer, column) groups a row's chords by sample line, each line's
     few chords are sorted by (start, end), and the union's running maximum gives the
     covered length, added to the strip's pixel sums in np.bincount's order;
   * each strip is added to the image when it ends, as the numpy path adds it.

   A line's chords are sorted by their keys, so the order in which the spheres are visited
   does not change a bit of the image.
*/
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define Q_BITS 17   /* bits of a chord end in a key (amfe.dataset.images._Q_BITS) */

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Sort keys[a:b] in place: a line holds a few chords (about six in a generated bed). */
static void sort_run(int64_t *keys, int64_t a, int64_t b)
{
    if (b - a > 32) {
        qsort(keys + a, (size_t)(b - a), sizeof(int64_t), cmp_i64);
        return;
    }
    for (int64_t m = a + 1; m < b; m++) {
        int64_t v = keys[m], q = m - 1;
        while (q >= a && keys[q] > v) {
            keys[q + 1] = keys[q];
            q--;
        }
        keys[q + 1] = v;
    }
}

typedef struct {
    const double *edges;   /* (layers + 1,) layer faces [m] */
    int64_t layers;
    double t, lo, hi, scale;   /* thickness [m], the box in z [m], levels per metre */
} ZGrid;

static int64_t layer_of(double s, const ZGrid *z)
{
    double q = (s - z->edges[0]) / z->t;   /* >= 0 but for a sphere below the box */
    int64_t l = q >= 0.0 ? (int64_t)q : (int64_t)floor(q);
    if (l < 0) l = 0;
    return l < z->layers - 1 ? l : z->layers - 1;
}

static double dmax(double a, double b) { return b > a ? b : a; }
static double dmin(double a, double b) { return b < a ? b : a; }

/* One sphere as the rows read it: centre [m], R^2 [m^2], its first sample column at or
   right of cx, the layer of its lowest point in the box, and whether its centre lies in
   that layer too (then every chord starts in it). */
typedef struct {
    double cx, cy, zc, rr;
    int64_t j0, l_lo, sure;
} Sphere;

/* The first index i of the increasing samples mid (n,) with mid[i] >= v (n if none:
   numpy's searchsorted), started from the guess of a regular spacing h. */
static int64_t first_at_or_above(const double *mid, int64_t n, double h, double v)
{
    double g = ceil((v - mid[0]) / h);
    int64_t i = g <= 0.0 ? 0 : (g >= (double)n ? n : (int64_t)g);
    while (i > 0 && mid[i - 1] >= v) i--;
    while (i < n && mid[i] < v) i++;
    return i;
}

/* The chords of spheres sp[k0, k1) through the sample lines at y: group = layer * nx +
   column, key = qs << 17 | qe; returns their count. */
static int64_t row_chords(const Sphere *sp, int64_t k0, int64_t k1, double y,
                          const double *xmid, int64_t nx, const ZGrid *z, int64_t *group,
                          int64_t *key)
{
    int64_t m = 0, top_layer = z->layers - 1;
    for (int64_t k = k0; k < k1; k++) {
        const Sphere *q = sp + k;
        double dy = y - q->cy, dy2 = dy * dy, rr = q->rr;
        if (dy2 >= rr) continue;
        double cx = q->cx, zc = q->zc;
        int64_t l_lo = q->l_lo;
        int sure = (int)q->sure;
        for (int step = 1; step >= -1; step -= 2) {
            int64_t ix = step == 1 ? q->j0 : q->j0 - 1;
            while (ix >= 0 && ix < nx) {
                double dx = xmid[ix] - cx, half2 = (rr - dx * dx) - dy2;
                if (!(half2 > 0.0)) break;
                double half = sqrt(half2);
                double s = dmax(zc - half, z->lo), e = dmin(zc + half, z->hi);
                if (e > s) {
                    int64_t layer = sure ? l_lo : layer_of(s, z);
                    for (;;) {
                        double face = z->edges[layer + 1];
                        double top = (layer < top_layer && e > face) ? face : e;
                        double bottom = z->edges[layer];
                        int64_t qs = (int64_t)rint((s - bottom) * z->scale);
                        int64_t qe = (int64_t)rint((top - bottom) * z->scale);
                        group[m] = layer * nx + ix;
                        key[m] = (int64_t)(((uint64_t)qs << Q_BITS) | (uint64_t)qe);
                        m++;
                        if (top == e) break;
                        s = face;
                        layer++;
                    }
                }
                ix += step;
            }
        }
    }
    return m;
}

/* Merge a row's m chords by line and add each line's covered length [m] x its weight
   yw * xw[ix] [m^2] to part[layer * HW + prow + xcell[ix]], lines in group order (group =
   layer * nx + ix). start, fill: (groups + 1,) scratch. */
static void row_lines(const int64_t *group, const int64_t *key, int64_t m, int64_t nx,
                      int64_t n_groups, int64_t *start, int64_t *fill, int64_t *keys,
                      double yw, const double *xw, const int64_t *xcell, int64_t prow,
                      int64_t HW, double quantum, double *part)
{
    const int64_t mask = ((int64_t)1 << Q_BITS) - 1;
    memset(start, 0, (size_t)(n_groups + 1) * sizeof(int64_t));
    for (int64_t q = 0; q < m; q++) start[group[q] + 1]++;
    for (int64_t g = 0; g < n_groups; g++) start[g + 1] += start[g];
    memcpy(fill, start, (size_t)n_groups * sizeof(int64_t));
    for (int64_t q = 0; q < m; q++) keys[fill[group[q]]++] = key[q];
    for (int64_t g = 0; g < n_groups; g++) {
        int64_t a = start[g], b = start[g + 1];
        if (a == b) continue;
        sort_run(keys, a, b);
        double line = 0.0;
        int64_t reach = -1;
        for (int64_t q = a; q < b; q++) {
            int64_t qs = keys[q] >> Q_BITS, qe = keys[q] & mask;
            int64_t from = qs > reach ? qs : reach;
            int64_t covered = qe - from > 0 ? qe - from : 0;
            line += (double)covered * quantum;
            if (qe > reach) reach = qe;
        }
        int64_t layer = g / nx, ix = g - layer * nx;
        double weight = yw * xw[ix];
        line *= weight;
        part[layer * HW + prow + xcell[ix]] += line;
    }
}

/* Add the union volume [m^3] of spheres c (n, 3), r (n,) (any order) to image
   (layers * H * W,). x samples: xmid, xw, xcell (nx,), spacing xh [m]; y samples: ymid,
   yw, ycell (ny,), spacing yh [m] (both regular but for the last sample, cut at the box);
   z: edges (layers + 1,), thickness t, the box's z_lo, z_hi [m], scale (levels per metre)
   and quantum [m]; rows: sample rows per strip. Returns 0, or -3 when memory runs out. */
int amfe_union_rows(int64_t n, const double *c, const double *r, int64_t nx,
                    const double *xmid, const double *xw, const int64_t *xcell, double xh,
                    int64_t ny, const double *ymid, const double *yw, const int64_t *ycell,
                    double yh, int64_t layers, const double *z_edges, double t, double z_lo,
                    double z_hi, double scale, double quantum, int64_t rows, int64_t H,
                    int64_t W, double *image)
{
    ZGrid z = {z_edges, layers, t, z_lo, z_hi, scale};
    int64_t n_groups = layers * nx, size = layers * H * W, cap = 1 << 16;
    int64_t *group = malloc((size_t)cap * sizeof(int64_t));
    int64_t *key = malloc((size_t)cap * sizeof(int64_t));
    int64_t *keys = malloc((size_t)cap * sizeof(int64_t));
    int64_t *start = malloc((size_t)(n_groups + 1) * sizeof(int64_t));
    int64_t *fill = malloc((size_t)(n_groups + 1) * sizeof(int64_t));
    double *part = calloc((size_t)size, sizeof(double));
    int64_t *bucket = malloc((size_t)(n > 0 ? n : 1) * sizeof(int64_t));
    /* bucket b (the spheres whose first sample row at or above them is b) holds sp[first[b],
       first[b + 1]); bound[k]: the most chords spheres sp[0, k) can give one row */
    int64_t *first = calloc((size_t)(ny + 2), sizeof(int64_t));
    int64_t *bound = malloc((size_t)(n + 1) * sizeof(int64_t));
    Sphere *sp = malloc((size_t)(n > 0 ? n : 1) * sizeof(Sphere));
    int status = 0;
    if (!group || !key || !keys || !start || !fill || !part || !bucket || !first || !bound
        || !sp) {
        status = -3;
        goto done;
    }
    double rmax = 0.0;
    for (int64_t k = 0; k < n; k++)
        if (k == 0 || r[k] > rmax) rmax = r[k];
    for (int64_t k = 0; k < n; k++) {
        bucket[k] = first_at_or_above(ymid, ny, yh, c[3 * k + 1]);
        first[bucket[k] + 1]++;
    }
    for (int64_t b = 0; b <= ny; b++) first[b + 1] += first[b];
    for (int64_t k = 0; k < n; k++) {   /* stable: the spheres of a bucket keep their order */
        Sphere *q = sp + first[bucket[k]]++;
        double rr = r[k] * r[k], zc = c[3 * k + 2];
        q->cx = c[3 * k];
        q->cy = c[3 * k + 1];
        q->zc = zc;
        q->rr = rr;
        q->j0 = first_at_or_above(xmid, nx, xh, c[3 * k]);
        q->l_lo = layer_of(dmax(zc - sqrt(rr), z.lo), &z);
        q->sure = q->l_lo == layer_of(dmax(zc, z.lo), &z);
    }
    for (int64_t b = ny; b > 0; b--) first[b] = first[b - 1];   /* undo the scatter's shift */
    first[0] = 0;
    bound[0] = 0;
    for (int64_t k = 0; k < n; k++) {   /* columns x layers a sphere's chords can span */
        double rk = sqrt(sp[k].rr);
        bound[k + 1] = bound[k] + (int64_t)ceil(dmin(2.0 * rk / xh + 3.0, (double)nx)
                                                 * dmin(2.0 * rk / t + 2.0, (double)layers));
    }
    /* A sphere reaching row iy (|y - cy| < R <= rmax) lies in a bucket within reach rows. */
    int64_t reach = (int64_t)ceil(rmax / yh) + 2;
    for (int64_t iy = 0; iy < ny; iy++) {
        int64_t b0 = iy - reach > 0 ? iy - reach : 0;
        int64_t b1 = iy + reach + 1 < ny ? iy + reach + 1 : ny;   /* buckets [b0, b1] */
        int64_t k0 = first[b0], k1 = first[b1 + 1];
        int64_t need = bound[k1] - bound[k0];
        if (need > cap) {
            cap = need;
            free(group);
            free(key);
            free(keys);
            group = malloc((size_t)cap * sizeof(int64_t));
            key = malloc((size_t)cap * sizeof(int64_t));
            keys = malloc((size_t)cap * sizeof(int64_t));
            if (!group || !key || !keys) {
                status = -3;
                goto done;
            }
        }
        int64_t m = row_chords(sp, k0, k1, ymid[iy], xmid, nx, &z, group, key);
        if (m)
            row_lines(group, key, m, nx, n_groups, start, fill, keys, yw[iy], xw, xcell,
                      ycell[iy] * W, H * W, quantum, part);
        if ((iy + 1) % rows == 0 || iy == ny - 1) {
            for (int64_t p = 0; p < size; p++) {
                image[p] += part[p];
                part[p] = 0.0;
            }
        }
    }
done:
    free(group);
    free(key);
    free(keys);
    free(start);
    free(fill);
    free(part);
    free(bucket);
    free(first);
    free(bound);
    free(sp);
    return status;
}
