/* fuzz_capture.c - capture.json through gs_capture_read, beside two valid 4x4 16-bit grey
 * frames f0.png, f1.png and an HDR map h0.png (so that JSON naming them reaches the pixels).
 * The memory budget is 256 MiB (gs_mem_check), under libFuzzer's -rss_limit_mb. */
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(capture)
{
    static int ready;
    if (!ready++) {
        gs_mem_budget_set((size_t)256 << 20);
        unsigned short px[16];
        unsigned char h[16] = {0};
        for (int i = 0; i < 16; i++) px[i] = (unsigned short)(100 * i);
        unsigned char *png;
        size_t n;
        if (gs_png_encode(px, 4, 4, 1, 16, &png, &n) != GS_OK) abort();
        fuzz_file("f0.png", png, n);
        fuzz_file("f1.png", png, n);
        free(png);
        if (gs_png_encode(h, 4, 4, 1, 8, &png, &n) != GS_OK) abort();
        fuzz_file("h0.png", png, n);
        free(png);
    }
    fuzz_file("capture.json", data, size);
    gs_capture c;
    if (gs_capture_read(fuzz_dir(), &c) == GS_OK) gs_capture_release(&c);
    return 0;
}
