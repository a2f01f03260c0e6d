/* fuzz_scene.c - scene JSON (gridsurvey-scene/1: inline lights, GeoJSON light files, street
 * grids, effects) through cap_scene_parse; a GeoJSON file "lights.geojson" beside it.
 *
 * The fuzzing binary skips a scene whose street grids would lay out more than FUZZ_GRID_MAX
 * lights (before their range and image tests): such a grid runs the same loop longer (the
 * seed metro.json's 41,000 take 0.13 s under the sanitizers), not other code. Only grids whose
 * size and spacings are inside the parser's ranges count, so every range check on them is still
 * reached. How many lights a scene may ask for is the memory budget's question
 * (docs/reliability.md, "Memory"); the replay in `make check` parses every input whole. */
#include "capture/capture.h"
#include "tests/fuzz/fuzz.h"

#include <jansson.h>
#include <math.h>

#ifndef FUZZ_REPLAY
#define FUZZ_GRID_MAX 4096.0

/* A number member inside [lo, hi], else NAN. */
static double grid_num(json_t *o, const char *key, double lo, double hi)
{
    json_t *v = json_object_get(o, key);
    double x = json_is_number(v) ? json_number_value(v) : NAN;
    return x >= lo && x <= hi ? x : NAN;
}

/* The lights laid out by the street grids of the scene text: streets every street_spacing_m
 * across a size_m rectangle in both directions, lights every light_spacing_m along them
 * (docs/scene.md; the ranges of capture/scene_lights.c). 0 for what is not such a grid. */
static double grid_lights(const char *text)
{
    json_t *doc = json_loads(text, 0, NULL);
    json_t *lights = json_object_get(doc, "lights");
    double total = 0;
    for (size_t i = 0; i < json_array_size(lights); i++) {
        json_t *b = json_array_get(lights, i), *size = json_object_get(b, "size_m");
        json_t *type = json_object_get(b, "type");
        if (!json_is_string(type) || strcmp(json_string_value(type), "street_grid") ||
            json_array_size(size) != 2)
            continue;
        double u = json_is_number(json_array_get(size, 0)) ? json_number_value(json_array_get(size, 0)) : NAN;
        double v = json_is_number(json_array_get(size, 1)) ? json_number_value(json_array_get(size, 1)) : NAN;
        double street = grid_num(b, "street_spacing_m", 10, 1e4);
        double spacing = grid_num(b, "light_spacing_m", 5, 1e4);
        if (!(u >= 1 && u <= 1e5 && v >= 1 && v <= 1e5 && street > 0 && spacing > 0)) continue;
        total += (floor(v / street) + 1) * floor(u / spacing) + (floor(u / street) + 1) * floor(v / spacing);
    }
    json_decref(doc);
    return total;
}
#endif

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
#ifndef FUZZ_REPLAY
    if (grid_lights(text) > FUZZ_GRID_MAX) {
        free(text);
        return 0;
    }
#endif
    cap_scene sc;
    cap_scene_parse(text, "fuzz-scene.json", fuzz_dir(), &sc);
    cap_scene_release(&sc);
    free(text);
    return 0;
}
