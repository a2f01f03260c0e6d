/* hw_fixture.c - the hardware backend's fakes; the contract is in tests/hw_fixture.h. */
#include "tests/hw_fixture.h"

#include "tests/test.h"

#include <stdio.h>
#include <string.h>

static size_t sample(int k, int x, int y, int b, int W, int H)
{
    return (((size_t)k * (size_t)H + (size_t)y) * (size_t)W + (size_t)x) * 3 + (size_t)b;
}

const char *hw_fx_camera(int K, int W, int H, hw_fx_pixel px)
{
    static char dir[1024], pattern[1100];
    snprintf(dir, sizeof dir, "%s/cam", test_tmpdir());
    snprintf(pattern, sizeof pattern, "%s/cam_%%03d.png", dir);
    gs_capture c;
    memset(&c, 0, sizeof c);
    c.K = K;
    c.bands = 3;
    c.width = W;
    c.height = H;
    CHECK_OK(gs_capture_alloc(&c));
    if (!c.raw) return pattern;
    for (int k = 0; k < K; k++) {
        snprintf(c.frames[k].file, GS_PATH_MAX, "cam_%03d.png", k);
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                for (int b = 0; b < 3; b++) c.raw[sample(k, x, y, b, W, H)] = px(k, x, y, b);
    }
    for (int k = 0; k < K; k++) CHECK_OK(gs_capture_write_frame(dir, &c, k));
    gs_capture_release(&c);
    return pattern;
}

size_t hw_fx_camera_diff(const gs_capture *cap, int K, int W, int H, hw_fx_pixel px)
{
    size_t bad = 0;
    for (int k = 0; k < K; k++)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                for (int b = 0; b < 3; b++)
                    bad += cap->raw[sample(k, x, y, b, W, H)] != px(k, x, y, b);
    return bad;
}

void hw_fx_config(cap_hw_config *hw, const char *camera_pattern, int serial_fd, int K, int C,
                  int W, int H)
{
    cap_hw_config_default(hw);
    hw->camera = camera_pattern;
    hw->camera_images = 1;
    hw->serial_fd = serial_fd;
    hw->gpio_chip = "gpiochip0";
    hw->zc_line = 17;
    hw->shutter_line = 22;
    hw->trigger_line = 27;
    hw->width = W;
    hw->height = H;
    hw->bands = 3;
    hw->K = K;
    hw->cycles = C;
}
