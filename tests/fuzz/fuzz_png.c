/* fuzz_png.c - frame PNGs and HDR maps through gs_png_decode: the first byte picks the
 * expected channels and depth, the next two the expected width and height (1..64). */
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(png)
{
    if (size < 3) return 0;
    int channels = data[0] & 1 ? 3 : 1, bits = data[0] & 2 ? 8 : 16;
    int w = 1 + data[1] % 64, h = 1 + data[2] % 64;
    void *out = malloc((size_t)w * (size_t)h * (size_t)channels * (size_t)(bits / 8));
    if (!out) abort();
    gs_png_decode(data + 3, size - 3, "fuzz.png", "", w, h, channels, bits, out);
    free(out);
    return 0;
}
