/* opencv_shim.cpp - the one C++ file of recognize/: OpenCV 4.6 (core, imgproc)
 * behind plain C functions (shared/TOOLCHAIN.md: OpenCV's C API is gone).
 *
 * Every function catches every exception at this boundary and returns a gs_status with a
 * gs_fail detail; nothing C++ leaks into the C side. The prototypes are those of the "OpenCV
 * shim" section of recognize/internal.h (repeated here because internal.h pulls <complex.h>,
 * which is not C++: keep the two in step).
 *
 * Notes on OpenCV used here:
 * - connectedComponentsWithStats needs 8-bit input (TOOLCHAIN.md) and gives CV_32S labels.
 * - A cv::Mat header over a caller's buffer is an output only if OpenCV does not reallocate
 *   it: every such call checks the data pointer afterwards. */
#include <cstddef>
#include <cstdio>
/* recognize.h is C without extern "C" guards: give its declarations C linkage here */
extern "C" {
#include "recognize/recognize.h"
}

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <new>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "recognize/base/cv_nomem.hpp"

extern "C" {
gs_status rec_cv_components(const unsigned char *mask, int width, int height, int *labels,
                            int *count, int **stats);
gs_status rec_cv_dilate_f32(const float *src, float *dst, int width, int height, int radius);
gs_status rec_cv_dilate_u8(unsigned char *mask, int width, int height, int radius);
}

namespace {

gs_status fail_exception(const char *what, const std::exception &e)
{
    if (gs_cv_out_of_memory(e)) return gs_fail(GS_ENOMEM, "%s: out of memory", what);
    return gs_fail(GS_EFORMAT, "%s: OpenCV: %s", what, e.what());
}

} // namespace

extern "C" gs_status rec_cv_components(const unsigned char *mask, int width, int height,
                                       int *labels, int *count, int **stats)
{
    if (!mask || !labels || !count || !stats || width < 1 || height < 1)
        return gs_fail(GS_EINVAL, "rec_cv_components: bad arguments");
    *count = 0;
    *stats = nullptr;
    try {
        const cv::Mat m(height, width, CV_8U, const_cast<unsigned char *>(mask));
        cv::Mat lab(height, width, CV_32S, labels), st, centroids;
        int n = cv::connectedComponentsWithStats(m, lab, st, centroids, 8, CV_32S);
        if (lab.data != (uchar *)labels)
            return gs_fail(GS_EFORMAT, "connected components: internal: labels reallocated");
        int *s = static_cast<int *>(std::malloc(sizeof(int) * 5 * (size_t)(n > 0 ? n : 1)));
        if (!s) return gs_fail(GS_ENOMEM, "connected components: cannot hold %d labels", n);
        for (int i = 0; i < n; i++) {
            s[5 * i + 0] = st.at<int>(i, cv::CC_STAT_AREA);
            s[5 * i + 1] = st.at<int>(i, cv::CC_STAT_LEFT);
            s[5 * i + 2] = st.at<int>(i, cv::CC_STAT_TOP);
            s[5 * i + 3] = st.at<int>(i, cv::CC_STAT_WIDTH);
            s[5 * i + 4] = st.at<int>(i, cv::CC_STAT_HEIGHT);
        }
        *count = n > 0 ? n - 1 : 0;
        *stats = s;
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("connected components", e);
    } catch (...) {
        return gs_fail(GS_EFORMAT, "connected components: unknown C++ exception");
    }
}

extern "C" gs_status rec_cv_dilate_f32(const float *src, float *dst, int width, int height,
                                       int radius)
{
    if (!src || !dst || src == dst || width < 1 || height < 1 || radius < 0)
        return gs_fail(GS_EINVAL, "rec_cv_dilate_f32: bad arguments");
    try {
        const cv::Mat s(height, width, CV_32F, const_cast<float *>(src));
        cv::Mat d(height, width, CV_32F, dst);
        const cv::Mat k = cv::getStructuringElement(cv::MORPH_RECT,
                                                    cv::Size(2 * radius + 1, 2 * radius + 1));
        /* BORDER_CONSTANT with the default border value: outside pixels never win a maximum */
        cv::dilate(s, d, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT,
                   cv::morphologyDefaultBorderValue());
        if (d.data != (uchar *)dst) return gs_fail(GS_EFORMAT, "dilate: internal: reallocated");
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("dilate", e);
    } catch (...) {
        return gs_fail(GS_EFORMAT, "dilate: unknown C++ exception");
    }
}

extern "C" gs_status rec_cv_dilate_u8(unsigned char *mask, int width, int height, int radius)
{
    if (!mask || width < 1 || height < 1 || radius < 0)
        return gs_fail(GS_EINVAL, "rec_cv_dilate_u8: bad arguments");
    if (radius == 0) return GS_OK;
    try {
        cv::Mat m(height, width, CV_8U, mask);
        const cv::Mat k = cv::getStructuringElement(cv::MORPH_RECT,
                                                    cv::Size(2 * radius + 1, 2 * radius + 1));
        cv::Mat out;
        cv::dilate(m, out, k);
        out.copyTo(m);
        if (m.data != mask) return gs_fail(GS_EFORMAT, "dilate: internal: reallocated");
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("dilate", e);
    } catch (...) {
        return gs_fail(GS_EFORMAT, "dilate: unknown C++ exception");
    }
}

extern "C" const char *rec_opencv_version(void)
{
    return CV_VERSION;
}
