/* opencv_shim.cpp - the one C++ file of recognize/: OpenCV 4.6 (core, imgproc, imgcodecs)
 * behind plain C functions (shared/TOOLCHAIN.md: OpenCV's C API is gone).
 *
 * Every function catches every exception at this boundary and returns a gs_status with a
 * gs_fail detail; nothing C++ leaks into the C side. The prototypes are those of the "OpenCV
 * shim" section of recognize/internal.h (repeated here because internal.h pulls <complex.h>,
 * which is not C++: keep the two in step).
 *
 * Notes on OpenCV used here:
 * - PNGs are decoded with IMREAD_ANYDEPTH | IMREAD_UNCHANGED so 16 bits and the channel count
 *   survive; OpenCV orders colour channels B, G, R, the capture format R, G, B.
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
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

extern "C" {
gs_status rec_cv_png_decode(const unsigned char *buf, size_t size, const char *name, int width,
                            int height, int channels, int depth16, void *out);
gs_status rec_cv_png_encode(const void *pixels, int width, int height, int channels, int depth16,
                            unsigned char **png, size_t *size);
gs_status rec_cv_components(const unsigned char *mask, int width, int height, int *labels,
                            int *count, int **stats);
gs_status rec_cv_dilate_f32(const float *src, float *dst, int width, int height, int radius);
gs_status rec_cv_dilate_u8(unsigned char *mask, int width, int height, int radius);
}

namespace {

/* OpenCV type of an interleaved image with `channels` channels of 8 or 16 bits. */
int cv_type(int channels, int depth16)
{
    return CV_MAKETYPE(depth16 ? CV_16U : CV_8U, channels);
}

gs_status fail_exception(const char *what, const std::exception &e)
{
    if (dynamic_cast<const std::bad_alloc *>(&e)) return gs_fail(GS_ENOMEM, "%s: out of memory", what);
    return gs_fail(GS_EFORMAT, "%s: OpenCV: %s", what, e.what());
}

} // namespace

extern "C" gs_status rec_cv_png_decode(const unsigned char *buf, size_t size, const char *name,
                                       int width, int height, int channels, int depth16, void *out)
{
    if (!buf || !out || size == 0 || size > (size_t)INT32_MAX || width < 1 || height < 1 ||
        (channels != 1 && channels != 3))
        return gs_fail(GS_EINVAL, "%s: rec_cv_png_decode: bad arguments", name);
    try {
        const cv::Mat data(1, (int)size, CV_8U, const_cast<unsigned char *>(buf));
        cv::Mat img = cv::imdecode(data, cv::IMREAD_ANYDEPTH | cv::IMREAD_UNCHANGED);
        if (img.empty())
            return gs_fail(GS_EFORMAT, "%s: the PNG data could not be decoded (corrupt file)", name);
        if (img.cols != width || img.rows != height)
            return gs_fail(GS_EFORMAT, "%s: image is %dx%d pixels: expected %dx%d", name, img.cols,
                           img.rows, width, height);
        if (img.depth() != (depth16 ? CV_16U : CV_8U))
            return gs_fail(GS_EFORMAT, "%s: decoded sample depth is not %d bits", name,
                           depth16 ? 16 : 8);
        if (img.channels() != channels)
            return gs_fail(GS_EFORMAT, "%s: decoded image has %d channels: expected %d", name,
                           img.channels(), channels);
        cv::Mat dst(height, width, cv_type(channels, depth16), out);
        if (channels == 3) cv::cvtColor(img, dst, cv::COLOR_BGR2RGB);
        else img.copyTo(dst);
        if (dst.data != (uchar *)out)
            return gs_fail(GS_EFORMAT, "%s: internal: OpenCV reallocated the output", name);
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception(name, e);
    } catch (...) {
        return gs_fail(GS_EFORMAT, "%s: unknown C++ exception while decoding", name);
    }
}

extern "C" gs_status rec_cv_png_encode(const void *pixels, int width, int height, int channels,
                                       int depth16, unsigned char **png, size_t *size)
{
    if (!pixels || !png || !size || width < 1 || height < 1 || (channels != 1 && channels != 3))
        return gs_fail(GS_EINVAL, "rec_cv_png_encode: bad arguments");
    *png = nullptr;
    *size = 0;
    try {
        const cv::Mat src(height, width, cv_type(channels, depth16), const_cast<void *>(pixels));
        cv::Mat bgr;
        if (channels == 3) cv::cvtColor(src, bgr, cv::COLOR_RGB2BGR);
        else bgr = src;
        std::vector<uchar> enc;
        /* zlib level 1: fast, and PNG is lossless at any level */
        const std::vector<int> params = {cv::IMWRITE_PNG_COMPRESSION, 1};
        if (!cv::imencode(".png", bgr, enc, params) || enc.empty())
            return gs_fail(GS_EIO, "OpenCV could not encode a %dx%d PNG", width, height);
        unsigned char *p = static_cast<unsigned char *>(std::malloc(enc.size()));
        if (!p) return gs_fail(GS_ENOMEM, "cannot hold a %zu-byte PNG", enc.size());
        std::memcpy(p, enc.data(), enc.size());
        *png = p;
        *size = enc.size();
        return GS_OK;
    } catch (const std::exception &e) {
        return fail_exception("PNG encoding", e);
    } catch (...) {
        return gs_fail(GS_EIO, "unknown C++ exception while encoding a PNG");
    }
}

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
