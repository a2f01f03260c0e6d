/* fuzz_pixels.c - pixel CSVs as `gridsurvey locate --pixels` reads them (survey/cmd_locate.c, the
 * command itself on a fixed station): the command returns 0 (and wrote its output) or 1 (a bad
 * input), never 2 (a usage error: the arguments are fixed and valid). */
#include "tests/fuzz/fuzz.h"
#include "survey/internal.h"

static const char fuzz_pixels_station[] =
    "{\"format\": \"gridsurvey-station/1\", \"lat_deg\": 32.794, \"lon_deg\": 34.99,"
    " \"height_m\": 470, \"heading_deg\": 52, \"pitch_deg\": -5, \"roll_deg\": 0.5,"
    " \"focal_px\": 2000, \"cx_px\": 400, \"cy_px\": 300, \"width_px\": 800, \"height_px\": 600,"
    " \"sigma_px\": 0.7, \"id\": \"carmel\"}";

FUZZ_TARGET(pixels)
{
    char station[700], pixels[700], out[700];
    snprintf(station, sizeof station, "%s",
             fuzz_file("fuzz-station.json", fuzz_pixels_station, sizeof fuzz_pixels_station - 1));
    snprintf(pixels, sizeof pixels, "%s", fuzz_file("fuzz-pixels.csv", data, size));
    snprintf(out, sizeof out, "%s/fuzz-located.csv", fuzz_dir());
    char *argv[] = {"locate", "--station", station, "--pixels", pixels, "-o", out, NULL};
    int rc = srv_cmd_locate(7, argv);
    if (rc != 0 && rc != 1) abort();
    if (rc == 0 && access(out, F_OK) != 0) abort();
    unlink(out);
    return 0;
}
