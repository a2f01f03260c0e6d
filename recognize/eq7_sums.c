/* eq7_sums.c - the sums of Eq. 7's scores, S = sum w x t and T = sum w t^2 of every template
 * (per band with band gains), for a block of lights (rec_eq7_block_sums):
 * - the templates that are not Fourier grids: a matrix product of the block's weighted samples
 *   with the transposed templates, by a kernel whose every sum runs in the order of the samples
 *   (one multiply-add per term, fused where the CPU can), so that a light's sums are the same bits
 *   whatever lights share its block: rec_match_light and rec_match_catalog agree to the bit;
 * - continuous bulbs with the Fourier form: one G-point inverse FFT per sum and light;
 * - the slow path (m->exhaustive, the tests' oracle) and matchers too large for the transposed
 *   copies: one matrix-vector product per light and sum (OpenBLAS). */
#include "recognize/internal.h"

#include <cblas.h>
#include <fftw3.h>
#include <stdlib.h>
#include <string.h>

/* The transposed copies are built up to this many values each (64 MiB). */
#define SUMS_MAX_VALUES (8u << 20)

/* The float sums from this many values per light: below, the double sums cost little and a
 * light of few samples scores many templates exactly, each from its double sums. */
#define FSUMS_MIN_D 64

/* The float sums' transposed templates (m->fsums). */
static gs_status float_setup(rec_matcher *m)
{
    size_t D = (size_t)m->D, M = m->M;
    m->ldtrf = (M + SUMS_COLS_F - 1) / SUMS_COLS_F * SUMS_COLS_F + SUMS_COLS_F;
    m->ttrf = calloc(D * m->ldtrf, sizeof *m->ttrf);
    m->tsqtrf = calloc(D * m->ldtrf, sizeof *m->tsqtrf);
    if (!m->ttrf || !m->tsqtrf)
        return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate %zu templates", M);
    for (size_t j = 0; j < M; j++)
        for (size_t d = 0; d < D; d++) {
            m->ttrf[d * m->ldtrf + j] = (float)m->t[j * D + d];
            m->tsqtrf[d * m->ldtrf + j] = (float)m->tsq[j * D + d];
        }
    return GS_OK;
}

gs_status rec_eq7_sums_setup(rec_matcher *m)
{
    size_t D = (size_t)m->D, M = m->M;
    m->ldtr = (M + SUMS_COLS - 1) / SUMS_COLS * SUMS_COLS + SUMS_COLS;   /* a tile past any range */
    if ((m->fourier && (size_t)m->ncont == m->nb) || D * m->ldtr > SUMS_MAX_VALUES) return GS_OK;
    /* the float sums: templates within 2^30 (their squares' sums with the rows scaled below 1
     * then stay far inside float's range: float_rows), and D >= FSUMS_MIN_D; then the double
     * kernel is not used (the exhaustive path takes matrix-vector products) */
    m->fsums = m->nfit == 1 && !m->red && !m->o.nested_tests && m->ncont == 0 && D >= FSUMS_MIN_D;
    for (size_t i = 0; m->fsums && i < M * D; i++) m->fsums = fabs(m->t[i]) <= 0x1p30;
    if (m->fsums) return float_setup(m);
    m->ttr = calloc(D * m->ldtr, sizeof *m->ttr);
    m->tsqtr = calloc(D * m->ldtr, sizeof *m->tsqtr);
    if (!m->ttr || !m->tsqtr) return gs_fail(GS_ENOMEM, "Eq. 7 matcher: cannot allocate %zu templates", M);
    for (size_t j = 0; j < M; j++)
        for (size_t d = 0; d < D; d++) {
            m->ttr[d * m->ldtr + j] = m->t[j * D + d];
            m->tsqtr[d * m->ldtr + j] = m->tsq[j * D + d];
        }
    return GS_OK;
}

/* The largest |v_d| of a row, by its bits (doubles >= 0 order as their bits). */
GS_VECTOR_LOOP static double row_top(const double *restrict v, size_t D)
{
    long long top = 0;
    for (size_t d = 0; d < D; d++) {
        double a = fabs(v[d]);
        long long b;
        memcpy(&b, &a, sizeof b);
        top = b > top ? b : top;
    }
    double r;
    memcpy(&r, &top, sizeof r);
    return r;
}

/* The power of two that takes a row's largest |value| top into [1/2, 1): scaled so, the row fits
 * float's range and its rounding is relative to its largest value. Within 2^-1000..2^1000, so
 * that its inverse is finite too (a row of subnormals keeps float's absolute error, eabs of
 * scr_bounds_1f; one near DBL_MAX comes to at most 2^24). */
static double row_scale(double top)
{
    int e;
    frexp(top, &e);
    e = e < -1000 ? -1000 : e > 1000 ? 1000 : e;
    return top > 0.0 ? ldexp(1.0, -e) : 1.0;
}

/* f = (float)(v s), s a power of two. */
GS_VECTOR_LOOP static void to_float(const double *restrict v, size_t D, double s, float *restrict f)
{
    for (size_t d = 0; d < D; d++) f[d] = (float)(v[d] * s);
}

/* The block's rows in float, each of w and wx scaled by its power of two, and |wx| scaled. */
static void float_rows(const rec_matcher *m, rec_eq7_work *w, size_t n)
{
    size_t D = (size_t)m->D;
    for (size_t q = 0; q < n; q++) {
        const double *wv = w->w_all + q * D, *wx = w->wx_all + q * D;
        double sw = row_scale(row_top(wv, D)), sx = row_scale(row_top(wx, D));
        to_float(wv, D, sw, w->wf_all + q * D);
        to_float(wx, D, sx, w->wxf_all + q * D);
        w->fsw_all[q] = sw;
        w->fsx_all[q] = sx;
        /* |wx| scaled, from the float row (no overflow): above |fl(v)| / (1 - 2^-24) by a margin */
        w->wxn_all[q] = sqrt(rec_pix_sumsq(w->wxf_all + q * D, D)) * (1.0 + 0x1p-20) + (double)D * 0x1p-149;
    }
}

void rec_eq7_exact_sums(const rec_matcher *m, rec_eq7_work *w, const size_t *idx, size_t n)
{
    if (!rec_eq7_float_sums(m)) return;
    size_t D = (size_t)m->D;
    for (size_t i = 0; i < n; i++) {
        size_t j = idx[i];
        if (w->have[j]) continue;
        w->have[j] = 1;
        w->S[j] = gs_dot(w->wx, m->t + j * D, D);
        w->T[j] = gs_dot(w->w, m->tsq + j * D, D);
    }
}

/* out[q * ldo + j] = sum over d < n of a[q * lda + d] tt[d * ldt + j], for q < nq and j < nj; tt
 * holds COLS columns past nj (ldt >= nj + COLS). Tiles of SUMS_ROWS lights by two vectors of
 * templates, then the last rows one by one; each sum its own chain of multiply-adds over d,
 * fused where the CPU can: the same bits whichever kernel runs (the 512-bit one, the 256-bit one
 * with FMA; the plain one, for a CPU without FMA, rounds each product), and whatever lights
 * share the tile. In double (sums_kernel) and in float (sums_kernel_f: the float sums' path). */
#ifdef __clang__
#pragma clang fp contract(fast)
#define SUMS_CONTRACT
#else
#define SUMS_CONTRACT optimize("fp-contract=fast"),
#endif
#define SUMS_ROW(r)                                                                                 \
    do {                                                                                            \
        __typeof__(*ar) x = ar[(r) * lda + d];                                                      \
        s[r] += x * t0;                                                                             \
        s[SUMS_ROWS + (r)] += x * t1;                                                               \
    } while (0)
#define SUMS_STORE(r, s0, s1, VW)                                                                   \
    do {                                                                                            \
        size_t n0 = nj - j < (VW) ? nj - j : (VW), n1 = nj - j > (VW) ? nj - j - (VW) : 0;          \
        memcpy(out + (r) * ldo + j, &(s0), n0 * sizeof *out);                                       \
        memcpy(out + (r) * ldo + j + (VW), &(s1), (n1 < (VW) ? n1 : (VW)) * sizeof *out);          \
    } while (0)
#define SUMS_KERNEL(NAME, TY, VW, COLS, TARGET)                                                     \
    typedef TY NAME##_vec __attribute__((vector_size((VW) * sizeof(TY))));                          \
    __attribute__((SUMS_CONTRACT TARGET)) static void NAME(const TY *a, size_t lda, size_t nq,      \
                                                           const TY *tt, size_t ldt, size_t n,      \
                                                           TY *out, size_t ldo, size_t nj)          \
    {                                                                                               \
        _Static_assert(SUMS_ROWS == 8 && 2 * (VW) <= (COLS), "the tile");                           \
        size_t q8 = nq / SUMS_ROWS * SUMS_ROWS;                                                     \
        for (size_t j = 0; j < nj; j += 2 * (VW))   /* a tile of templates stays in L1 */           \
            for (size_t q = 0; q < q8; q += SUMS_ROWS) {                                            \
                const TY *ar = a + q * lda;                                                         \
                NAME##_vec s[2 * SUMS_ROWS] = {{0}};                                                \
                for (size_t d = 0; d < n; d++) {                                                    \
                    NAME##_vec t0, t1;                                                              \
                    memcpy(&t0, tt + d * ldt + j, sizeof t0);                                       \
                    memcpy(&t1, tt + d * ldt + j + (VW), sizeof t1);                                \
                    SUMS_ROW(0); SUMS_ROW(1); SUMS_ROW(2); SUMS_ROW(3);                             \
                    SUMS_ROW(4); SUMS_ROW(5); SUMS_ROW(6); SUMS_ROW(7);                             \
                }                                                                                   \
                for (size_t r = 0; r < SUMS_ROWS; r++) SUMS_STORE(q + r, s[r], s[SUMS_ROWS + r], VW); \
            }                                                                                       \
        for (size_t q = q8; q < nq; q++)   /* the last rows one by one: the same chain for each sum */ \
            for (size_t j = 0; j < nj; j += 2 * (VW)) {                                             \
                NAME##_vec s0 = {0}, s1 = {0};                                                      \
                for (size_t d = 0; d < n; d++) {                                                    \
                    NAME##_vec t0, t1;                                                              \
                    memcpy(&t0, tt + d * ldt + j, sizeof t0);                                       \
                    memcpy(&t1, tt + d * ldt + j + (VW), sizeof t1);                                \
                    TY x = a[q * lda + d];                                                          \
                    s0 += x * t0;                                                                   \
                    s1 += x * t1;                                                                   \
                }                                                                                   \
                SUMS_STORE(q, s0, s1, VW);                                                          \
            }                                                                                       \
    }
SUMS_KERNEL(sums_kernel_512, double, 8, SUMS_COLS, target("avx512f"))
SUMS_KERNEL(sums_kernel_256, double, 4, SUMS_COLS, target("avx2,fma"))
SUMS_KERNEL(sums_kernel_plain, double, 4, SUMS_COLS, )
SUMS_KERNEL(sums_kernel_f512, float, 16, SUMS_COLS_F, target("avx512f"))
SUMS_KERNEL(sums_kernel_f256, float, 8, SUMS_COLS_F, target("avx2,fma"))
SUMS_KERNEL(sums_kernel_fplain, float, 8, SUMS_COLS_F, )
#ifdef __clang__
#pragma clang fp contract(off)   /* (the build's -ffp-contract=off for the rest of the file) */
#endif

#define SUMS_PICK(k, ...)                                                                           \
    do {                                                                                            \
        if (__builtin_cpu_supports("avx512f")) k##512(__VA_ARGS__);                                 \
        else if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))                   \
            k##256(__VA_ARGS__);                                                                    \
        else                                                                                        \
            k##plain(__VA_ARGS__);                                                                  \
    } while (0)

static void sums_kernel(const double *a, size_t lda, size_t nq, const double *tt, size_t ldt, size_t n,
                        double *out, size_t ldo, size_t nj)
{
    SUMS_PICK(sums_kernel_, a, lda, nq, tt, ldt, n, out, ldo, nj);
}

static void sums_kernel_f(const float *a, size_t lda, size_t nq, const float *tt, size_t ldt, size_t n,
                          float *out, size_t ldo, size_t nj)
{
    SUMS_PICK(sums_kernel_f, a, lda, nq, tt, ldt, n, out, ldo, nj);
}

GS_VECTOR_LOOP void rec_eq7_dft(const double *restrict v, const double *restrict c, const double *restrict s,
                                size_t K, double *restrict x)
{
    enum { TILE = 64 };   /* bins summed in split parts, then stored as pairs */
    for (size_t r0 = 0; r0 < K; r0 += TILE) {
        size_t nr = K - r0 < TILE ? K - r0 : TILE;
        double re[TILE], im[TILE];
        for (size_t r = 0; r < nr; r++) re[r] = im[r] = 0.0;
        for (size_t k = 0; k < K; k++) {
            double vk = v[k];
            const double *ck = c + k * K + r0, *sk = s + k * K + r0;
            for (size_t r = 0; r < nr; r++) {
                re[r] += vk * ck[r];
                im[r] -= vk * sk[r];
            }
        }
        for (size_t r = 0; r < nr; r++) {
            x[2 * (r0 + r)] = re[r];
            x[2 * (r0 + r) + 1] = im[r];
        }
    }
}

/* The conjugate K-point DFTs of D values v per band, conj(sum_k v_k e^{2 pi i r k / K}), repeated
 * over the G/2 + 1 bins of the grid (bin r is the DFT's r mod K), into X ([band * nh + r]). */
void rec_eq7_band_dfts(const rec_matcher *m, const double *v, double complex *X)
{
    size_t K = (size_t)m->K, nh = (size_t)m->G / 2 + 1;
    for (int band = 0; band < m->bands; band++) {
        double complex *Xb = X + (size_t)band * nh;
        rec_eq7_dft(v + (size_t)band * K, m->dftc, m->dfts, K, (double *)Xb);
        for (size_t r = K; r < nh; r++) Xb[r] = Xb[r - K];
    }
}

/* The light's DFTs of wx and w (rec_eq7_band_dfts) into w->spec + nh (X, then W). */
void rec_eq7_light_dfts(const rec_matcher *m, rec_eq7_work *w)
{
    size_t nh = (size_t)m->G / 2 + 1, bn = (size_t)m->bands * nh;
    rec_eq7_band_dfts(m, w->wx, w->spec + nh);
    rec_eq7_band_dfts(m, w->w, w->spec + nh + bn);
}

GS_VECTOR_LOOP void rec_eq7_cross_sum(const double *restrict a, const double *restrict x, size_t ld, int nq, size_t n,
                                      double *restrict z)
{
    size_t r = 0;
    rec_cx4 p, zv;
    for (; r + 4 <= n; r += 4) {
        zv = (rec_cx4){0};
        for (int q = 0; q < nq; q++) {
            REC_CX4_MUL(p, a + (size_t)q * ld + 2 * r, x + (size_t)q * ld + 2 * r);
            zv += p;
        }
        memcpy(z + 2 * r, &zv, sizeof zv);
    }
    if (r == n) return;
    zv = (rec_cx4){0};
    for (int q = 0; q < nq; q++) {
        double ab[8] = {0}, xb[8] = {0};
        memcpy(ab, a + (size_t)q * ld + 2 * r, sizeof *ab * 2 * (n - r));
        memcpy(xb, x + (size_t)q * ld + 2 * r, sizeof *xb * 2 * (n - r));
        REC_CX4_MUL(p, ab, xb);
        zv += p;
    }
    memcpy(z + 2 * r, &zv, sizeof *z * 2 * (n - r));
}

/* One grid of sums of continuous bulb b for brightness f into dst (G values): the inverse FFT of
 * the cross-spectrum of the template spectra hat (m->ahat: sum v t; m->bhat: sum v t^2) with
 * the band DFTs X of the weighted values v (all bands with one gain). */
static void grid_corr(const rec_matcher *m, rec_eq7_work *w, size_t b, int f, const double complex *hat,
                      const double complex *X, double *dst)
{
    size_t nh = (size_t)m->G / 2 + 1;
    int nf = m->nfit, b0 = nf == 1 ? 0 : f, b1 = nf == 1 ? m->bands : f + 1;
    rec_eq7_cross_sum((const double *)(hat + (b * (size_t)m->bands + (size_t)b0) * nh),
                      (const double *)(X + (size_t)b0 * nh), 2 * nh, b1 - b0, nh, (double *)w->spec);
    fftw_execute_dft_c2r((fftw_plan)m->c2r, (fftw_complex *)w->spec, w->grid);
    memcpy(dst, w->grid, sizeof *dst * (size_t)m->G);
}

void rec_eq7_grid_sums(const rec_matcher *m, rec_eq7_work *w, size_t b)
{
    size_t nh = (size_t)m->G / 2 + 1, M = m->M, bn = (size_t)m->bands * nh;
    const double complex *X = w->spec + nh, *W = X + bn;
    for (int f = 0; f < m->nfit; f++) {
        grid_corr(m, w, b, f, m->ahat, X, w->S + (size_t)f * M + m->first[b]);
        grid_corr(m, w, b, f, m->bhat, W, w->T + (size_t)f * M + m->first[b]);
    }
}

void rec_eq7_grid_dots(const rec_matcher *m, rec_eq7_work *w, size_t b, int f, const double complex *X, double *dst)
{
    grid_corr(m, w, b, f, m->ahat, X, dst);
}

/* Templates j0..j0+n-1 of row q by matrix-vector products (the slow path). */
static void gemv_sums(const rec_matcher *m, rec_eq7_work *w, size_t j0, size_t n)
{
    size_t D = (size_t)m->D, M = m->M, span = m->bg ? (size_t)m->K : D;
    for (int f = 0; f < m->nfit; f++) {
        size_t o = (size_t)f * span;
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)span, 1.0, m->t + j0 * D + o, (int)D,
                    w->wx + o, 1, 0.0, w->S + (size_t)f * M + j0, 1);
        cblas_dgemv(CblasRowMajor, CblasNoTrans, (int)n, (int)span, 1.0, m->tsq + j0 * D + o, (int)D,
                    w->w + o, 1, 0.0, w->T + (size_t)f * M + j0, 1);
    }
}

void rec_eq7_block_sums(const rec_matcher *m, rec_eq7_work *w, size_t n)
{
    size_t D = (size_t)m->D, M = m->M, span = m->bg ? (size_t)m->K : D;
    if (rec_eq7_float_sums(m)) {   /* every template discrete, one brightness */
        float_rows(m, w, n);
        sums_kernel_f(w->wxf_all, D, n, m->ttrf, m->ldtrf, D, w->Sf_all, M, M);
        sums_kernel_f(w->wf_all, D, n, m->tsqtrf, m->ldtrf, D, w->Tf_all, M, M);
        return;
    }
    int fourier = m->fourier && !m->exhaustive, kernel = m->ttr && !m->exhaustive;
    /* the templates that are not Fourier grids, in runs of consecutive ones */
    for (size_t b = 0; b < m->nb;) {
        if (fourier && m->cont[b]) {
            b++;
            continue;
        }
        size_t b1 = b + 1;
        while (b1 < m->nb && !(fourier && m->cont[b1])) b1++;
        size_t j0 = m->first[b], nj = m->first[b1 - 1] + m->count[b1 - 1] - j0;
        for (size_t q = 0; !kernel && q < n; q++) {
            rec_eq7_work_row(m, w, q);
            gemv_sums(m, w, j0, nj);
        }
        for (int f = 0; kernel && f < m->nfit; f++) {
            size_t o = (size_t)f * span, ldo = (size_t)m->nfit * M;
            sums_kernel(w->wx_all + o, D, n, m->ttr + o * m->ldtr + j0, m->ldtr, span,
                        w->S_all + (size_t)f * M + j0, ldo, nj);
            sums_kernel(w->w_all + o, D, n, m->tsqtr + o * m->ldtr + j0, m->ldtr, span,
                        w->T_all + (size_t)f * M + j0, ldo, nj);
        }
        b = b1;
    }
    /* (with the screen of bulbs, each light's grids only where it opens them: rec_eq7_screen) */
    for (size_t q = 0; fourier && !rec_eq7_bulb_screen(m) && q < n; q++) {
        rec_eq7_work_row(m, w, q);
        rec_eq7_light_dfts(m, w);
        for (size_t b = 0; b < m->nb; b++)
            if (m->cont[b]) rec_eq7_grid_sums(m, w, b);
    }
}
