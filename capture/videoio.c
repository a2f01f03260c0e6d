/* videoio.c - the camera functions of capture/internal.h: each forwards to the videoio plugin
 * (capture/videoio/videoio_plugin.cpp), loaded by the first cap_vio_open from beside the
 * running binary or from the installed layout (PREFIX/bin/../lib/gridsurvey/). */
#include "capture/internal.h"

#include <dlfcn.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

static const char PLUGIN[] = "gridsurvey-videoio.so";

static cap_vio_api api;

gs_status cap_vio_plugin_load(const char *bin_dir, cap_vio_api *out)
{
    memset(out, 0, sizeof *out);
    char paths[2][PATH_MAX + 64], why[2][PATH_MAX + 256];
    snprintf(paths[0], sizeof paths[0], "%s/%s", bin_dir, PLUGIN);
    snprintf(paths[1], sizeof paths[1], "%s/../lib/gridsurvey/%s", bin_dir, PLUGIN);
    void *h = NULL;
    for (int i = 0; i < 2 && !h; i++) {
        h = dlopen(paths[i], RTLD_NOW | RTLD_LOCAL);
        const char *e = h ? "" : dlerror();
        snprintf(why[i], sizeof why[i], "%s", e ? e : "");
    }
    if (!h)
        return gs_fail(GS_EIO, "camera: cannot load the OpenCV camera plugin (%s; %s): make builds "
                       "it beside the binary, make install puts it in PREFIX/lib/gridsurvey",
                       why[0], why[1]);
    cap_vio_api a = {.handle = h};
    *(void **)&a.open = dlsym(h, "cap_vio_plugin_open");
    *(void **)&a.close = dlsym(h, "cap_vio_plugin_close");
    *(void **)&a.set_exposure = dlsym(h, "cap_vio_plugin_set_exposure");
    *(void **)&a.read = dlsym(h, "cap_vio_plugin_read");
    *(void **)&a.backend = dlsym(h, "cap_vio_plugin_backend");
    if (!a.open || !a.close || !a.set_exposure || !a.read || !a.backend) {
        dlclose(h);
        return gs_fail(GS_EIO, "camera: the OpenCV camera plugin lacks its entry points "
                       "(cap_vio_plugin_*): rebuild it with the binary");
    }
    *out = a;
    return GS_OK;
}

/* Once per process, from the running binary's directory. */
static gs_status load(void)
{
    if (api.open) return GS_OK;
    char exe[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n <= 0) return gs_fail(GS_EIO, "camera: cannot find the running binary (/proc/self/exe) "
                               "to load %s beside it", PLUGIN);
    exe[n] = '\0';
    char *slash = strrchr(exe, '/');
    if (slash) *slash = '\0';
    return cap_vio_plugin_load(exe, &api);
}

gs_status cap_vio_open(const char *source, int images, cap_vio **out)
{
    *out = NULL;
    gs_status s = load();
    return s != GS_OK ? s : api.open(source, images, out);
}

void cap_vio_close(cap_vio *v)
{
    if (v && api.close) api.close(v);
}

double cap_vio_units_per_s(const char *backend)
{
    return backend && !strcmp(backend, "V4L2") ? 1e4 : NAN;
}

gs_status cap_vio_set_exposure(cap_vio *v, double exposure_s, double *actual_s)
{
    double per = cap_vio_units_per_s(api.backend(v)), raw = NAN;
    gs_status s = api.set_exposure(v, isfinite(per) ? exposure_s * per : exposure_s, &raw);
    *actual_s = isfinite(per) ? raw / per : NAN;
    return s;
}

gs_status cap_vio_read(cap_vio *v, int width, int height, int bands, unsigned short *out)
{
    return api.read(v, width, height, bands, out);
}
