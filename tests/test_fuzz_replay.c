/* test_fuzz_replay.c - every libFuzzer target (tests/fuzz/fuzz_*.c, built here as plain functions
 * with FUZZ_REPLAY) over its seed corpus tests/fuzz/corpus/NAME/ and every past crash input
 * tests/fuzz/crashes/NAME/: each input must return normally (under `make test-asan` and
 * `make test-clang` also without a sanitizer report). docs/reliability.md. */
#define FUZZ_REPLAY 1
#include "tests/fuzz/fuzz_capture.c"
#include "tests/fuzz/fuzz_csv.c"
#include "tests/fuzz/fuzz_db.c"
#include "tests/fuzz/fuzz_delight_csv.c"
#include "tests/fuzz/fuzz_firmware.c"
#include "tests/fuzz/fuzz_geojson.c"
#include "tests/fuzz/fuzz_link.c"
#include "tests/fuzz/fuzz_pixels.c"
#include "tests/fuzz/fuzz_png.c"
#include "tests/fuzz/fuzz_recording.c"
#include "tests/fuzz/fuzz_scene.c"
#include "tests/fuzz/fuzz_station.c"
#include "tests/fuzz/fuzz_truth.c"
#include "tests/fuzz/fuzz_wav.c"
#include "tests/fixtures.h"
#include "tests/test.h"

#include <dirent.h>

static const struct {
    const char *name;
    int (*fn)(const uint8_t *, size_t);
} targets[] = {
    {"capture", fuzz_capture},         {"csv", fuzz_csv},           {"db", fuzz_db},
    {"delight_csv", fuzz_delight_csv}, {"firmware", fuzz_firmware}, {"geojson", fuzz_geojson},
    {"link", fuzz_link},               {"pixels", fuzz_pixels},     {"png", fuzz_png},
    {"recording", fuzz_recording},     {"scene", fuzz_scene},       {"station", fuzz_station},
    {"truth", fuzz_truth},             {"wav", fuzz_wav},
};

/* Every file of dir through fn; returns how many. */
static int replay_dir(const char *dir, int (*fn)(const uint8_t *, size_t))
{
    DIR *d = opendir(dir);
    if (!d) return 0;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.') continue;
        size_t size;
        char *data = fx_read_file(fx_path(dir, e->d_name), &size);
        CHECK_MSG(data != NULL, "%s/%s: cannot read", dir, e->d_name);
        if (!data) continue;
        CHECK_MSG(fn((const uint8_t *)data, size) == 0, "%s/%s", dir, e->d_name);
        free(data);
        n++;
    }
    closedir(d);
    return n;
}

TEST(fuzz_corpora_and_crash_inputs_replay)
{
    setenv("TMPDIR", test_tmpdir(), 1);   /* the targets' scratch files */
    for (size_t i = 0; i < sizeof targets / sizeof *targets; i++) {
        char corpus[256], crashes[256];
        snprintf(corpus, sizeof corpus, "tests/fuzz/corpus/%s", targets[i].name);
        snprintf(crashes, sizeof crashes, "tests/fuzz/crashes/%s", targets[i].name);
        int n = replay_dir(corpus, targets[i].fn);
        CHECK_MSG(n >= 1, "%s: no seed inputs", corpus);
        replay_dir(crashes, targets[i].fn);
    }
    /* (the empty input, which libFuzzer always tries first) */
    for (size_t i = 0; i < sizeof targets / sizeof *targets; i++) CHECK(targets[i].fn((const uint8_t *)"", 0) == 0);
}
