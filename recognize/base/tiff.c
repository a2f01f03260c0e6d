/* tiff.c - 32-bit float TIFF images (libtiff), the light-transport images of
 * docs/light-transport.md: uncompressed IEEE float samples, 1 band (grey) or 3 (R, G, B in file
 * order), one page per image, written atomically. libtiff's messages go to the detail, not to
 * stderr. */
#include "recognize/base/base.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <tiffio.h>

/* libtiff reports through handlers: keep the last message for the detail. */
static _Thread_local char tiff_msg[256];

static void tiff_handler(const char *module, const char *fmt, va_list ap)
{
    char m[200];
    vsnprintf(m, sizeof m, fmt, ap);
    snprintf(tiff_msg, sizeof tiff_msg, "%s%s%s", module ? module : "", module ? ": " : "", m);
}

static void tiff_quiet(void)
{
    TIFFSetErrorHandler(tiff_handler);
    TIFFSetWarningHandler(NULL);
    tiff_msg[0] = '\0';
}

gs_status gs_tiff_write_float(const char *path, const float *pix, int width, int height,
                              int bands, int pages)
{
    if (!path || !pix || width < 1 || height < 1 || width > 65535 || height > 65535 ||
        (bands != 1 && bands != 3) || pages < 1 || pages > 65535)
        return gs_fail(GS_EINVAL, "%s: TIFF of %d x %d x %d, %d pages: expected 1..65535 pixels a "
                       "side, 1 or 3 bands, 1..65535 pages", path ? path : "(null)", width, height,
                       bands, pages);
    tiff_quiet();
    gs_atomic a;
    gs_status st = gs_atomic_open(&a, path, 0);
    if (st != GS_OK) return st;
    TIFF *t = TIFFOpen(a.tmp, "w");
    if (!t) {
        gs_atomic_abort(&a);
        return gs_fail(GS_EIO, "%s: cannot write a TIFF: %s", path, tiff_msg);
    }
    size_t row = (size_t)width * (size_t)bands;
    int ok = 1;
    for (int pg = 0; pg < pages && ok; pg++) {
        ok = TIFFSetField(t, TIFFTAG_IMAGEWIDTH, (uint32_t)width) &&
             TIFFSetField(t, TIFFTAG_IMAGELENGTH, (uint32_t)height) &&
             TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, (uint16_t)bands) &&
             TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, (uint16_t)32) &&
             TIFFSetField(t, TIFFTAG_SAMPLEFORMAT, (uint16_t)SAMPLEFORMAT_IEEEFP) &&
             TIFFSetField(t, TIFFTAG_PLANARCONFIG, (uint16_t)PLANARCONFIG_CONTIG) &&
             TIFFSetField(t, TIFFTAG_COMPRESSION, (uint16_t)COMPRESSION_NONE) &&
             TIFFSetField(t, TIFFTAG_PHOTOMETRIC,
                          (uint16_t)(bands == 3 ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK)) &&
             TIFFSetField(t, TIFFTAG_ROWSPERSTRIP, (uint32_t)(height < 16 ? height : 16));
        if (ok && pages > 1)
            ok = TIFFSetField(t, TIFFTAG_SUBFILETYPE, (uint32_t)FILETYPE_PAGE) &&
                 TIFFSetField(t, TIFFTAG_PAGENUMBER, (uint16_t)pg, (uint16_t)pages);
        const float *img = pix + (size_t)pg * (size_t)height * row;
        for (int y = 0; y < height && ok; y++)
            ok = TIFFWriteScanline(t, (void *)(img + (size_t)y * row), (uint32_t)y, 0) == 1;
        if (ok) ok = TIFFWriteDirectory(t) == 1;
    }
    TIFFClose(t);
    if (!ok) {
        gs_atomic_abort(&a);
        return gs_fail(GS_EIO, "%s: TIFF write failed: %s", path, tiff_msg);
    }
    return gs_atomic_commit(&a);
}

gs_status gs_tiff_read_float(const char *path, int *width, int *height, int *bands, int *pages,
                             float **pix)
{
    *pix = NULL;
    *width = *height = *bands = *pages = 0;
    tiff_quiet();
    gs_status in = gs_input_check(path);   /* libtiff reads by name: a regular file */
    if (in != GS_OK) return in;
    TIFF *t = TIFFOpen(path, "r");
    if (!t) return gs_fail(GS_EFORMAT, "%s: not a TIFF file: %s", path, tiff_msg);
    int np = 0;
    do np++;
    while (TIFFReadDirectory(t));
    TIFFSetDirectory(t, 0);
    gs_status st = GS_OK;
    float *out = NULL;
    uint32_t w0 = 0, h0 = 0;
    uint16_t b0 = 0;
    for (int pg = 0; pg < np && st == GS_OK; pg++) {
        if (pg && !TIFFSetDirectory(t, (uint16_t)pg)) {
            st = gs_fail(GS_EFORMAT, "%s: page %d cannot be read: %s", path, pg, tiff_msg);
            break;
        }
        uint32_t w = 0, h = 0;
        uint16_t spp = 1, bps = 1, fmt = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
        TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &w);
        TIFFGetField(t, TIFFTAG_IMAGELENGTH, &h);
        TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLESPERPIXEL, &spp);
        TIFFGetFieldDefaulted(t, TIFFTAG_BITSPERSAMPLE, &bps);
        TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLEFORMAT, &fmt);
        TIFFGetFieldDefaulted(t, TIFFTAG_PLANARCONFIG, &planar);
        if (bps != 32 || fmt != SAMPLEFORMAT_IEEEFP || (spp != 1 && spp != 3) ||
            planar != PLANARCONFIG_CONTIG || w < 1 || h < 1 || w > 65535 || h > 65535) {
            st = gs_fail(GS_EFORMAT, "%s: page %d has %u-bit samples of format %u, %u per pixel, "
                         "%ux%u: expected 32-bit float (format 3), 1 or 3 samples, contiguous",
                         path, pg, bps, fmt, spp, w, h);
            break;
        }
        if (pg == 0) {
            w0 = w;
            h0 = h;
            b0 = spp;
            out = malloc((size_t)np * w * h * spp * sizeof *out);
            if (!out) {
                st = gs_fail(GS_ENOMEM, "%s: cannot hold %d pages of %ux%u", path, np, w, h);
                break;
            }
        } else if (w != w0 || h != h0 || spp != b0) {
            st = gs_fail(GS_EFORMAT, "%s: page %d is %ux%ux%u: expected %ux%ux%u as page 0", path,
                         pg, w, h, spp, w0, h0, b0);
            break;
        }
        if (TIFFScanlineSize(t) != (tmsize_t)((size_t)w * spp * 4)) {
            st = gs_fail(GS_EFORMAT, "%s: page %d: unexpected scanline size", path, pg);
            break;
        }
        float *img = out + (size_t)pg * w * h * spp;
        for (uint32_t y = 0; y < h; y++)
            if (TIFFReadScanline(t, img + (size_t)y * w * spp, y, 0) != 1) {
                st = gs_fail(GS_EFORMAT, "%s: page %d row %u cannot be read: %s", path, pg, y,
                             tiff_msg);
                break;
            }
    }
    TIFFClose(t);
    if (st != GS_OK) {
        free(out);
        return st;
    }
    *pix = out;
    *width = (int)w0;
    *height = (int)h0;
    *bands = b0;
    *pages = np;
    return GS_OK;
}
