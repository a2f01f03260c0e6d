/*
 * proto.h - the ACam controller's line protocol (prefix fw_), specified in docs/firmware.md:
 * 115200 8N1, one ASCII command per line, every firmware line ends in "*HH" (XOR of the bytes
 * before the '*', two upper-case hex digits), like NMEA 0183. A command may carry the same
 * checksum; when it does, it is verified.
 *
 * Plain C11 without libc formatting (no printf on the AVR): compiled into the firmware by
 * avr-gcc and into tests/test_firmware_logic.c by the host gcc.
 */
#ifndef GRIDSURVEY_FW_PROTO_H
#define GRIDSURVEY_FW_PROTO_H

#include <stdint.h>

#define FW_LINE_MAX 48u   /* longest command line accepted, without its newline */
#define FW_OUT_MAX 128u   /* longest line the firmware sends, with "*HH\n" */

/* Commands (docs/firmware.md). */
enum {
    FW_CMD_NONE = 0, /* empty line: ignored */
    FW_CMD_PING,
    FW_CMD_VER,
    FW_CMD_CFG,      /* CFG <K> <k> <C> <L|F> */
    FW_CMD_START,
    FW_CMD_STOP,
    FW_CMD_STATUS,
    FW_CMD_COUNT,
    FW_CMD_HALF
};

/* Parse errors, each answered "ERR <name>". */
enum {
    FW_PERR_OK = 0,
    FW_PERR_SYNTAX,   /* unknown command, wrong argument count, not a number, bad character */
    FW_PERR_CHECKSUM, /* a "*HH" suffix that does not match */
    FW_PERR_RANGE,    /* a number outside its range (K, k, C) or a mode other than L/F */
    FW_PERR_LONG      /* a line longer than FW_LINE_MAX */
};

typedef struct {
    uint8_t kind;     /* FW_CMD_* */
    uint8_t K, k;     /* CFG */
    uint8_t mode;     /* CFG: 0 locked (L), 1 free running (F) */
    uint32_t C;       /* CFG */
} fw_cmd;

/* Line assembly from received bytes: CR is dropped, LF ends a line. */
typedef struct {
    char buf[FW_LINE_MAX + 1u];
    uint8_t len;
    uint8_t overlong;
} fw_linebuf;

void fw_linebuf_reset(fw_linebuf *lb);
/* Returns 0 (line not complete), 1 (buf holds a NUL-terminated line of len bytes) or 2 (an
 * overlong line ended: answer FW_PERR_LONG). After 1 or 2 the next byte starts a new line. */
uint8_t fw_linebuf_feed(fw_linebuf *lb, char c);

/* XOR of s[0..len). */
uint8_t fw_checksum(const char *s, uint8_t len);
/* Parses one line (without newline) into *cmd; returns FW_PERR_*. Range checks are those of
 * schedule.h (2 <= K <= 26, k < K, 1 <= C <= 1000000); the per-grid K limit is checked at START. */
uint8_t fw_parse(const char *line, uint8_t len, fw_cmd *cmd);
/* Name of a FW_PERR_* code ("SYNTAX", ...). */
const char *fw_perr_name(uint8_t err);

/* An outgoing line under construction; fw_out_end appends "*HH\n". Text beyond the buffer is
 * dropped (FW_OUT_MAX is sized for the longest reply). */
typedef struct {
    char buf[FW_OUT_MAX];
    uint8_t len;
} fw_out;

void fw_out_begin(fw_out *o);
void fw_out_str(fw_out *o, const char *s);
void fw_out_char(fw_out *o, char c);
void fw_out_u32(fw_out *o, uint32_t v); /* decimal, by subtracting powers of ten (no division) */
void fw_out_end(fw_out *o);

#endif
