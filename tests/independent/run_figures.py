#!/usr/bin/python3
"""Reproduce the recognition figures with the independent renderer (render.py) and harness
(score.py): every capture is rendered, `gridsurvey recognize` scored with its default options,
with --ambiguous-below 0 and with diagnostic variants, and the tables are written as Markdown
(OUT/results.md) and JSON (OUT/results.json).  Every command run is printed and listed in
results.md.  Deterministic: fixed seeds."""

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
PY = "/usr/bin/python3"

CONFIGS = [  # label, render options
    ("mono K=26 50 Hz", ["--bands", "1", "-K", "26", "--grid-hz", "50"]),
    ("RGB K=26 50 Hz", ["--bands", "3", "-K", "26", "--grid-hz", "50"]),
    ("mono K=13 60 Hz", ["--bands", "1", "-K", "13", "--grid-hz", "60"]),
]
LEVELS = [1000, 3000, 10000, 40000]
FREE_LEVELS, FREE_PERIODS, FREE_CYCLES = [10000, 100000], ["measured", "nominal"], [128, 512, 1024]
FREE_THRESHOLDS, FREE_MAINS = ["0.5", "1", "none"], "whu_001_ref"


def run(cmd, log):
    log.append(" ".join(cmd))
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bin", default=os.path.normpath(os.path.join(HERE, "..", "..", "build", "gridsurvey")))
    ap.add_argument("--out", default="/tmp/indep-figs")
    ap.add_argument("--lights", type=int, default=600)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", default="", help="comma list of parts: levels,blends,ood,continuous,free")
    ap.add_argument("--tables-only", action="store_true", help="rewrite OUT/results.md from OUT/results.json")
    ap.add_argument("--variants", default="default,mc0,me0,bgoff,bgoff_me0,open",
                    help="levels: comma list of recognize variants (default = with the oracle; mc0 "
                         "--ambiguous-below 0; me0 --model-error 0; bgoff, bgoff_me0 --band-model chroma "
                         "[RGB]; open --other-prior 0.2)")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    if a.tables_only:
        r = json.load(open(os.path.join(a.out, "results.json")))
        with open(os.path.join(a.out, "results.md"), "w") as f:
            f.write(tables(r))
        print(tables(r))
        return 0
    csv = os.path.join(a.out, "delight.csv")
    log = []
    run([a.bin, "delight", "export", "-o", csv], log)
    parts = set(a.only.split(",")) if a.only else {"levels", "blends", "ood", "continuous", "free"}
    R = lambda *x: [PY, os.path.join(HERE, "render.py")] + list(x) + ["--delight-csv", csv]
    S = lambda cap, js, *x: [PY, os.path.join(HERE, "score.py"), cap, "--delight-csv", csv, "--bin", a.bin,
                             "--jobs", str(a.jobs), "--json", js] + list(x)
    results = {}
    t0 = time.time()
    if "levels" in parts:
        for ci, (label, ropt) in enumerate(CONFIGS):
            for e in LEVELS:
                cap = os.path.join(a.out, f"c{ci}_{e}")
                run(R(cap, *ropt, "--lights", str(a.lights), "--electrons", str(e), "--seed", str(10 + ci)), log)
                variants = [("default", []), ("mc0", ["--ambiguous-below", "0", "--no-oracle"]),
                            ("me0", ["--model-error", "0", "--no-oracle"]),
                            ("open", ["--other-prior", "0.2", "--no-oracle"])]
                if ropt[1] == "3":
                    variants.append(("bgoff", ["--band-model", "chroma", "--no-oracle"]))
                    variants.append(("bgoff_me0", ["--band-model", "chroma", "--model-error", "0", "--no-oracle"]))
                for vname, vopt in variants:
                    if vname not in a.variants.split(","):
                        continue
                    js = cap + f".{vname}.json"
                    run(S(cap, js, "--label", f"{label} {e} e- {vname}", *vopt), log)
                    results[f"{ci}/{e}/{vname}"] = json.load(open(js))
    if "blends" in parts:
        for e in (10000, 40000):
            cap = os.path.join(a.out, f"blend_{e}")
            run(R(cap, "--bands", "1", "-K", "26", "--grid-hz", "50", "--lights", "0", "--blend-pairs", "60",
                  "--blend-sep", "3", "--electrons", str(e), "--seed", "21"), log)
            for vname, vopt in (("default", []), ("me0", ["--model-error", "0"])):
                js = cap + f".{vname}.json"
                run(S(cap, js, "--no-oracle", *vopt), log)
                results[f"blend/{e}/{vname}"] = json.load(open(js))
    if "ood" in parts:
        oc = [("mono K=13 60 Hz", ["--bands", "1", "-K", "13", "--grid-hz", "60"]),
              ("mono K=26 50 Hz", ["--bands", "1", "-K", "26", "--grid-hz", "50"]),
              ("RGB K=26 50 Hz", ["--bands", "3", "-K", "26", "--grid-hz", "50"])]
        for ci, (label, ropt) in enumerate(oc):
            for e in (10000, 40000):
                cap = os.path.join(a.out, f"ood{ci}_{e}")
                run(R(cap, *ropt, "--lights", "0", "--ood-file", "Old_IKEA_LED", "--ood-count", "40",
                      "--electrons", str(e), "--seed", str(31 + ci)), log)
                for vname, vopt in (("default", []), ("me0", ["--model-error", "0"])):
                    js = cap + f".{vname}.json"
                    run(S(cap, js, "--no-oracle", *vopt), log)
                    results[f"ood/{ci}/{e}/{vname}"] = json.load(open(js))
                    results[f"ood/{ci}/{e}/{vname}"]["config"] = label
    if "continuous" in parts:
        for ci, (label, ropt) in enumerate(CONFIGS[:2]):
            for e in (10000, 40000):
                cap = os.path.join(a.out, f"cont{ci}_{e}")
                run(R(cap, *ropt, "--lights", str(a.lights), "--phases", "continuous", "--electrons", str(e),
                      "--seed", str(41 + ci)), log)
                js = cap + ".default.json"
                run(S(cap, js, "--phases", "continuous", "--oracle-max", "200"), log)
                results[f"cont/{ci}/{e}"] = json.load(open(js))
                results[f"cont/{ci}/{e}"]["config"] = label
    if "free" in parts:
        # free running on a real grid (whu_001_ref's crossings), the period measured or nominal,
        # against the same lights locked; recognize at three drift thresholds
        rgb = CONFIGS[1][1]
        for e in FREE_LEVELS:
            cap = os.path.join(a.out, f"free_locked_{e}")
            run(R(cap, *rgb, "--lights", str(a.lights), "--electrons", str(e), "--seed", "51"), log)
            js = cap + ".json"
            run(S(cap, js, "--no-oracle"), log)
            results[f"free/locked/{e}"] = json.load(open(js))
            for period in FREE_PERIODS:
                for C in FREE_CYCLES:
                    cap = os.path.join(a.out, f"free_{period}_{C}_{e}")
                    run(R(cap, *rgb, "--lights", str(a.lights), "--electrons", str(e), "--seed", "51", "-C", str(C),
                          "--free-running", FREE_MAINS, "--free-period", period), log)
                    cj = json.load(open(os.path.join(cap, "capture.json")))
                    frames = cj["frames"]
                    drift = [f["window_drift_windows"] for f in frames]
                    # each frame's net motion over its exposure, K C (2 P f - 1) windows (signed)
                    net = [cj["K"] * f["cycles"] * (2 * f["window_half_period_s"] * f["grid_hz_measured"] - 1) for f in frames]
                    for t in FREE_THRESHOLDS:
                        js = cap + f".{t}.json"
                        run(S(cap, js, "--no-oracle", "--max-drift-windows", t), log)
                        x = json.load(open(js))
                        x["drift_max"] = max(drift)
                        x["net"] = [min(net), max(net), sum(v > 0 for v in net)]
                        x["frames_out"] = sum(d > float(t) for d in drift) if t != "none" else 0
                        results[f"free/{period}/{C}/{e}/{t}"] = x
    results["_commands"] = log
    results["_wall_s"] = time.time() - t0
    prev = {}
    pj = os.path.join(a.out, "results.json")
    if a.only and os.path.exists(pj):
        prev = json.load(open(pj))
        prev["_commands"] = prev.get("_commands", []) + log
        log = prev["_commands"]
    prev.update(results)
    results = prev
    results["_commands"] = log
    with open(pj, "w") as f:
        json.dump(results, f, indent=1)
    with open(os.path.join(a.out, "results.md"), "w") as f:
        f.write(tables(results))
    print(tables(results))


def p(x, pct=True):
    if x is None:
        return "-"
    return f"{100 * x:.1f}" if pct else f"{x:.3f}"


def answer_cells(x):
    """pair | answered | acc. answered | ECE pair | conf. wrong b / t / p of one scored run."""
    cw = x["confident_wrong"]
    return (f"{p(x['pair_acc'])} | {p(x['answered_share'])} | {p(x['answered_acc'])} | {p(x['ece_pair'], 0)} | "
            f"{p(cw['bulb'])} / {p(cw['technology'])} / {p(cw['phase'])}")


def tables(r):
    out = []
    w = out.append
    if any(k.endswith("/default") and k[0].isdigit() for k in r):
        w("### Isolated lights, default `recognize` options\n")
        w("Percentages of the matched lights unless noted. *pair* = best guess bulb and phase right (runner-up for "
          "unknown/dim lights, the `--ambiguous-below 0` phase for phase-ambiguous ones); *oracle* = the maximum-"
          "likelihood oracle on the same lights; *answered* = not unknown/dim/bulb- or phase-ambiguous; "
          "*amb. but right* = flagged phase_ambiguous while the best phase is right; *conf. wrong* = confidence "
          "> 0.9 and wrong bulb / technology / phase, per answered light.\n")
        w("| config | e-/light | detected | false | pair | oracle pair | bulb | phase | answered | acc. answered | phase amb. | amb. but right | ECE pair / bulb / phase | oracle ECE pair | conf. wrong b / t / p | median chi2/dof |")
        w("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for ci, (label, _) in enumerate(CONFIGS):
            for e in LEVELS:
                x = r.get(f"{ci}/{e}/default")
                if not x:
                    continue
                d = x["detection"]["isolated"]
                o = x.get("oracle_matched", {})
                cw = x["confident_wrong"]
                w(f"| {label} | {e:,} | {d[0]}/{d[1]} | {x['false_detections']} | {p(x['pair_acc'])} | {p(o.get('pair_acc'))} | "
                  f"{p(x['bulb_acc'])} | {p(x['phase_acc'])} | {p(x['answered_share'])} | {p(x['answered_acc'])} | "
                  f"{p(x['phase_amb_share'])} | {p(x['phase_amb_but_right'])} | "
                  f"{p(x['ece_pair'], 0)} / {p(x['ece_bulb'], 0)} / {p(x['ece_phase'], 0)} | {p(o.get('ece_pair'), 0)} | "
                  f"{p(cw['bulb'])} / {p(cw['technology'])} / {p(cw['phase'])} | {x['median_chi2_dof']:.2f} |")
        w("")
        if any(k.endswith("/open") for k in r):
            w("### The same captures in the open world (`--other-prior 0.2`)\n")
            w("| config | e-/light | pair | answered | acc. answered | ECE pair | conf. wrong b / t / p |")
            w("|---|---|---|---|---|---|---|")
            for ci, (label, _) in enumerate(CONFIGS):
                for e in LEVELS:
                    x = r.get(f"{ci}/{e}/open")
                    if x:
                        w(f"| {label} | {e:,} | {answer_cells(x)} |")
            w("")
        w("### The same captures with `--ambiguous-below 0`, `--model-error 0` and (RGB) `--band-model chroma`\n")
        w("| config | e-/light | mc0: answered | mc0: acc. answered | mc0: conf. wrong b / t / p | me0: pair | me0: answered | me0: acc. answered | me0: median chi2/dof | me0: ECE pair | bg off: pair | bg off: answered | bg off+me0: pair | bg off+me0: median chi2/dof |")
        w("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for ci, (label, _) in enumerate(CONFIGS):
            for e in LEVELS:
                m0, me, bg, bm = (r.get(f"{ci}/{e}/{v}") for v in ("mc0", "me0", "bgoff", "bgoff_me0"))
                if not m0:
                    continue
                cw = m0["confident_wrong"]
                w(f"| {label} | {e:,} | {p(m0['answered_share'])} | {p(m0['answered_acc'])} | "
                  f"{p(cw['bulb'])} / {p(cw['technology'])} / {p(cw['phase'])} | {p(me['pair_acc'])} | {p(me['answered_share'])} | "
                  f"{p(me['answered_acc'])} | {me['median_chi2_dof']:.2f} | {p(me['ece_pair'], 0)} | "
                  f"{p(bg['pair_acc']) if bg else '-'} | {p(bg['answered_share']) if bg else '-'} | "
                  f"{p(bm['pair_acc']) if bm else '-'} | {('%.2f' % bm['median_chi2_dof']) if bm else '-'} |")
        w("")
    if any(k.startswith("blend/") for k in r):
        w("### Blends: 60 pairs of different (bulb, phase) 3 px apart, mono K=26 50 Hz, both members at the same e-\n")
        w("| e-/member | options | one blob | resolved (2+ lights) | one blob, conf > 0.9, bulb of neither member | one blob, conf > 0.9, bulb of one member |")
        w("|---|---|---|---|---|---|")
        for e in (10000, 40000):
            for v, name in (("default", "default"), ("me0", "--model-error 0")):
                x = r.get(f"blend/{e}/{v}")
                if x:
                    b = x["blends"]
                    w(f"| {e:,} | {name} | {b['one_blob']}/60 | {b['resolved_2plus']} | {b['one_blob_confident_bulb_of_neither']} | {b['one_blob_confident_bulb_of_one_member']} |")
        w("")
    if any(k.startswith("ood/") for k in r):
        w("### Out of the database: 40 lights of Old_IKEA_LED (LED, capacitor driver, 14.8 % flicker folded here)\n")
        w("| config | e-/light | options | detected | unknown | conf > 0.9, other technology | conf > 0.9, not an LED | bulb conf > 0.9, other technology | called | median chi2/dof |")
        w("|---|---|---|---|---|---|---|---|---|---|")
        for ci in range(3):
            for e in (10000, 40000):
                for v, name in (("default", "default"), ("me0", "--model-error 0")):
                    x = r.get(f"ood/{ci}/{e}/{v}")
                    if x:
                        o = x["out_of_db"]
                        called = ", ".join(f"{k} {n}" for k, n in sorted(o["called"].items(), key=lambda t: -t[1]))
                        w(f"| {x['config']} | {e:,} | {name} | {o['detected']}/40 | {o['unknown']} | {o['conf_gt_0.9_other_technology']} | "
                          f"{o['conf_gt_0.9_other_family']} | {o['bulb_conf_gt_0.9_other_technology']} | {called} | {o['median_chi2_dof']:.2f} |")
        w("")
    if any(k.startswith("cont/") for k in r):
        w("### Continuous phases (render and recognize `--phases continuous`)\n")
        w("*pair* = bulb right and phase within 30 deg (all matched lights); the oracle (a grid of max(4K, 64) "
          "delays per bulb, refined 16x around each plausible peak) ran on the first 200 lights, compared with the recogniser on the same lights.\n")
        w("| config | e-/light | pair | pair, oracle's lights | oracle pair | oracle bulb | bulb | RMS phase error, deg (bulb right) | RMS (error / reported sigma) | ECE pair | oracle ECE pair | median chi2/dof |")
        w("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for ci in range(2):
            for e in (10000, 40000):
                x = r.get(f"cont/{ci}/{e}")
                if x:
                    o = x.get("oracle_matched", {})
                    w(f"| {x['config']} | {e:,} | {p(x['pair_acc'])} | {p(x.get('recognizer_pair_acc_on_oracle_set'))} | "
                      f"{p(o.get('pair_acc'))} | {p(o.get('bulb_acc'))} | {p(x['bulb_acc'])} | "
                      f"{x['phase_err_rms_deg']:.2f} | {x['phase_z_rms']:.2f} | {p(x['ece_pair'], 0)} | "
                      f"{p(o.get('ece_pair'), 0)} | {x['median_chi2_dof']:.2f} |")
        w("")
    if any(k.startswith("free/") for k in r):
        w(f"### Free running on a real grid ({FREE_MAINS}'s crossings), RGB K=26 50 Hz\n")
        w("Each frame's windows timed with a fixed half period P from its first crossing (`render.py --free-running`: "
          "P measured over the 64 half periods before each exposure, as the firmware does, or the nominal 10 ms), "
          "scored at `recognize --max-drift-windows` 0.5, 1 and none (the default, auto, is none for the measured period and 0.5 "
          "for the nominal one: render.py writes capture.json's `window_period`); *largest drift* the frames' largest "
          "`window_drift_windows` (windows), *net* the frames' signed net motions over their exposures, "
          "K C (2 P f - 1) windows from capture.json (the least and the most, and how many frames moved forward), "
          "*out* the frames over the threshold. *locked*: the same lights AC-locked. Columns as above.\n")
        w("| period | C | e-/light | largest drift | net (frames > 0) | threshold | out of 26 | pair | answered | acc. answered | ECE pair | conf. wrong b / t / p |")
        w("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for e in FREE_LEVELS:
            x = r.get(f"free/locked/{e}")
            if x:
                w(f"| locked | - | {e:,} | 0 | 0 | - | 0 | {answer_cells(x)} |")
            for period in FREE_PERIODS:
                for C in FREE_CYCLES:
                    for t in FREE_THRESHOLDS:
                        x = r.get(f"free/{period}/{C}/{e}/{t}")
                        if x:
                            n = x.get("net")
                            nc = f"{n[0]:+.2f} .. {n[1]:+.2f} ({n[2]})" if n else "-"
                            w(f"| {period} | {C} | {e:,} | {x['drift_max']:.2f} | {nc} | {t} | {x['frames_out']} | {answer_cells(x)} |")
        w("")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())
