/* areas.c - polygons a utility supplies (feeder areas, districts) as a GeoJSON FeatureCollection
 * of Polygon / MultiPolygon features in WGS84 longitude/latitude (RFC 7946), for
 * `stats --clip` (docs/survey-db.md, "Areas"). Geometry by GEOS (its GeoJSON reader and
 * prepared-geometry predicates): a point belongs to the first feature (in file order) that
 * covers it (its boundary included). Properties by jansson. */
#include "survey/internal.h"

#include <geos_c.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct srv_areas {
    GEOSContextHandle_t ctx;
    size_t n;
    GEOSGeometry **geom;
    const GEOSPreparedGeometry **prep;
    double (*box)[4];          /* min lon, min lat, max lon, max lat */
    char (*label)[96];
};

/* GEOS's messages are dropped: a failure is reported through the return values. */
static void geos_quiet(const char *message, void *userdata)
{
    (void)message;
    (void)userdata;
}

void srv_areas_free(srv_areas *a)
{
    if (!a) return;
    for (size_t i = 0; i < a->n; i++) {
        if (a->prep && a->prep[i]) GEOSPreparedGeom_destroy_r(a->ctx, a->prep[i]);
        if (a->geom && a->geom[i]) GEOSGeom_destroy_r(a->ctx, a->geom[i]);
    }
    free(a->geom);
    free(a->prep);
    free(a->box);
    free(a->label);
    if (a->ctx) GEOS_finish_r(a->ctx);
    free(a);
}

/* The property's value as a label: a string as it is, a number or boolean as JSON text. */
static int property_label(json_t *v, char *out, size_t size)
{
    if (json_is_string(v)) snprintf(out, size, "%s", json_string_value(v));
    else if (json_is_integer(v)) snprintf(out, size, "%lld", (long long)json_integer_value(v));
    else if (json_is_real(v)) snprintf(out, size, "%.15g", json_real_value(v));
    else if (json_is_boolean(v)) snprintf(out, size, "%s", json_is_true(v) ? "true" : "false");
    else return 0;
    return 1;
}

gs_status srv_areas_load(const char *path, const char *field, srv_areas **out)
{
    if (!path || !out) return gs_fail(GS_EINVAL, "srv_areas_load: NULL argument");
    *out = NULL;
    json_error_t err;
    json_t *root = json_load_file(path, 0, &err);
    if (!root)
        return gs_fail(GS_EFORMAT, "%s: line %d: %s: expected a GeoJSON FeatureCollection", path,
                       err.line, err.text);
    json_t *features = json_object_get(root, "features");
    const char *type = json_string_value(json_object_get(root, "type"));
    gs_status s = GS_OK;
    srv_areas *a = calloc(1, sizeof *a);
    size_t n = json_array_size(features);
    if (!type || strcmp(type, "FeatureCollection") || !json_is_array(features) || n == 0) {
        s = gs_fail(GS_EFORMAT, "%s: type '%s': expected a GeoJSON FeatureCollection with at least "
                    "one feature", path, type ? type : "(none)");
        goto done;
    }
    if (!a || !(a->ctx = GEOS_init_r()) || !(a->geom = calloc(n, sizeof *a->geom)) ||
        !(a->prep = calloc(n, sizeof *a->prep)) || !(a->box = calloc(n, sizeof *a->box)) ||
        !(a->label = calloc(n, sizeof *a->label))) {
        s = gs_fail(GS_ENOMEM, "%s: out of memory for %zu areas", path, n);
        goto done;
    }
    GEOSContext_setErrorMessageHandler_r(a->ctx, geos_quiet, NULL);
    GEOSContext_setNoticeMessageHandler_r(a->ctx, geos_quiet, NULL);
    GEOSGeoJSONReader *rd = GEOSGeoJSONReader_create_r(a->ctx);
    for (size_t i = 0; i < n && s == GS_OK; i++) {
        json_t *f = json_array_get(features, i), *g = json_object_get(f, "geometry");
        const char *gt = json_string_value(json_object_get(g, "type"));
        if (!gt || (strcmp(gt, "Polygon") && strcmp(gt, "MultiPolygon"))) {
            s = gs_fail(GS_EFORMAT, "%s: feature %zu: geometry type '%s': expected Polygon or "
                        "MultiPolygon", path, i, gt ? gt : "(none)");
            break;
        }
        if (field) {
            json_t *v = json_object_get(json_object_get(f, "properties"), field);
            if (!property_label(v, a->label[i], sizeof a->label[i])) {
                s = gs_fail(GS_EFORMAT, "%s: feature %zu: property '%s': expected a string, number "
                            "or boolean", path, i, field);
                break;
            }
        } else {
            snprintf(a->label[i], sizeof a->label[i], "feature %zu", i);
        }
        char *text = json_dumps(g, JSON_COMPACT);
        a->geom[i] = text ? GEOSGeoJSONReader_readGeometry_r(a->ctx, rd, text) : NULL;
        free(text);
        a->n = i + 1;
        double x0, y0, x1, y1;
        if (!a->geom[i] || !GEOSisValid_r(a->ctx, a->geom[i]) ||
            !GEOSGeom_getXMin_r(a->ctx, a->geom[i], &x0) || !GEOSGeom_getYMin_r(a->ctx, a->geom[i], &y0) ||
            !GEOSGeom_getXMax_r(a->ctx, a->geom[i], &x1) || !GEOSGeom_getYMax_r(a->ctx, a->geom[i], &y1)) {
            s = gs_fail(GS_EFORMAT, "%s: feature %zu: expected a valid %s (closed rings of "
                        "[longitude, latitude] positions that do not self-intersect)", path, i, gt);
            break;
        }
        if (x0 < -180.0 || x1 > 180.0 || y0 < -90.0 || y1 > 90.0) {
            s = gs_fail(GS_EFORMAT, "%s: feature %zu: coordinates outside longitude [-180, 180], "
                        "latitude [-90, 90]", path, i);
            break;
        }
        a->box[i][0] = x0;
        a->box[i][1] = y0;
        a->box[i][2] = x1;
        a->box[i][3] = y1;
        a->prep[i] = GEOSPrepare_r(a->ctx, a->geom[i]);
        if (!a->prep[i]) s = gs_fail(GS_ENOMEM, "%s: feature %zu: cannot prepare the geometry", path, i);
    }
    GEOSGeoJSONReader_destroy_r(a->ctx, rd);
done:
    json_decref(root);
    if (s != GS_OK) {
        srv_areas_free(a);
        return s;
    }
    *out = a;
    return GS_OK;
}

size_t srv_areas_count(const srv_areas *a)
{
    return a ? a->n : 0;
}

const char *srv_areas_label(const srv_areas *a, size_t i)
{
    return a && i < a->n ? a->label[i] : "";
}

int srv_areas_find(const srv_areas *a, double lat_deg, double lon_deg)
{
    if (!a || !isfinite(lat_deg) || !isfinite(lon_deg)) return -1;
    /* the 180 deg meridian is stored as -180 (gs_wrap180), and a polygon may draw it at +180 */
    double lon[2] = {gs_wrap180(lon_deg), 180.0};
    int nlon = lon[0] == -180.0 ? 2 : 1;
    GEOSGeometry *p[2] = {NULL, NULL};
    int found = -1;
    for (size_t i = 0; i < a->n && found < 0; i++)
        for (int q = 0; q < nlon && found < 0; q++) {
            if (lon[q] < a->box[i][0] || lon[q] > a->box[i][2] || lat_deg < a->box[i][1] || lat_deg > a->box[i][3])
                continue;
            if (!p[q] && !(p[q] = GEOSGeom_createPointFromXY_r(a->ctx, lon[q], lat_deg))) break;
            if (GEOSPreparedCovers_r(a->ctx, a->prep[i], p[q]) == 1) found = (int)i;
        }
    for (int q = 0; q < 2; q++)
        if (p[q]) GEOSGeom_destroy_r(a->ctx, p[q]);
    return found;
}

gs_status srv_areas_wkt(const srv_areas *a, const char *label, char **wkt)
{
    *wkt = NULL;
    if (!a || !label) return gs_fail(GS_EINVAL, "srv_areas_wkt: NULL argument");
    GEOSGeometry **parts = calloc(a->n ? a->n : 1, sizeof *parts);
    if (!parts) return gs_fail(GS_ENOMEM, "areas: out of memory");
    unsigned k = 0;
    gs_status s = GS_OK;
    for (size_t i = 0; i < a->n && s == GS_OK; i++) {
        if (strcmp(a->label[i], label)) continue;
        if (!(parts[k] = GEOSGeom_clone_r(a->ctx, a->geom[i]))) s = gs_fail(GS_ENOMEM, "areas: out of memory");
        else k++;
    }
    if (s == GS_OK && !k) s = gs_fail(GS_ENOTFOUND, "areas: no feature named '%s'", label);
    /* the features of one label as one geometry: a collection (which owns the parts), then
     * its union (overlapping features merged) */
    GEOSGeometry *coll = NULL, *u = NULL;
    if (s == GS_OK && !(coll = GEOSGeom_createCollection_r(a->ctx, GEOS_GEOMETRYCOLLECTION, parts, k)))
        s = gs_fail(GS_ENOMEM, "areas: out of memory");
    if (!coll)
        for (unsigned i = 0; i < k; i++) GEOSGeom_destroy_r(a->ctx, parts[i]);
    free(parts);
    if (s == GS_OK && !(u = GEOSUnaryUnion_r(a->ctx, coll))) s = gs_fail(GS_ENUMERIC, "areas: '%s': union failed", label);
    GEOSWKTWriter *w = s == GS_OK ? GEOSWKTWriter_create_r(a->ctx) : NULL;
    char *t = NULL;
    if (w) {
        GEOSWKTWriter_setTrim_r(a->ctx, w, 1);
        GEOSWKTWriter_setRoundingPrecision_r(a->ctx, w, 9);
        t = GEOSWKTWriter_write_r(a->ctx, w, u);
        GEOSWKTWriter_destroy_r(a->ctx, w);
    }
    if (s == GS_OK && !(t && (*wkt = strdup(t)))) s = gs_fail(GS_ENOMEM, "areas: out of memory");
    if (t) GEOSFree_r(a->ctx, t);
    if (u) GEOSGeom_destroy_r(a->ctx, u);
    if (coll) GEOSGeom_destroy_r(a->ctx, coll);
    return s;
}
