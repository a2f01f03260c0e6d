/* png.c - PNG images of the capture format (docs/formats.md) through libspng: 16-bit grey or
 * RGB frames and 8-bit grey maps. The decoder is told the size it must find before it
 * allocates anything (spng_set_image_limits), checks every chunk's CRC and length, and reads
 * the chunks after the image data up to IEND, so a truncated or corrupt file is named as such.
 * Samples cross this boundary host-endian, R, G, B interleaved, row-major. */
#include "recognize/base/base.h"

#include <spng.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static const char *color_name(int t)
{
    switch (t) {
    case SPNG_COLOR_TYPE_GRAYSCALE: return "grey";
    case SPNG_COLOR_TYPE_TRUECOLOR: return "RGB";
    case SPNG_COLOR_TYPE_INDEXED: return "palette";
    case SPNG_COLOR_TYPE_GRAYSCALE_ALPHA: return "grey+alpha";
    case SPNG_COLOR_TYPE_TRUECOLOR_ALPHA: return "RGBA";
    }
    return "unknown";
}

/* The one-line detail of a libspng error while reading name. */
static gs_status png_error(int err, const char *name, size_t size, const char *ref)
{
    switch (err) {
    case SPNG_IO_EOF:
    case SPNG_EOF:
    case SPNG_EIDAT_TOO_SHORT:
    case SPNG_ECHUNK_SIZE:
        return gs_fail(GS_EFORMAT, "%s: truncated PNG: the file ends at byte %zu before the end of "
                       "the IEND chunk (%s)%s", name, size, spng_strerror(err), ref);
    case SPNG_ECHUNK_CRC:
        return gs_fail(GS_EFORMAT, "%s: corrupt PNG: chunk data fails its CRC%s", name, ref);
    case SPNG_EIDAT_STREAM:
    case SPNG_EZLIB:
        return gs_fail(GS_EFORMAT, "%s: corrupt PNG: the image data (IDAT) does not decompress "
                       "(%s)%s", name, spng_strerror(err), ref);
    }
    return gs_fail(GS_EFORMAT, "%s: corrupt PNG: %s%s", name, spng_strerror(err), ref);
}

/* Whether the file holds IEND whole: libspng takes an IEND whose CRC is cut short for a whole
 * one (and checks the CRC when it is there), so a file missing its last 1-4 bytes read as
 * complete. The last IEND header (length 0, "IEND") must be followed by its 4 CRC bytes. */
static int iend_whole(const unsigned char *buf, size_t size)
{
    static const unsigned char head[8] = {0, 0, 0, 0, 'I', 'E', 'N', 'D'};
    for (size_t i = size >= 8 ? size - 8 + 1 : 0; i-- > 0;)
        if (!memcmp(buf + i, head, sizeof head)) return size - i >= 12;
    return 0;
}

gs_status gs_png_decode(const unsigned char *buf, size_t size, const char *name, const char *ref,
                        int width, int height, int channels, int bits, void *out)
{
    if (!buf || !name || !ref || !out || width < 1 || height < 1 ||
        (channels != 1 && channels != 3) || (bits != 8 && bits != 16))
        return gs_fail(GS_EINVAL, "gs_png_decode: bad arguments");
    if (size < 8)
        return gs_fail(GS_EFORMAT, "%s: not a PNG file (shorter than the 8-byte signature)%s",
                       name, ref);
    /* here, not by libspng: it reads the signature and IHDR (33 bytes) at once, so a shorter
     * file that is no PNG would be called truncated */
    if (memcmp(buf, "\x89PNG\r\n\x1a\n", 8))
        return gs_fail(GS_EFORMAT, "%s: not a PNG file (no PNG signature)%s", name, ref);
    spng_ctx *ctx = spng_ctx_new(0);
    if (!ctx) return gs_fail(GS_ENOMEM, "%s: cannot create a PNG decoder", name);
    gs_status st = GS_OK;
    struct spng_ihdr ih;
    int err = spng_set_png_buffer(ctx, buf, size);
    /* refuse a larger image before anything is allocated (the size check below names it) */
    if (!err) err = spng_set_image_limits(ctx, (uint32_t)width + 1, (uint32_t)height + 1);
    if (!err) err = spng_get_ihdr(ctx, &ih);
    if (err == SPNG_EUSER_WIDTH || err == SPNG_EUSER_HEIGHT) {
        st = gs_fail(GS_EFORMAT, "%s: PNG is larger than width x height = %dx%d%s", name, width,
                     height, ref);
        goto done;
    }
    if (err) {
        st = png_error(err, name, size, ref);
        goto done;
    }
    int want_color = channels == 3 ? SPNG_COLOR_TYPE_TRUECOLOR : SPNG_COLOR_TYPE_GRAYSCALE;
    if (ih.width != (uint32_t)width || ih.height != (uint32_t)height)
        st = gs_fail(GS_EFORMAT, "%s: PNG is %ux%u pixels: expected width x height = %dx%d%s",
                     name, ih.width, ih.height, width, height, ref);
    else if (ih.bit_depth != bits)
        st = gs_fail(GS_EFORMAT, "%s: PNG has %d-bit samples: expected %d-bit%s", name,
                     ih.bit_depth, bits, ref);
    else if (ih.color_type != want_color)
        st = gs_fail(GS_EFORMAT, "%s: PNG colour type is %s: expected %s (%d channel%s)%s", name,
                     color_name(ih.color_type), color_name(want_color), channels,
                     channels == 1 ? "" : "s", ref);
    if (st != GS_OK) goto done;
    size_t need = (size_t)width * (size_t)height * (size_t)channels * (size_t)(bits / 8), len;
    err = spng_decoded_image_size(ctx, SPNG_FMT_PNG, &len);
    if (!err && len != need) err = SPNG_EINTERNAL;
    if (!err) err = spng_decode_image(ctx, out, need, SPNG_FMT_PNG, 0);
    if (!err) err = spng_decode_chunks(ctx);   /* the chunks after IDAT, through IEND */
    if (!err && !iend_whole(buf, size)) err = SPNG_EOF;
    if (err) st = png_error(err, name, size, ref);
done:
    spng_ctx_free(ctx);
    return st;
}

gs_status gs_png_encode(const void *pixels, int width, int height, int channels, int bits,
                        unsigned char **png, size_t *size)
{
    if (!pixels || !png || !size || width < 1 || height < 1 || (channels != 1 && channels != 3) ||
        (bits != 8 && bits != 16))
        return gs_fail(GS_EINVAL, "gs_png_encode: bad arguments");
    *png = NULL;
    *size = 0;
    spng_ctx *ctx = spng_ctx_new(SPNG_CTX_ENCODER);
    if (!ctx) return gs_fail(GS_ENOMEM, "cannot create a PNG encoder");
    struct spng_ihdr ih = {
        .width = (uint32_t)width,
        .height = (uint32_t)height,
        .bit_depth = (uint8_t)bits,
        .color_type = (uint8_t)(channels == 3 ? SPNG_COLOR_TYPE_TRUECOLOR
                                              : SPNG_COLOR_TYPE_GRAYSCALE),
    };
    size_t len = (size_t)width * (size_t)height * (size_t)channels * (size_t)(bits / 8);
    /* fast settings: raw sensor data compresses little whatever the effort */
    int err = spng_set_option(ctx, SPNG_ENCODE_TO_BUFFER, 1);
    if (!err) err = spng_set_option(ctx, SPNG_IMG_COMPRESSION_LEVEL, 1);
    if (!err) err = spng_set_option(ctx, SPNG_FILTER_CHOICE, SPNG_FILTER_CHOICE_SUB);
    if (!err) err = spng_set_ihdr(ctx, &ih);
    if (!err) err = spng_encode_image(ctx, pixels, len, SPNG_FMT_PNG, SPNG_ENCODE_FINALIZE);
    gs_status st = GS_OK;
    if (!err) {
        *png = spng_get_png_buffer(ctx, size, &err);   /* ours to free() from now on */
        if (!*png && !err) err = SPNG_EMEM;
    }
    if (err) st = gs_fail(err == SPNG_EMEM ? GS_ENOMEM : GS_EINVAL, "PNG encoder: %s",
                          spng_strerror(err));
    spng_ctx_free(ctx);
    return st;
}
