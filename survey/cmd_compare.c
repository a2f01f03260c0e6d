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
    "       gridsurvey compare --db DB --survey A --survey B --by G [--clip AREAS.geojson]\n"
    "                          [--bbox MINLON,MINLAT,MAXLON,MAXLAT] [--min-phase-confidence X]\n"
    "                          [--format table|csv]\n"
    "\n"
    "The light sites (physical lights) whose grid phase or bulb changed from survey A to survey\n"
    "B, with the evidence for each (both surveys' answers, their confidences and detections,\n"
    "and the probability that they differ), and the sites seen in only one of them (appeared\n"
    "in B, vanished from A: a light off, removed, or outside the other survey's view).\n"
    "With --by, the phase shares of each group (e.g. each feeder area of --clip) in A and in B\n"
    "instead, with the two-proportion z test of each share's change and the chi-square test of\n"
    "homogeneity of the 0/120/240 split (P: two-sided; the surveys taken as independent samples).\n"
    "\n"
    "Examples:\n"
    "  gridsurvey compare --db city.sqlite --survey june --survey july\n"
    "  gridsurvey compare --db city.sqlite --survey june --survey july --clip feeders.geojson \\\n"
    "                     --by feature:feeder\n"
    "\n"
    "  --db DB          the survey database (read-only)\n"
    "  --survey NAME    survey A, then survey B (given twice: the two surveys read)\n"
    "  --min-p P        report a phase or bulb change when the probability that the answers\n"
    "                   differ is at least P, in [0, 1] (default 0.9)\n"
    "  --by G           per-group share changes; G as in gridsurvey stats (technology,\n"
    "                   cell:SIZE_m, feature:FIELD, combinations; survey is not allowed)\n"
    "  --clip FILE      with --by: only sites inside these areas (GeoJSON polygons)\n"
    "  --bbox B         with --by: only sites in MINLON,MINLAT,MAXLON,MAXLAT\n"
    "  --min-phase-confidence X  with --by: leave out sites whose phase confidence is below X\n"
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

/* A share's cell: "33.3 % -> 40.0 % (+6.7 pp, z 1.02, P 0.3077)" (pp: percentage points). */
static void share_cell(const srv_share_change *c, int i, char *buf, size_t size)
{
    if (isnan(c->share_a[i]) || isnan(c->share_b[i])) {
        char a[16] = "-", b[16] = "-";
        if (!isnan(c->share_a[i])) snprintf(a, sizeof a, "%.1f %%", 100.0 * c->share_a[i]);
        if (!isnan(c->share_b[i])) snprintf(b, sizeof b, "%.1f %%", 100.0 * c->share_b[i]);
        snprintf(buf, size, "%s -> %s", a, b);
        return;
    }
    char zp[48] = "";
    if (!isnan(c->z[i])) snprintf(zp, sizeof zp, ", z %.2f, P %.4f", c->z[i], c->p[i]);
    snprintf(buf, size, "%.1f %% -> %.1f %% (%+.1f pp%s)", 100.0 * c->share_a[i], 100.0 * c->share_b[i],
             100.0 * (c->share_b[i] - c->share_a[i]), zp);
}

/* compare --by: the per-group share changes. */
static int compare_shares(const char *path, const char *const sv[2], srv_stats_opts *so, int by,
                          const char *clip, int csv)
{
    if (!by) {
        return srv_usage_error("compare", "--clip, --bbox and --min-phase-confidence need --by");
    }
    int by_feature = so->by == SRV_BY_FEATURE, by_survey = so->by == SRV_BY_SURVEY;
    for (int i = 0; i < so->n_then; i++) {
        by_feature |= so->then[i] == SRV_BY_FEATURE;
        by_survey |= so->then[i] == SRV_BY_SURVEY;
    }
    if (by_survey) {
        return srv_usage_error("compare", "--by survey: the two surveys are the comparison");
    }
    if (by_feature && !clip) {
        return srv_usage_error("compare", "--by feature:%s needs --clip AREAS.geojson", so->feature_field);
    }
    srv_areas *areas = NULL;
    gs_status s = clip ? srv_areas_load(clip, by_feature ? so->feature_field : NULL, &areas) : GS_OK;
    srv_db *db = NULL;
    if (s == GS_OK) s = srv_db_open(path, SRV_DB_READ, &db);
    so->areas = areas;
    srv_share_change *v = NULL;
    size_t n = 0;
    if (s == GS_OK) s = srv_compare_shares(db, so, sv[0], sv[1], &v, &n);
    srv_db_close(db);
    srv_areas_free(areas);
    if (s != GS_OK) return srv_error("compare", s);
    static const char *const ph[3] = {"0", "120", "240"};
    int cells = 0;
    for (size_t k = 0; k < n; k++) cells |= !isnan(v[k].lat_deg);
    if (csv) {
        printf("group,lat_deg,lon_deg,n_a,n_b");
        for (int i = 0; i < 3; i++)
            printf(",n%s_a,n%s_b,share%s_a,share%s_b,z%s,p%s", ph[i], ph[i], ph[i], ph[i], ph[i], ph[i]);
        printf(",chi2,dof,p_value\n");
        for (size_t k = 0; k < n; k++) {
            const srv_share_change *c = &v[k];
            printf("\"%s\",", c->group);
            isnan(c->lat_deg) ? printf(",,") : printf("%.8f,%.8f,", c->lat_deg, c->lon_deg);
            printf("%ld,%ld", c->total_a, c->total_b);
            for (int i = 0; i < 3; i++) {
                printf(",%ld,%ld", c->n_a[i], c->n_b[i]);
                double x[4] = {c->share_a[i], c->share_b[i], c->z[i], c->p[i]};
                for (int j = 0; j < 4; j++) isnan(x[j]) ? printf(",") : printf(",%.10g", x[j]);
            }
            isnan(c->chi2) ? printf(",,%d,", c->dof) : printf(",%.10g,%d,%.10g", c->chi2, c->dof, c->p_value);
            printf("\n");
        }
    } else {
        printf("Phase shares of %s -> %s (two-proportion z test of each change; chi-square test of "
               "homogeneity of the split):\n\n| group |%s n %s | n %s | 0 deg | 120 deg | 240 deg | chi2 | P |\n"
               "|---|%s---:|---:|---|---|---|---:|---:|\n", sv[0], sv[1], cells ? " lat, lon |" : "", sv[0], sv[1],
               cells ? "---|" : "");
        for (size_t k = 0; k < n; k++) {
            const srv_share_change *c = &v[k];
            char cell[3][128];
            for (int i = 0; i < 3; i++) share_cell(c, i, cell[i], sizeof cell[i]);
            char ll[64] = "";
            if (cells) snprintf(ll, sizeof ll, " %.6f, %.6f |", c->lat_deg, c->lon_deg);
            printf("| %s |%s %ld | %ld | %s | %s | %s | ", c->group, ll, c->total_a, c->total_b, cell[0], cell[1],
                   cell[2]);
            isnan(c->chi2) ? printf("- | - |\n") : printf("%.2f | %.4f |\n", c->chi2, c->p_value);
        }
    }
    free(v);
    if (fflush(stdout) != 0 || ferror(stdout)) return srv_error("compare", gs_fail(GS_EIO, "stdout: write failed"));
    return 0;
}

int srv_cmd_compare(int argc, char **argv)
{
    static const struct option longs[] = {
        {"db", required_argument, 0, 'd'},     {"survey", required_argument, 0, 'S'},
        {"min-p", required_argument, 0, 'p'},  {"format", required_argument, 0, 'f'},
        {"help", no_argument, 0, 'h'},         {"by", required_argument, 0, 'b'},
        {"clip", required_argument, 0, 'C'},   {"bbox", required_argument, 0, 'B'},
        {"min-phase-confidence", required_argument, 0, 'c'}, {0, 0, 0, 0},
    };
    const char *path = NULL, *sv[2] = {NULL, NULL}, *clip = NULL;
    srv_stats_opts so;
    srv_stats_opts_default(&so);
    int by = 0;
    int nsv = 0, csv = 0;
    double min_p = 0.9;
    optind = 1;
    int c;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'd': path = optarg; break;
        case 'S':
            if (nsv == 2) {
                return srv_usage_error("compare", "--survey given more than twice");
            }
            sv[nsv++] = optarg;
            break;
        case 'p':
            if (!srv_num_arg("compare", "--min-p", optarg, 0.0, 1.0, &min_p)) return 2;
            break;
        case 'f':
            if (!strcmp(optarg, "table")) csv = 0;
            else if (!strcmp(optarg, "csv")) csv = 1;
            else {
                return srv_usage_error("compare", "--format '%s': expected table or csv", optarg);
            }
            break;
        case 'b':
            if (srv_stats_parse_by(optarg, &so) != GS_OK) {
                return srv_usage_error("compare", "%s", gs_detail());
            }
            by = 1;
            break;
        case 'C': clip = optarg; break;
        case 'B':
            if (srv_parse_bbox(optarg, so.bbox) != GS_OK) {
                return srv_usage_error("compare", "%s", gs_detail());
            }
            break;
        case 'c':
            if (!srv_num_arg("compare", "--min-phase-confidence", optarg, 0.0, 1.0, &so.min_phase_confidence)) return 2;
            break;
        case 'h': fputs(compare_usage, stdout); return 0;
        default: return srv_usage_hint("compare", argv);
        }
    }
    if (optind < argc) return srv_usage_error("compare", "unexpected argument '%s'", argv[optind]);
    if (!path) return srv_usage_error("compare", "--db DB is required");
    if (nsv != 2)
        return srv_usage_error("compare", "%sexpected --survey A --survey B", nsv ? "--survey given once: " : "");
    if (by || clip || !isnan(so.bbox[0]) || so.min_phase_confidence > 0.0) return compare_shares(path, sv, &so, by, clip, csv);
    srv_db *db;
    gs_status s = srv_db_open(path, SRV_DB_READ, &db);
    if (s != GS_OK) return srv_error("compare", s);
    srv_change *v = NULL;
    size_t n = 0;
    srv_compare_totals t;
    s = srv_compare(db, sv[0], sv[1], min_p, &v, &n, &t);
    srv_db_close(db);
    if (s != GS_OK) return srv_error("compare", s);
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
    if (fflush(stdout) != 0 || ferror(stdout)) return srv_error("compare", gs_fail(GS_EIO, "stdout: write failed"));
    return 0;
}
