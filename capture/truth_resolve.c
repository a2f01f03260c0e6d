/* truth_resolve.c - which of the truth's lights a camera can tell apart (docs/formats.md,
 * "Resolvability"): the separation of two lights in units of the image's point spread, and
 * whether their received fluxes are comparable.
 *
 * sigma_e = sqrt(sigma_psf^2 + 1/12) px: the PSF integrated over a pixel (a box of variance
 * 1/12); sigma_psf = 0 without the psf effect. F_i = sum_b flux_ib trans_ib, the light's
 * photo-electrons per cycle at the sensor after extinction. Two in-image lights i, j are close
 * when |x_i - x_j| < CAP_RESOLVE_SEPARATION sigma_e. Light i is resolvable when no close light
 * has F_j >= F_i / CAP_RESOLVE_FLUX_RATIO (comparable or brighter); close pairs of comparable
 * flux (within that ratio either way) are joined, and each connected set of two or more lights
 * is a blend group. An unresolvable light in no group is hidden by a much brighter neighbour.
 * Work: the lights sorted by x, a window of +-2 sigma_e each (O(n log n) for sparse scenes). */
#include "capture/sim.h"

#include <math.h>
#include <stdlib.h>

typedef struct {
    double x;
    size_t l;
} rs_key;

static int cmp_key(const void *a, const void *b)
{
    const rs_key *p = a, *q = b;
    if (p->x != q->x) return p->x < q->x ? -1 : 1;
    return (p->l > q->l) - (p->l < q->l);
}

static size_t uf_find(size_t *parent, size_t i)
{
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

double cap_resolve_sigma_px(const cap_sim *s)
{
    double psf = (s->fx >> CAP_FX_PSF) & 1u ? s->sc.fx.psf.sigma_px : 0.0;
    return sqrt(psf * psf + 1.0 / 12.0);
}

/* Received flux of light l, photo-electrons per cycle over bands. */
static double received(const cap_sim *s, size_t l)
{
    double f = 0;
    for (int b = 0; b < s->B; b++) {
        size_t i = l * (size_t)s->B + (size_t)b;
        f += s->flux[i] * (s->trans ? s->trans[i] : 1.0);
    }
    return f;
}

gs_status cap_resolve(const cap_sim *s, unsigned char *resolvable, int *group, int *n_groups)
{
    const size_t n = s->n;
    const double R = CAP_RESOLVE_SEPARATION * cap_resolve_sigma_px(s);
    rs_key *key = malloc((n ? n : 1) * sizeof *key);
    size_t *parent = malloc((n ? n : 1) * sizeof *parent);
    size_t *size = calloc(n ? n : 1, sizeof *size);
    double *F = malloc((n ? n : 1) * sizeof *F);
    if (!key || !parent || !size || !F) {
        free(key);
        free(parent);
        free(size);
        free(F);
        return gs_fail(GS_ENOMEM, "truth: out of memory for the resolvability of %zu lights", n);
    }
    size_t m = 0;
    for (size_t l = 0; l < n; l++) {
        parent[l] = l;
        resolvable[l] = 0;
        group[l] = -1;
        F[l] = received(s, l);
        if (s->sc.lights[l].in_image) {
            resolvable[l] = 1;
            key[m++] = (rs_key){s->sc.lights[l].x_px, l};
        }
    }
    qsort(key, m, sizeof *key, cmp_key);
    for (size_t a = 0; a < m; a++)
        for (size_t b = a + 1; b < m && key[b].x - key[a].x < R; b++) {
            size_t i = key[a].l, j = key[b].l;
            const cap_light *li = &s->sc.lights[i], *lj = &s->sc.lights[j];
            if (!(hypot(li->x_px - lj->x_px, li->y_px - lj->y_px) < R)) continue;
            int j_hides_i = F[j] >= F[i] / CAP_RESOLVE_FLUX_RATIO;
            int i_hides_j = F[i] >= F[j] / CAP_RESOLVE_FLUX_RATIO;
            if (j_hides_i) resolvable[i] = 0;
            if (i_hides_j) resolvable[j] = 0;
            if (j_hides_i && i_hides_j) {
                size_t ri = uf_find(parent, i), rj = uf_find(parent, j);
                if (ri != rj) parent[ri < rj ? rj : ri] = ri < rj ? ri : rj;
            }
        }
    for (size_t l = 0; l < n; l++) size[uf_find(parent, l)]++;
    /* groups numbered in order of their first light; key reused as root -> id */
    int ng = 0;
    for (size_t l = 0; l < n; l++) key[l].l = (size_t)-1;
    for (size_t l = 0; l < n; l++) {
        size_t r = uf_find(parent, l);
        if (size[r] < 2) continue;
        if (key[r].l == (size_t)-1) key[r].l = (size_t)ng++;
        group[l] = (int)key[r].l;
    }
    *n_groups = ng;
    free(key);
    free(parent);
    free(size);
    free(F);
    return GS_OK;
}
