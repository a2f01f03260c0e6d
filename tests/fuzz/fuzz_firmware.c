/* fuzz_firmware.c - the ACam firmware's serial protocol parser (firmware/proto.c, compiled
 * natively): bytes through the line assembler, each line through fw_parse. */
#include "tests/fuzz/fuzz.h"
#ifdef FUZZ_REPLAY
#include "firmware/proto.h"   /* proto.c is in the test binary already (test_firmware_logic.c) */
#else
#include "firmware/proto.c"
#endif

FUZZ_TARGET(firmware)
{
    fw_linebuf lb;
    fw_linebuf_reset(&lb);
    for (size_t i = 0; i < size; i++) {
        if (fw_linebuf_feed(&lb, (char)data[i]) == 1) {
            fw_cmd cmd;
            uint8_t err = fw_parse(lb.buf, lb.len, &cmd);
            if (!fw_perr_name(err)) abort();
        }
    }
    return 0;
}
