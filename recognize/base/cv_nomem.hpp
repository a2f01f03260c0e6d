/* cv_nomem.hpp - for the C++ shims over OpenCV (recognize/opencv_shim.cpp,
 * capture/videoio/videoio_plugin.cpp): whether an exception caught at the C boundary is an
 * allocation failure, so that it is returned as GS_ENOMEM. */
#ifndef GS_CV_NOMEM_HPP
#define GS_CV_NOMEM_HPP

#include <exception>
#include <new>

#include <opencv2/core.hpp>

/* operator new's std::bad_alloc, or OpenCV's own allocator's cv::Exception StsNoMem */
static inline bool gs_cv_out_of_memory(const std::exception &e)
{
    if (dynamic_cast<const std::bad_alloc *>(&e)) return true;
    const auto *cve = dynamic_cast<const cv::Exception *>(&e);
    return cve && cve->code == cv::Error::StsNoMem;
}

#endif
