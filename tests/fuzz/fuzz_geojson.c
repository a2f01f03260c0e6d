/* fuzz_geojson.c - a scene's GeoJSON light file (the scene fixed, the file fuzzed). */
#include "capture/capture.h"
#include "tests/fuzz/fuzz.h"

FUZZ_TARGET(geojson)
{
    static const char scene[] =
        "{\"format\": \"gridsurvey-scene/1\", \"grid\": {\"nominal_hz\": 50},\n"
        " \"camera\": {\"width_px\": 800, \"height_px\": 600,\n"
        "   \"station\": {\"lat_deg\": 32.7940, \"lon_deg\": 34.9900, \"height_m\": 470},\n"
        "   \"pose\": {\"heading_deg\": 52, \"pitch_deg\": -5}, \"intrinsics\": {\"focal_px\": 2000}},\n"
        " \"acam\": {\"K\": 10, \"cycles\": 40},\n"
        " \"lights\": [{\"type\": \"geojson\", \"file\": \"fuzz.geojson\",\n"
        "              \"defaults\": {\"bulb\": \"mh-250w\", \"height_m\": 30}}]}\n";
    fuzz_file("fuzz.geojson", data, size);
    cap_scene sc;
    cap_scene_parse(scene, "geojson-scene.json", fuzz_dir(), &sc);
    cap_scene_release(&sc);
    return 0;
}
