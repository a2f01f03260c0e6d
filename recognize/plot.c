/* plot.c - BRF plots like the paper's Fig. 2 (bottom right): each bulb's BRF over one flicker
 * cycle, one panel per band, drawn with PLplot's cairo PNG driver. */
#include "recognize/recognize.h"

#include <plplot.h>
#include <stdio.h>
#include <stdlib.h>

/* A qualitative palette (Okabe-Ito, then darker variants) on PLplot's colour map 0. */
static const unsigned char palette[][3] = {
    {0, 0, 0},     {230, 159, 0}, {86, 180, 233}, {0, 158, 115}, {170, 150, 0}, {0, 114, 178},
    {213, 94, 0},  {204, 121, 167}, {120, 120, 120}, {150, 90, 0}, {30, 90, 140}, {0, 90, 60},
    {140, 40, 90}, {90, 90, 200},   {200, 60, 60},  {60, 160, 60},
};
#define PALETTE_N ((int)(sizeof palette / sizeof *palette))

static const char *band_label(int bands, int band)
{
    static const char *const rgb[3] = {"red band", "green band", "blue band"};
    return bands == 1 ? "monochrome" : rgb[band];
}

gs_status rec_plot_brfs(const gs_bulb *const *bulbs, size_t count, const char *png_path,
                        const char *title)
{
    if (count == 0) return gs_fail(GS_EINVAL, "plot: no bulbs to plot");
    if (count > (size_t)PALETTE_N - 1)
        return gs_fail(GS_ELIMIT, "plot: %zu bulbs: at most %d fit one legible plot", count, PALETTE_N - 1);
    int bands = bulbs[0]->brf.bands;
    for (size_t i = 1; i < count; i++)
        if (bulbs[i]->brf.bands != bands)
            return gs_fail(GS_EINVAL, "plot: bulb %s has %d bands, %s has %d: expected the same",
                           bulbs[i]->id, bulbs[i]->brf.bands, bulbs[0]->id, bands);
    FILE *probe = fopen(png_path, "wb");   /* PLplot exits the process on open failures */
    if (!probe) return gs_fail(GS_EIO, "%s: cannot write the plot", png_path);
    fclose(probe);

    double ymax = 0.0;
    int nmax = 0;
    for (size_t i = 0; i < count; i++) {
        const gs_brf *b = &bulbs[i]->brf;
        for (int j = 0; j < b->n * b->bands; j++)
            if (b->v[j] > ymax) ymax = b->v[j];
        if (b->n > nmax) nmax = b->n;
    }
    ymax = ymax < 1.5 ? 1.5 : ymax * 1.08;
    double *x = malloc(sizeof *x * (size_t)(nmax + 1)), *y = malloc(sizeof *y * (size_t)(nmax + 1));
    if (!x || !y) {
        free(x);
        free(y);
        return gs_fail(GS_ENOMEM, "plot: cannot allocate %d points", nmax);
    }

    plsdev("pngcairo");
    plsfnam(png_path);
    plsetopt("geometry", bands == 1 ? "1100x700" : "1100x1400");
    plscmap0n(PALETTE_N + 1);
    plscol0(0, 255, 255, 255); /* background */
    for (int c = 0; c < PALETTE_N; c++) plscol0(c + 1, palette[c][0], palette[c][1], palette[c][2]);
    plstar(1, bands);
    const char **labels = calloc(count, sizeof *labels);
    PLINT *opts = calloc(count, sizeof *opts), *colors = calloc(count, sizeof *colors),
          *styles = calloc(count, sizeof *styles);
    PLFLT *widths = calloc(count, sizeof *widths);
    char(*text)[160] = calloc(count, sizeof *text);
    for (int band = 0; band < bands; band++) {
        pladv(0);
        plvpor(0.11, 0.60, 0.12, 0.88);
        plwind(0.0, 1.0, 0.0, ymax);
        plcol0(1);
        plwidth(1.0);
        plbox("bcnstg", 0.1, 0, "bcnstvg", 0, 0);
        char top[256];
        snprintf(top, sizeof top, "%s (%s)", title, band_label(bands, band));
        pllab("time in the flicker cycle, t / #gD", "BRF (mean 1)", top);
        for (size_t i = 0; i < count; i++) {
            const gs_brf *b = &bulbs[i]->brf;
            for (int j = 0; j <= b->n; j++) {   /* close the cycle: sample n is sample 0 */
                x[j] = (double)j / b->n;
                y[j] = b->v[(size_t)band * (size_t)b->n + (size_t)(j % b->n)];
            }
            int c = (int)i % (PALETTE_N - 1) + 2;
            plcol0(c);
            plwidth(2.0);
            plline(b->n + 1, x, y);
            snprintf(text[i], sizeof text[i], "%s (%s, %d Hz)", bulbs[i]->id,
                     gs_tech_name(bulbs[i]->type), bulbs[i]->grid_hz);
            labels[i] = text[i];
            opts[i] = PL_LEGEND_LINE;
            colors[i] = c;
            styles[i] = 1;
            widths[i] = 2.0;
        }
        PLFLT lw, lh;
        pllegend(&lw, &lh, PL_LEGEND_BACKGROUND | PL_LEGEND_BOUNDING_BOX,
                 PL_POSITION_RIGHT | PL_POSITION_OUTSIDE, 0.02, 0.0, 0.05, 0, 1,
                 1, (PLINT)count, 1, (PLINT)count, opts, 0.8, 0.6, 2.0, 0.0, colors,
                 (const char *const *)labels, NULL, NULL, NULL, NULL, colors, styles, widths, NULL,
                 NULL, NULL, NULL);
    }
    plend();
    free(labels);
    free(opts);
    free(colors);
    free(styles);
    free(widths);
    free(text);
    free(x);
    free(y);
    return GS_OK;
}
