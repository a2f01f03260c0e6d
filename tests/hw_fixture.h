/* hw_fixture.h - the hardware backend's fakes shared by tests/test_capture_hw.c and
 * tests/test_firmware_link.c (tests/hw_fixture.c), prefix hw_fx_: an image-sequence camera
 * with a known pattern, and a hardware configuration wired to it and to the fake libgpiod
 * (tests/fake_gpiod.h). */
#ifndef GRIDSURVEY_TESTS_HW_FIXTURE_H
#define GRIDSURVEY_TESTS_HW_FIXTURE_H

#include "capture/capture.h"

#include <stddef.h>

/* The camera's value of frame k at pixel (x, y), band b. */
typedef unsigned short (*hw_fx_pixel)(int k, int x, int y, int b);

/* The fake camera: K 16-bit RGB frames TMPDIR/cam/cam_000.png, cam_001.png, ... of W x H
 * pixels. Returns their printf pattern (a static buffer) for cap_hw_config.camera. */
const char *hw_fx_camera(int K, int W, int H, hw_fx_pixel px);
/* Samples of cap (K frames of H x W x 3) that differ from the camera's. */
size_t hw_fx_camera_diff(const gs_capture *cap, int K, int W, int H, hw_fx_pixel px);
/* cap_hw_config_default, then: the camera (images named by the printf pattern), the controller
 * on serial_fd, GPIO chip "gpiochip0" with the zero-crossing input on line 17, the shutter on
 * 22 and the trigger on 27, W x H x 3 frames, window count K and C cycles an exposure. */
void hw_fx_config(cap_hw_config *hw, const char *camera_pattern, int serial_fd, int K, int C,
                  int W, int H);

#endif
