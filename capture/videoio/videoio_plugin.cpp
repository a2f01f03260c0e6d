/* videoio_plugin.cpp - the only C++ of capture/: a camera through OpenCV 4 VideoCapture, built
 * as the plugin BUILD/gridsurvey-videoio.so (linked with opencv_videoio) that capture/videoio.c
 * loads on the first camera opened. Plain C functions (cap_vio_plugin_*, capture/internal.h);
 * every exception is caught here and returned as a gs_status (gs_fail is the program's). */
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "recognize/base/cv_nomem.hpp"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <new>
#include <string>

extern "C" {
#include "capture/internal.h"
}

struct cap_vio {
    cv::VideoCapture cap;
    std::string backend;   /* getBackendName(), kept for cap_vio_plugin_backend */
};

static gs_status fail_exception(const char *what, const std::exception &e)
{
    if (gs_cv_out_of_memory(e)) return gs_fail(GS_ENOMEM, "OpenCV %s: out of memory", what);
    return gs_fail(GS_EIO, "OpenCV %s: %s", what, e.what());
}

extern "C" gs_status cap_vio_plugin_open(const char *source, int images, cap_vio **out)
{
    *out = nullptr;
    if (!source || !*source) return gs_fail(GS_EINVAL, "camera: no source");
    cap_vio *v = nullptr;
    try {
        v = new cap_vio;
        bool digits = std::strspn(source, "0123456789") == std::strlen(source);
        bool ok;
        if (images) ok = v->cap.open(source, cv::CAP_IMAGES);
        else if (digits) ok = v->cap.open(std::atoi(source));
        else ok = v->cap.open(source);
        if (!ok || !v->cap.isOpened()) {
            delete v;
            return gs_fail(GS_EIO, "camera %s: OpenCV VideoCapture cannot open it%s", source,
                           images ? " as an image sequence (CAP_IMAGES)" : "");
        }
        try {
            v->backend = v->cap.getBackendName();
        } catch (const cv::Exception &) {   /* (a capture without a backend name) */
        }
        *out = v;
        return GS_OK;
    } catch (const std::exception &e) {
        delete v;
        return fail_exception("VideoCapture open", e);
    } catch (...) {
        delete v;
        return gs_fail(GS_EIO, "camera %s: unknown C++ exception", source);
    }
}

extern "C" void cap_vio_plugin_close(cap_vio *v)
{
    try {
        delete v;
    } catch (...) {
    }
}

extern "C" gs_status cap_vio_plugin_set_exposure(cap_vio *v, double exposure, double *actual)
{
    try {
        bool ok = v->cap.set(cv::CAP_PROP_EXPOSURE, exposure);
        *actual = ok ? v->cap.get(cv::CAP_PROP_EXPOSURE) : NAN;
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("set exposure", e);
    } catch (...) {
        return gs_fail(GS_EIO, "camera: unknown C++ exception");
    }
}

extern "C" const char *cap_vio_plugin_backend(cap_vio *v)
{
    return v->backend.c_str();
}

extern "C" gs_status cap_vio_plugin_read(cap_vio *v, int width, int height, int bands,
                                  unsigned short *out)
{
    try {
        cv::Mat m;
        if (!v->cap.read(m) || m.empty()) return gs_fail(GS_EIO, "camera: no frame");
        if (m.cols != width || m.rows != height)
            return gs_fail(GS_EFORMAT, "camera: a %dx%d frame: expected %dx%d", m.cols, m.rows,
                           width, height);
        cv::Mat c;
        if (m.channels() == 1 && bands == 1) c = m;
        else if (m.channels() == 3 && bands == 3) cv::cvtColor(m, c, cv::COLOR_BGR2RGB);
        else if (m.channels() == 4 && bands == 3) cv::cvtColor(m, c, cv::COLOR_BGRA2RGB);
        else if (m.channels() >= 3 && bands == 1)
            cv::cvtColor(m, c, m.channels() == 3 ? cv::COLOR_BGR2GRAY : cv::COLOR_BGRA2GRAY);
        else
            return gs_fail(GS_EFORMAT, "camera: a %d-channel frame: expected %d", m.channels(), bands);
        cv::Mat d;
        if (c.depth() == CV_16U) d = c;
        else if (c.depth() == CV_8U) c.convertTo(d, CV_16U, 257.0);
        else return gs_fail(GS_EFORMAT, "camera: frame depth %d: expected 8 or 16 bits", c.depth());
        for (int y = 0; y < height; y++)
            std::memcpy(out + (size_t)y * (size_t)width * (size_t)bands, d.ptr<unsigned short>(y),
                        sizeof(unsigned short) * (size_t)width * (size_t)bands);
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("read", e);
    } catch (...) {
        return gs_fail(GS_EIO, "camera: unknown C++ exception");
    }
}
