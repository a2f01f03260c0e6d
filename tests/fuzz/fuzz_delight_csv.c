/* fuzz_delight_csv.c - `delight import` (gs_delight_import_csv) into an empty database. */
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(delight_csv)
{
    gs_delight *d = gs_delight_new();
    if (!d) abort();
    gs_delight_import_csv(d, fuzz_file("fuzz-delight.csv", data, size));
    gs_delight_free(d);
    return 0;
}
