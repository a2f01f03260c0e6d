/* kit_mem.c - the format kit's memory budget: the most a command may allocate for one input's
 * pixels and working images, checked before the allocation so that a small file that declares a
 * huge image fails with one line instead of exhausting the machine. Default: half the physical
 * RAM, and no more than RLIMIT_AS; `--max-memory SIZE` or GS_MAX_MEMORY (survey/cli.c) sets it. */
#include "recognize/base/base.h"

#include <ctype.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

static size_t budget_bytes;   /* 0: the default */

gs_status gs_mem_parse(const char *what, const char *text, size_t *bytes)
{
    double v = NAN;
    const char *end = text ? gs_number_prefix(text, &v) : NULL;
    double unit = 1.0;
    if (end && *end) {
        static const char units[] = "KMGT";
        /* (a letter only: ' ' & ~0x20 is the terminator, which strchr finds) */
        const char *u = isalpha((unsigned char)end[0]) ? strchr(units, end[0] & ~0x20) : NULL;
        if (u && (!end[1] || ((end[1] | 0x20) == 'i' && (end[2] | 0x20) == 'b' && !end[3]) ||
                  ((end[1] | 0x20) == 'b' && !end[2])))
            unit = ldexp(1.0, 10 * (int)(u - units + 1));
        else
            v = NAN;
    }
    v *= unit;
    if (!(v >= 1048576.0 && v <= 0x1p62))
        return gs_fail(GS_EINVAL, "%s '%s': expected a size of at least 1M, in bytes or with a "
                       "suffix K, M, G or T (powers of 1024), e.g. 4G", what, text ? text : "");
    *bytes = (size_t)v;
    return GS_OK;
}

void gs_mem_budget_set(size_t bytes)
{
    budget_bytes = bytes;
}

size_t gs_mem_budget(void)
{
    if (budget_bytes) return budget_bytes;
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
    double b = pages > 0 && page > 0 ? 0.5 * (double)pages * (double)page : 0x1p32;
    struct rlimit rl;
    if (getrlimit(RLIMIT_AS, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY && (double)rl.rlim_cur < b)
        b = 0.5 * (double)rl.rlim_cur;   /* the rest for libraries, stacks and fragmentation */
    return (size_t)b;
}

gs_status gs_mem_check(double bytes, const char *what)
{
    double budget = (double)gs_mem_budget();
    if (bytes <= budget) return GS_OK;
    return gs_fail(GS_ELIMIT, "%s need %.1f MiB: more than the memory budget of %.1f MiB (give "
                   "--max-memory SIZE to change it; default half the RAM)", what,
                   bytes / 1048576.0, budget / 1048576.0);
}
