/* cmd_compare.c - `gridsurvey compare`: what changed between two surveys of the same area
 * (srv_compare, survey/sites.c; docs/survey-db.md "Changes"). */
#include "survey/internal.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char compare_usage[] =
    "usage: gridsurvey compare --db DB --survey A --survey B [--min-p P] [--format table|csv]\n"
    "\n"
    "The light sites (physical lights) whose grid phase or bulb changed from survey A to survey\n"
    "B, with the evidence for each (both surveys' answers, their confidences and detections,\n"
    "and the probability that they differ), and the sites seen in only one of them (appeared\n"
    "in B, vanished from A: a light off, removed, or outside the other survey's view).\n"
    "\n"
    "  --db DB          the survey database (read-only)\n"
    "  --survey NAME    survey A, then survey B (twice)\n"
    "  --min-p P        report a phase or bulb change when the probability that the answers\n"
    "                   differ is at least P, in [0, 1] (default 0.9)\n"
    "  --format F       table (Markdown, default) or csv\n"
    "  --help           this text\n"
    "\n"
    "Exit status: 0 done, 1 failure (one line on stderr), 2 usage error.\n";

static const char *kind_text(unsigned k, char *buf, size_t size)
{
    buf[0] = '\0';
    static const char *const names[4] = {"phase", "bulb", "appeared", "vanished"};
    for (int i = 0; i < 4; i++)
        if (k & (1u << i)) {
            size_t used = strlen(buf);
            snprintf(buf + used, size - used, "%s%s", used ? "+" : "", names[i]);
        }
    return buf;
}

/* "bulb @ phase (p_bulb, p_phase; n det)" of one side, "-" when unseen. */
static void side_text(const srv_site_value *v, char *buf, size_t size)
{
    if (!v->detections) {
        snprintf(buf, size, "-");
        return;
    }
    char ph[32] = "unknown";
    if (!isnan(v->phase_deg)) snprintf(ph, sizeof ph, "%.0f deg", v->phase_deg);
    snprintf(buf, size, "%s %s (bulb %.3f, phase %.3f; %ld det.)", v->bulb_id[0] ? v->bulb_id : "none", ph,
             v->bulb_confidence, v->phase_confidence, v->detections);
}

static void fmt_p(char *buf, size_t size, double p)
{
    if (isnan(p)) snprintf(buf, size, "-");
    else snprintf(buf, size, "%.4f", p);
}

int srv_cmd_compare(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},     {"survey", required_argument, 0, 'S'},
        {"min-p", required_argument, 0, 'p'},  {"format", required_argument, 0, 'f'},
        {"help", no_argument, 0, 'h'},         {0, 0, 0, 0},
    };
    const char *path = NULL, *sv[2] = {NULL, NULL};
    int nsv = 0, csv = 0;
    double min_p = 0.9;
    optind = 1;
    int c;
    char *end;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 'S':
            if (nsv == 2) {
                fprintf(stderr, "gridsurvey compare: --survey given more than twice\n");
                return 2;
            }
            sv[nsv++] = optarg;
            break;
        case 'p':
            min_p = strtod(optarg, &end);
            if (!*optarg || *end || !(min_p >= 0.0 && min_p <= 1.0)) {
                fprintf(stderr, "gridsurvey compare: --min-p '%s': expected a probability in [0, 1]\n", optarg);
                return 2;
            }
            break;
        case 'f':
            if (!strcmp(optarg, "table")) csv = 0;
            else if (!strcmp(optarg, "csv")) csv = 1;
            else {
                fprintf(stderr, "gridsurvey compare: --format '%s': expected table or csv\n", optarg);
                return 2;
            }
            break;
        case 'h': fputs(compare_usage, stdout); return 0;
        default: fputs(compare_usage, stderr); return 2;
        }
    }
    if (optind < argc || !path || nsv != 2) {
        fprintf(stderr, "gridsurvey compare: expected --db DB --survey A --survey B\n%s", compare_usage);
        return 2;
    }
    srv_db *db;
    gs_status s = srv_db_open(path, SRV_DB_READ, &db);
    if (s != GS_OK) return srv_error(s);
    srv_change *v = NULL;
    size_t n = 0;
    srv_compare_totals t;
    s = srv_compare(db, sv[0], sv[1], min_p, &v, &n, &t);
    srv_db_close(db);
    if (s != GS_OK) return srv_error(s);
    char k[64], a[160], b[160], pp[32], pb[32];
    if (csv) {
        printf("site,lat_deg,lon_deg,x_px,y_px,change,a_bulb,a_phase_deg,a_bulb_confidence,"
               "a_phase_confidence,a_detections,b_bulb,b_phase_deg,b_bulb_confidence,"
               "b_phase_confidence,b_detections,p_phase_change,p_bulb_change\n");
        for (size_t i = 0; i < n; i++) {
            const srv_change *x = &v[i];
            printf("%lld,", (long long)x->site_id);
            double pos[4] = {x->lat_deg, x->lon_deg, x->x_px, x->y_px};
            for (int j = 0; j < 4; j++) isnan(pos[j]) ? printf(",") : printf(j < 2 ? "%.7f," : "%.2f,", pos[j]);
            printf("%s", kind_text(x->kinds, k, sizeof k));
            const srv_site_value *side[2] = {&x->a, &x->b};
            for (int j = 0; j < 2; j++) {
                const srv_site_value *y = side[j];
                printf(",%s,", y->bulb_id);
                if (!isnan(y->phase_deg)) printf("%.3f", y->phase_deg);
                printf(",%.6g,%.6g,%ld", y->bulb_confidence, y->phase_confidence, y->detections);
            }
            fmt_p(pp, sizeof pp, x->p_phase_change);
            fmt_p(pb, sizeof pb, x->p_bulb_change);
            printf(",%s,%s\n", isnan(x->p_phase_change) ? "" : pp, isnan(x->p_bulb_change) ? "" : pb);
        }
    } else {
        printf("| site | position | change | %s | %s | P(phase differs) | P(bulb differs) |\n"
               "|---:|---|---|---|---|---:|---:|\n", sv[0], sv[1]);
        for (size_t i = 0; i < n; i++) {
            const srv_change *x = &v[i];
            char pos[64];
            if (isnan(x->lat_deg)) snprintf(pos, sizeof pos, "px %.1f, %.1f", x->x_px, x->y_px);
            else snprintf(pos, sizeof pos, "%.7f, %.7f", x->lat_deg, x->lon_deg);
            side_text(&x->a, a, sizeof a);
            side_text(&x->b, b, sizeof b);
            fmt_p(pp, sizeof pp, x->p_phase_change);
            fmt_p(pb, sizeof pb, x->p_bulb_change);
            printf("| %lld | %s | %s | %s | %s | %s | %s |\n", (long long)x->site_id, pos,
                   kind_text(x->kinds, k, sizeof k), a, b, pp, pb);
        }
        long ph = 0, bu = 0, ap = 0, va = 0;
        for (size_t i = 0; i < n; i++) {
            ph += (v[i].kinds & SRV_CHANGE_PHASE) != 0;
            bu += (v[i].kinds & SRV_CHANGE_BULB) != 0;
            ap += (v[i].kinds & SRV_CHANGE_APPEARED) != 0;
            va += (v[i].kinds & SRV_CHANGE_VANISHED) != 0;
        }
        printf("\n%s: %ld sites, %s: %ld sites, in both: %ld (%ld unchanged); changes: %ld phase, "
               "%ld bulb, %ld appeared, %ld vanished (P >= %g)\n", sv[0], t.sites_a, sv[1], t.sites_b,
               t.both, t.unchanged, ph, bu, ap, va, min_p);
    }
    free(v);
    if (fflush(stdout) != 0 || ferror(stdout)) {
        fprintf(stderr, "gridsurvey compare: cannot write the output\n");
        return 1;
    }
    return 0;
}
