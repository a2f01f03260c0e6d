/* station.c - station files (gis.h): one JSON object with the camera's position, pose,
 * intrinsics and sigmas, parsed with Jansson. Errors name the file, the line and the field. */
#include "gis/internal.h"

#include <errno.h>
#include <jansson.h>
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
    {"id", NULL, F_STR, 0, offsetof(gis_station, id), GIS_TEXT_MAX},
    {"time_utc", NULL, F_STR, 0, offsetof(gis_station, time_utc), 40},
};
#define N_FIELDS (sizeof fields / sizeof *fields)

/* The 1-based line of the first `"key" :` in text, or of the first '{' (or 1). */
static int key_line(const char *text, const char *key)
{
    size_t kl = key ? strlen(key) : 0;
    const char *hit = NULL;
    for (const char *p = key ? strchr(text, '"') : NULL; p; p = strchr(p + 1, '"')) {
        if (!strncmp(p + 1, key, kl) && p[kl + 1] == '"') {
            const char *q = p + kl + 2;
            while (*q == ' ' || *q == '\t' || *q == '\r' || *q == '\n') q++;
            if (*q == ':') {
                hit = p;
                break;
            }
        }
    }
    if (!hit) hit = strchr(text, '{');
    if (!hit) return 1;
    int line = 1;
    for (const char *p = text; p < hit; p++) line += *p == '\n';
    return line;
}

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

gs_status gis_station_parse(const char *json_text, const char *source, gis_station *st)
{
    memset(st, 0, sizeof *st);
    st->sigma_px = 1.0;
    if (!source) source = "station";
    json_error_t err;
    json_t *root = json_loads(json_text, JSON_REJECT_DUPLICATES, &err);
    if (!root) return gs_fail(GS_EFORMAT, "%s:%d:%d: %s", source, err.line, err.column, err.text);
    gs_status s = GS_OK;
    const char *key;
    json_t *v;
    unsigned char seen[N_FIELDS] = {0};
    const char *used_key[N_FIELDS] = {0};
    if (!json_is_object(root)) {
        s = gs_fail(GS_EFORMAT, "%s:1: expected a JSON object (a %s station)", source, GIS_STATION_FORMAT);
        goto done;
    }
    json_object_foreach(root, key, v) {
        int line = key_line(json_text, key);
        if (!strcmp(key, "format")) {
            if (!json_is_string(v) || strcmp(json_string_value(v), GIS_STATION_FORMAT)) {
                s = gs_fail(GS_EFORMAT, "%s:%d: format: expected \"%s\"", source, line, GIS_STATION_FORMAT);
                goto done;
            }
            continue;
        }
        int by_alias = 0;
        const field *f = find_field(key, &by_alias);
        if (!f) {
            s = gs_fail(GS_EFORMAT, "%s:%d: unknown field \"%s\" (see docs/gis.md for the station "
                        "fields)", source, line, key);
            goto done;
        }
        size_t i = (size_t)(f - fields);
        if (seen[i]) {
            s = gs_fail(GS_EFORMAT, "%s:%d: %s: given twice (as \"%s\" and \"%s\")", source, line,
                        f->name, used_key[i], key);
            goto done;
        }
        seen[i] = 1;
        used_key[i] = key;
        char *dst = (char *)st + f->offset;
        if (f->kind == F_NUM) {
            if (!json_is_number(v)) {
                s = gs_fail(GS_EFORMAT, "%s:%d: %s: expected a number", source, line, key);
                goto done;
            }
            double d = json_number_value(v);
            memcpy(dst, &d, sizeof d);
        } else if (f->kind == F_INT) {
            if (!json_is_integer(v) || json_integer_value(v) < 0 || json_integer_value(v) > 1000000) {
                s = gs_fail(GS_EFORMAT, "%s:%d: %s: expected an integer in [0, 1000000]", source, line, key);
                goto done;
            }
            int d = (int)json_integer_value(v);
            memcpy(dst, &d, sizeof d);
        } else {
            if (!json_is_string(v) || strlen(json_string_value(v)) >= f->size) {
                s = gs_fail(GS_EFORMAT, "%s:%d: %s: expected a string of at most %zu bytes", source,
                            line, key, f->size - 1);
                goto done;
            }
            strcpy(dst, json_string_value(v));
        }
    }
    for (size_t i = 0; i < N_FIELDS; i++)
        if (fields[i].required && !seen[i]) {
            s = gs_fail(GS_EFORMAT, "%s:%d: missing field \"%s\"", source, key_line(json_text, NULL),
                        fields[i].name);
            goto done;
        }
    if (!(st->sigma_px >= 0.0)) {
        s = gs_fail(GS_EFORMAT, "%s:%d: sigma_px: expected a value >= 0", source,
                    key_line(json_text, "sigma_px"));
        goto done;
    }
    s = gis_camera_check(&st->cam);
    if (s != GS_OK) {
        /* The detail reads "camera: FIELD ...": point at that field's line. */
        char msg[400];
        snprintf(msg, sizeof msg, "%s", gs_detail());
        const char *rest = strncmp(msg, "camera: ", 8) ? msg : msg + 8;
        int line = key_line(json_text, NULL);
        for (size_t i = 0; i < N_FIELDS; i++) {
            size_t n = strlen(fields[i].name);
            if (!strncmp(rest, fields[i].name, n) && (rest[n] == ' ' || rest[n] == ':')) {
                line = key_line(json_text, used_key[i] ? used_key[i] : fields[i].name);
                break;
            }
        }
        s = gs_fail(GS_EFORMAT, "%s:%d: %s", source, line, rest);
    }
done:
    json_decref(root);
    return s;
}

gs_status gis_station_read(const char *path, gis_station *st)
{
    FILE *f = fopen(path, "rb");
    if (!f) return gs_fail(GS_EIO, "%s: cannot open: %s", path, strerror(errno));
    size_t cap = 4096, n = 0;
    char *buf = malloc(cap);
    gs_status s = GS_OK;
    for (;;) {
        if (!buf) {
            s = gs_fail(GS_ENOMEM, "%s: out of memory", path);
            break;
        }
        if (n + 1 >= cap) {
            if (cap > (64u << 20)) {
                s = gs_fail(GS_EFORMAT, "%s: larger than 64 MiB: not a station file", path);
                break;
            }
            char *nb = realloc(buf, cap * 2);
            if (!nb) {
                s = gs_fail(GS_ENOMEM, "%s: out of memory", path);
                break;
            }
            buf = nb;
            cap *= 2;
        }
        size_t got = fread(buf + n, 1, cap - 1 - n, f);
        n += got;
        if (got == 0) {
            if (ferror(f)) s = gs_fail(GS_EIO, "%s: read error", path);
            break;
        }
    }
    fclose(f);
    if (s == GS_OK) {
        buf[n] = '\0';
        if (strlen(buf) != n) s = gs_fail(GS_EFORMAT, "%s: contains a NUL byte: not JSON text", path);
        else s = gis_station_parse(buf, path, st);
    }
    free(buf);
    return s;
}
