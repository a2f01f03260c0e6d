/* fuzz_scene.c - scene JSON (gridsurvey-scene/1: inline lights, GeoJSON light files, street
 * grids, effects) through cap_scene_parse; a GeoJSON file "lights.geojson" beside it. */
#include "capture/capture.h"
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(scene)
{
    static int ready;
    if (!ready++) {
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
