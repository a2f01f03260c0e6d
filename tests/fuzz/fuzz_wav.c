/* fuzz_wav.c - mains-voltage recordings (the "trace" frequency model's WAV, capture/aclock.c)
 * through gs_mains_read: a recording it accepts has samples, a rate > 0 and only finite samples
 * (recognize/base/base.h). */
#include "tests/fuzz/fuzz.h"

#include <math.h>

FUZZ_TARGET(wav)
{
    double *x = NULL, rate_hz = 0.0;
    size_t n = 0;
    if (gs_mains_read(fuzz_file("fuzz-mains.wav", data, size), &x, &n, &rate_hz) != GS_OK) return 0;
    if (n == 0 || !(rate_hz > 0.0) || !isfinite(rate_hz)) abort();
    for (size_t i = 0; i < n; i++)
        if (!isfinite(x[i])) abort();
    free(x);
    return 0;
}
