/* fuzz_scene.c - scene JSON (gridsurvey-scene/1: inline lights, GeoJSON light files, street
 * grids, effects) through cap_scene_parse; a GeoJSON file "lights.geojson" beside it.
 *
 * The fuzzing binary parses under a memory budget of 16 MiB (the replay in `make check`: the
 * default budget): a street grid's positions are checked against the budget before any is
 * generated (capture/scene_lights.c), so a grid of up to about 5,000 positions is generated
 * and a bigger one refused at once, and each input takes milliseconds. */
#include "capture/capture.h"
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(scene)
{
    static int ready;
    if (!ready++) {
#ifndef FUZZ_REPLAY
        gs_mem_budget_set((size_t)16 << 20);
#endif
        static const char gj[] = "{\"type\": \"FeatureCollection\", \"features\": [{\"type\": "
            "\"Feature\", \"geometry\": {\"type\": \"Point\", \"coordinates\": [35.03, 32.82, 25]},"
            " \"properties\": {\"id\": \"a\", \"bulb\": \"hps-150w\", \"lumens\": 15000}}]}\n";
        fuzz_file("lights.geojson", gj, sizeof gj - 1);
    }
    char *text = fuzz_text(data, size);
    cap_scene sc;
    cap_scene_parse(text, "fuzz-scene.json", fuzz_dir(), &sc);
    cap_scene_release(&sc);
    free(text);
    return 0;
}
