/* fuzz_station.c - station files and capture.json "station" objects (gis_station_parse). */
#include "tests/fuzz/fuzz.h"
#include "gis/gis.h"

FUZZ_TARGET(station)
{
    char *text = fuzz_text(data, size);
    gis_station st;
    gis_station_parse(text, "fuzz-station.json", &st);
    free(text);
    return 0;
}
