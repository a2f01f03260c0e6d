/* fuzz_csv.c - the format kit's CSV reader (gs_csv_read: DELIGHT CSV, recordings, pixel
 * lists), every field touched by the row function. */
#include "tests/fuzz/fuzz.h"

static gs_status fuzz_csv_row(void *ctx, char **fields, size_t count, size_t line)
{
    size_t *sum = ctx;
    for (size_t i = 0; i < count; i++) *sum += strlen(fields[i]) + line;
    return count > 1000 ? gs_fail(GS_EFORMAT, "too many fields") : GS_OK;
}

FUZZ_TARGET(csv)
{
    size_t sum = 0;
    gs_csv_read(fuzz_file("fuzz.csv", data, size), (size_t)1 << 20, fuzz_csv_row, &sum);
    return 0;
}
