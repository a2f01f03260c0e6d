/* fuzz_recording.c - photodiode recordings (`delight add --from-recording`, oscilloscope CSV)
 * through gs_recording_to_bulb, with and without a voltage column. */
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(recording)
{
    if (size < 1) return 0;
    gs_bulb b;
    memset(&b, 0, sizeof b);
    const char *path = fuzz_file("fuzz-recording.csv", data + 1, size - 1);
    if (gs_recording_to_bulb(path, data[0] & 1 ? 2 : 0, 64, &b, NULL) == GS_OK) gs_bulb_release(&b);
    return 0;
}
