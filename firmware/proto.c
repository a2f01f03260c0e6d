/* proto.c - line assembly, parsing and reply formatting of the ACam serial protocol (proto.h,
 * docs/firmware.md). No libc formatting: the AVR has no room for printf, and a 32-bit
 * division costs ~40 us there, so decimals are printed by subtraction. */
#include "firmware/proto.h"

#include "firmware/schedule.h"

void fw_linebuf_reset(fw_linebuf *lb)
{
    lb->len = 0;
    lb->overlong = 0;
    lb->buf[0] = '\0';
}

uint8_t fw_linebuf_feed(fw_linebuf *lb, char c)
{
    if (c == '\r') return 0;
    if (c == '\n') {
        uint8_t r = lb->overlong ? 2 : 1;
        lb->buf[lb->len] = '\0';
        if (r == 2) lb->len = 0;
        lb->overlong = 0;
        return r;
    }
    if (lb->overlong) return 0;
    if (lb->len >= FW_LINE_MAX) {
        lb->overlong = 1;
        lb->len = 0;
        return 0;
    }
    lb->buf[lb->len++] = c;
    return 0;
}

uint8_t fw_checksum(const char *s, uint8_t len)
{
    uint8_t x = 0;
    for (uint8_t i = 0; i < len; i++) x ^= (uint8_t)s[i];
    return x;
}

static int hex_value(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

/* Does token [s, s+n) equal the NUL-terminated word w? */
static uint8_t token_is(const char *s, uint8_t n, const char *w)
{
    uint8_t i = 0;
    for (; i < n && w[i]; i++)
        if (s[i] != w[i]) return 0;
    return i == n && w[i] == '\0';
}

/* Unsigned decimal token, at most 10 digits and no more than max. 0 on success, else
 * FW_PERR_SYNTAX (not digits) or FW_PERR_RANGE (too large). */
static uint8_t parse_u32(const char *s, uint8_t n, uint32_t max, uint32_t *v)
{
    if (n == 0 || n > 10) return n ? FW_PERR_RANGE : FW_PERR_SYNTAX;
    uint32_t x = 0;
    uint8_t big = 0;
    for (uint8_t i = 0; i < n; i++) {
        if (s[i] < '0' || s[i] > '9') return FW_PERR_SYNTAX;
        uint8_t digit = (uint8_t)(s[i] - '0');
        if (x > (UINT32_MAX - digit) / 10u) big = 1;
        else x = x * 10u + digit;
    }
    if (big || x > max) return FW_PERR_RANGE;
    *v = x;
    return FW_PERR_OK;
}

uint8_t fw_parse(const char *line, uint8_t len, fw_cmd *cmd)
{
    cmd->kind = FW_CMD_NONE;
    /* optional checksum suffix "*HH" */
    for (uint8_t i = 0; i < len; i++) {
        if (line[i] != '*') continue;
        if (len - i != 3) return FW_PERR_SYNTAX;
        int hi = hex_value(line[i + 1]), lo = hex_value(line[i + 2]);
        if (hi < 0 || lo < 0) return FW_PERR_SYNTAX;
        if (fw_checksum(line, i) != (uint8_t)(hi * 16 + lo)) return FW_PERR_CHECKSUM;
        len = i;
        break;
    }
    for (uint8_t i = 0; i < len; i++)
        if (line[i] < ' ' || line[i] > '~') return FW_PERR_SYNTAX;
    if (len == 0) return FW_PERR_OK;

    /* split on single spaces: at most 5 tokens */
    const char *tok[5];
    uint8_t tlen[5], ntok = 0, i = 0;
    while (i < len) {
        if (line[i] == ' ') return FW_PERR_SYNTAX; /* leading, trailing or double space */
        if (ntok == 5) return FW_PERR_SYNTAX;
        tok[ntok] = line + i;
        uint8_t start = i;
        while (i < len && line[i] != ' ') i++;
        tlen[ntok++] = (uint8_t)(i - start);
        if (i < len) {
            i++;
            if (i == len) return FW_PERR_SYNTAX;
        }
    }

    static const struct {
        const char *name;
        uint8_t kind, args;
    } table[] = {{"PING", FW_CMD_PING, 0},     {"VER", FW_CMD_VER, 0},
                 {"CFG", FW_CMD_CFG, 4},       {"START", FW_CMD_START, 0},
                 {"STOP", FW_CMD_STOP, 0},     {"STATUS", FW_CMD_STATUS, 0},
                 {"COUNT", FW_CMD_COUNT, 0},   {"HALF", FW_CMD_HALF, 0}};
    uint8_t kind = FW_CMD_NONE, args = 0;
    for (uint8_t t = 0; t < sizeof table / sizeof table[0]; t++)
        if (token_is(tok[0], tlen[0], table[t].name)) {
            kind = table[t].kind;
            args = table[t].args;
        }
    if (kind == FW_CMD_NONE || ntok != args + 1u) return FW_PERR_SYNTAX;
    if (kind == FW_CMD_CFG) {
        uint32_t K, k, C;
        uint8_t e;
        if ((e = parse_u32(tok[1], tlen[1], 255, &K)) != FW_PERR_OK) return e;
        if ((e = parse_u32(tok[2], tlen[2], 255, &k)) != FW_PERR_OK) return e;
        if ((e = parse_u32(tok[3], tlen[3], FW_C_MAX, &C)) != FW_PERR_OK) return e;
        if (tlen[4] != 1) return FW_PERR_SYNTAX;
        if (tok[4][0] != 'L' && tok[4][0] != 'F') return FW_PERR_RANGE;
        if (K < FW_K_MIN || K > FW_K_MAX_50 || k >= K || C < 1) return FW_PERR_RANGE;
        cmd->K = (uint8_t)K;
        cmd->k = (uint8_t)k;
        cmd->C = C;
        cmd->mode = tok[4][0] == 'L' ? FW_MODE_LOCKED : FW_MODE_FREE;
    }
    cmd->kind = kind;
    return FW_PERR_OK;
}

const char *fw_perr_name(uint8_t err)
{
    switch (err) {
    case FW_PERR_OK: return "OK";
    case FW_PERR_SYNTAX: return "SYNTAX";
    case FW_PERR_CHECKSUM: return "CHECKSUM";
    case FW_PERR_RANGE: return "RANGE";
    case FW_PERR_LONG: return "LONG";
    default: return "?";
    }
}

void fw_out_begin(fw_out *o)
{
    o->len = 0;
}

void fw_out_char(fw_out *o, char c)
{
    if (o->len < FW_OUT_MAX - 4u) o->buf[o->len++] = c; /* room kept for "*HH\n" */
}

void fw_out_str(fw_out *o, const char *s)
{
    while (*s) fw_out_char(o, *s++);
}

void fw_out_u32(fw_out *o, uint32_t v)
{
    static const uint32_t pow10[] = {1000000000ul, 100000000ul, 10000000ul, 1000000ul,
                                     100000ul,     10000ul,     1000ul,     100ul,
                                     10ul,         1ul};
    uint8_t started = 0;
    for (uint8_t i = 0; i < 10; i++) {
        char d = '0';
        while (v >= pow10[i]) {
            v -= pow10[i];
            d++;
        }
        if (d != '0' || started || i == 9) {
            fw_out_char(o, d);
            started = 1;
        }
    }
}

void fw_out_end(fw_out *o)
{
    static const char hex[] = "0123456789ABCDEF";
    uint8_t x = fw_checksum(o->buf, o->len);
    o->buf[o->len++] = '*';
    o->buf[o->len++] = hex[x >> 4];
    o->buf[o->len++] = hex[x & 15u];
    o->buf[o->len++] = '\n';
}
