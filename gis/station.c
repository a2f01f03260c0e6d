/* station.c - station files (gis.h): one JSON object with the camera's position, pose,
 * intrinsics and sigmas, parsed with Jansson. Errors name the file, the line and the field. */
#include "gis/internal.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { F_NUM, F_INT, F_STR };

typedef struct {
    const char *name;    /* canonical key (units in the name) */
    const char *alias;   /* short key also accepted, or NULL */
    int kind;
    int required;
    size_t offset;       /* into gis_station */
    size_t size;         /* for strings */
} field;

#define CAM(m) offsetof(gis_station, cam) + offsetof(gis_camera, m)
static const field fields[] = {
    {"lat_deg", "lat", F_NUM, 1, CAM(lat_deg), 0},
    {"lon_deg", "lon", F_NUM, 1, CAM(lon_deg), 0},
    {"height_m", "height", F_NUM, 1, CAM(height_m), 0},
    {"heading_deg", "heading", F_NUM, 1, CAM(heading_deg), 0},
    {"pitch_deg", "pitch", F_NUM, 1, CAM(pitch_deg), 0},
    {"roll_deg", "roll", F_NUM, 0, CAM(roll_deg), 0},
    {"focal_px", NULL, F_NUM, 1, CAM(focal_px), 0},
    {"cx_px", "cx", F_NUM, 1, CAM(cx_px), 0},
    {"cy_px", "cy", F_NUM, 1, CAM(cy_px), 0},
    {"k1", NULL, F_NUM, 0, CAM(k1), 0},
    {"k2", NULL, F_NUM, 0, CAM(k2), 0},
    {"width_px", NULL, F_INT, 0, CAM(width_px), 0},
    {"height_px", NULL, F_INT, 0, CAM(height_px), 0},
    {"sigma_heading_deg", "sigma_heading", F_NUM, 0, CAM(sigma_heading_deg), 0},
    {"sigma_pitch_deg", "sigma_pitch", F_NUM, 0, CAM(sigma_pitch_deg), 0},
    {"sigma_roll_deg", "sigma_roll", F_NUM, 0, CAM(sigma_roll_deg), 0},
    {"refraction_k", NULL, F_NUM, 0, CAM(refraction_k), 0},
    {"sigma_px", NULL, F_NUM, 0, offsetof(gis_station, sigma_px), 0},
    {"psf_sigma_px", NULL, F_NUM, 0, offsetof(gis_station, psf_sigma_px), 0},
    {"id", NULL, F_STR, 0, offsetof(gis_station, id), GIS_TEXT_MAX},
    {"time_utc", NULL, F_STR, 0, offsetof(gis_station, time_utc), 40},
};
#define N_FIELDS (sizeof fields / sizeof *fields)

static const field *find_field(const char *key, int *by_alias)
{
    for (size_t i = 0; i < N_FIELDS; i++) {
        if (!strcmp(key, fields[i].name)) {
            *by_alias = 0;
            return &fields[i];
        }
        if (fields[i].alias && !strcmp(key, fields[i].alias)) {
            *by_alias = 1;
            return &fields[i];
        }
    }
    return NULL;
}

/* The station's fields (names and aliases) as a NULL-terminated list for gs_json_check_keys. */
static const char *const *allowed_keys(void)
{
    static const char *keys[2 * N_FIELDS + 2];
    if (!keys[0]) {
        size_t n = 0;
        keys[n++] = "format";
        for (size_t i = 0; i < N_FIELDS; i++) {
            keys[n++] = fields[i].name;
            if (fields[i].alias) keys[n++] = fields[i].alias;
        }
        keys[n] = NULL;
    }
    return keys;
}

gs_status gis_station_parse(const char *json_text, const char *source, gis_station *st)
{
    memset(st, 0, sizeof *st);
    st->sigma_px = NAN;
    st->psf_sigma_px = NAN;
    if (!source) source = "station";
    gs_json *doc;
    gs_status s = gs_json_parse(json_text, strlen(json_text), source, &doc);
    if (s != GS_OK) return s;
    json_t *root = gs_json_root(doc);
    const char *key;
    json_t *v;
    unsigned char seen[N_FIELDS] = {0};
    const char *used_key[N_FIELDS] = {0};
    if (!json_is_object(root)) {
        s = gs_fail(GS_EFORMAT, "%s:1: expected a JSON object (a %s station)", source, GIS_STATION_FORMAT);
        goto done;
    }
    if ((s = gs_json_check_keys(doc, root, "", allowed_keys())) != GS_OK) goto done;
    json_object_foreach(root, key, v) {
        if (!strcmp(key, "format")) {
            if (!json_is_string(v) || strcmp(json_string_value(v), GIS_STATION_FORMAT)) {
                s = gs_json_fail(doc, GS_EFORMAT, key, "expected \"%s\"", GIS_STATION_FORMAT);
                goto done;
            }
            continue;
        }
        int by_alias = 0;
        const field *f = find_field(key, &by_alias);
        if (!f) continue;   /* an extension (gs_json_check_keys let it through) */
        size_t i = (size_t)(f - fields);
        if (seen[i]) {
            s = gs_json_fail(doc, GS_EFORMAT, key, "%s given twice (as \"%s\" and \"%s\")",
                             f->name, used_key[i], key);
            goto done;
        }
        seen[i] = 1;
        used_key[i] = key;
        char *dst = (char *)st + f->offset;
        if (f->kind == F_NUM) {
            double d;
            if ((s = gs_json_get_num(doc, root, "", key, 1, 0, -HUGE_VAL, HUGE_VAL, "a number", &d)) != GS_OK)
                goto done;
            memcpy(dst, &d, sizeof d);
        } else if (f->kind == F_INT) {
            long long d;
            if ((s = gs_json_get_int(doc, root, "", key, 1, 0, 0, 1000000, NULL, &d)) != GS_OK) goto done;
            int di = (int)d;
            memcpy(dst, &di, sizeof di);
        } else if ((s = gs_json_get_str(doc, root, "", key, 1, NULL, dst, f->size)) != GS_OK) {
            goto done;
        } else if (!gs_text_clean(dst)) {   /* (every export refused it, after the work) */
            s = gs_json_fail(doc, GS_EFORMAT, key, "expected text without control characters");
            goto done;
        }
    }
    for (size_t i = 0; i < N_FIELDS; i++)
        if (fields[i].required && !seen[i]) {
            s = gs_json_fail(doc, GS_EFORMAT, fields[i].name, "expected a number (the field is "
                             "missing; see docs/gis.md for the station fields)");
            goto done;
        }
    if (st->time_utc[0] && !gs_capture_valid_utc(st->time_utc)) {
        s = gs_json_fail(doc, GS_EFORMAT, "time_utc", "expected " GS_CAPTURE_EXP_UTC);
        goto done;
    }
    /* NaN = not given (JSON has no NaN): without a PSF, sigma_px is every light's pixel sigma
     * (1 px); with one, the calibration residual added to each light's centroid sigma (0) */
    if (isnan(st->sigma_px)) st->sigma_px = isnan(st->psf_sigma_px) ? 1.0 : 0.0;
    if (!(st->sigma_px >= 0.0) || !isfinite(st->sigma_px)) {
        s = gs_json_fail(doc, GS_EFORMAT, "sigma_px", "expected a value >= 0");
        goto done;
    }
    if (!isnan(st->psf_sigma_px) && !(st->psf_sigma_px >= 0.0 && st->psf_sigma_px <= 50.0)) {
        s = gs_json_fail(doc, GS_EFORMAT, "psf_sigma_px", "expected a value from 0 to 50");
        goto done;
    }
    s = gis_camera_check(&st->cam);
    if (s != GS_OK) {
        /* The detail reads "camera: FIELD ...": point at that field's line. */
        char msg[400];
        snprintf(msg, sizeof msg, "%s", gs_detail());
        const char *rest = strncmp(msg, "camera: ", 8) ? msg : msg + 8;
        const char *at = "(document)";
        for (size_t i = 0; i < N_FIELDS; i++) {
            size_t n = strlen(fields[i].name);
            if (!strncmp(rest, fields[i].name, n) && (rest[n] == ' ' || rest[n] == ':')) {
                at = used_key[i] ? used_key[i] : fields[i].name;
                break;
            }
        }
        s = gs_json_fail(doc, GS_EFORMAT, at, "%s", rest);
    }
done:
    gs_json_free(doc);
    return s;
}

gs_status gis_station_read(const char *path, gis_station *st)
{
    char *buf;
    size_t n;
    /* a station file is a few hundred bytes: 64 MiB bounds one that is not */
    gs_status s = gs_file_read(path, (size_t)64 << 20, &buf, &n);
    if (s != GS_OK) return s;
    if (strlen(buf) != n) s = gs_fail(GS_EFORMAT, "%s: contains a NUL byte: not JSON text", path);
    else s = gis_station_parse(buf, path, st);
    free(buf);
    return s;
}
