#!/usr/bin/env python3
"""guiding_report.py - guiding.sh's table and plots from its CSV.

    python3 tests/bench/guiding_report.py guiding.csv PLOT_DIR
    python3 tests/bench/guiding_report.py [--prefix P] [--label NAME]
        [--also LABEL=CSV]... guiding.csv PLOT_DIR

Rows: scene, build (base or new), spp (0: the 1-spp load run), rep, cpu,
relmse, worst. Per scene and build, a row's time is the median CPU time over
the repetitions less the median of the 1-spp runs (the scene's load), its
relMSE and worst-0.1 % share the means over the repetitions. For each base
row, the new build's time to the same relMSE is interpolated log-log between
its rows around it; ratio = base time / new time (above 1: the new build gets
there sooner). Prints a Markdown table per scene and writes
PLOT_DIR/guiding_SCENE.svg: relMSE against CPU seconds, log-log, both builds.

Several runs in one report: each --also names another guiding.sh run (its
CSV; several CSVs of one run, other SEED0, joined by commas) whose new build
is drawn and tabled as LABEL beside the first run's (named --label, default
"new"); its ratios are taken against its own base rows, which alternated with
it under the same load. --prefix names the plots PLOT_DIR/PSCENE.svg instead
of guiding_SCENE.svg. Where a run's folder holds guiding.sh's loadavg.csv, the
summary gives the load average's range while the scene ran. CSVs concatenated
with their header lines are read as one. Standard library only.
"""

import argparse
import csv
import math
import os
import statistics
import sys


def load(paths):
    """Rows of the CSVs (comma-separated paths) by (scene, build, spp)."""
    rows = {}
    for path in paths.split(","):
        with open(path) as f:
            for r in csv.DictReader(f):
                if r["spp"] == "spp":  # the header of a concatenated CSV
                    continue
                key = (r["scene"], r["build"], int(r["spp"]))
                rows.setdefault(key, []).append(r)
    return rows


def loads(paths):
    """{scene: [1-minute load averages]} from loadavg.csv beside each CSV,
    for the scenes that CSV holds (a CSV cut from a run's keeps its own)."""
    out = {}
    for path in paths.split(","):
        p = os.path.join(os.path.dirname(path) or ".", "loadavg.csv")
        if not os.path.exists(p):
            continue
        scenes = {s for (s, _, _) in load(path)}
        with open(p) as f:
            for r in csv.DictReader(f):
                if r["load1"] != "load1" and r["scene"] in scenes:
                    out.setdefault(r["scene"], []).append(float(r["load1"]))
    return out


def series(rows, scene, build):
    """[(spp, seconds, relmse, worst)] by spp, the load's time taken off."""
    load_cpu = statistics.median(float(r["cpu"]) for r in rows.get((scene, build, 0), [{"cpu": 0}]))
    out = []
    for (s, b, spp), rs in sorted(rows.items(), key=lambda kv: kv[0][2]):
        if s != scene or b != build or spp == 0:
            continue
        t = statistics.median(float(r["cpu"]) for r in rs) - load_cpu
        rel = statistics.fmean(float(r["relmse"]) for r in rs)
        worst = statistics.fmean(float(r["worst"]) for r in rs)
        out.append((spp, max(t, 1e-3), rel, worst))
    return out


def time_at(ser, level):
    """The time ser takes to reach relMSE level (log-log), or None."""
    for (s0, t0, e0, _), (s1, t1, e1, _) in zip(ser, ser[1:]):
        if e0 >= level >= e1 and e0 > e1:
            f = (math.log(level) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return None


COLOURS = ("#888", "#c22", "#26c", "#2a2", "#a6c")


def svg(path, scene, curves):
    """curves: [(label, series)], the base first."""
    w, h, m = 420, 300, 50
    pts = [p for _, ser in curves for p in ser]
    xs = [math.log10(p[1]) for p in pts]
    ys = [math.log10(p[2]) for p in pts]
    x0, x1 = math.floor(min(xs) * 2) / 2, math.ceil(max(xs) * 2) / 2
    y0, y1 = math.floor(min(ys) * 4) / 4, math.ceil(max(ys) * 4) / 4
    x1, y1 = max(x1, x0 + 0.5), max(y1, y0 + 0.25)

    def px(x):
        return m + (math.log10(x) - x0) / (x1 - x0) * (w - 1.5 * m)

    def py(y):
        return h - m - (math.log10(y) - y0) / (y1 - y0) * (h - 1.6 * m)

    o = ['<svg xmlns="http://www.w3.org/2000/svg" width="%d" height="%d" '
         'font-family="sans-serif" font-size="11">' % (w, h),
         '<rect width="100%" height="100%" fill="white"/>',
         '<text x="%d" y="16" font-size="13">%s: relMSE against CPU seconds</text>' % (m, scene)]
    for k in range(int(round((x1 - x0) * 2)) + 1):
        x = x0 + k / 2
        X = px(10 ** x)
        o.append('<line x1="%.1f" y1="%d" x2="%.1f" y2="%d" stroke="#ddd"/>' % (X, m * 0.6, X, h - m))
        o.append('<text x="%.1f" y="%d" text-anchor="middle">%.3g</text>' % (X, h - m + 14, 10 ** x))
    for k in range(int(round((y1 - y0) * 4)) + 1):
        y = y0 + k / 4
        Y = py(10 ** y)
        o.append('<line x1="%d" y1="%.1f" x2="%d" y2="%.1f" stroke="#ddd"/>' % (m, Y, w - m / 2, Y))
        o.append('<text x="%d" y="%.1f" text-anchor="end">%.3g</text>' % (m - 4, Y + 4, 10 ** y))
    o.append('<text x="%d" y="%d" text-anchor="middle">CPU seconds (log)</text>' % (w / 2, h - 12))
    for k, (name, ser) in enumerate(curves):
        col = COLOURS[k % len(COLOURS)]
        p = " ".join("%.1f,%.1f" % (px(t), py(e)) for _, t, e, _ in ser)
        o.append('<polyline points="%s" fill="none" stroke="%s" stroke-width="2"/>' % (p, col))
        for spp, t, e, _ in ser:
            o.append('<circle cx="%.1f" cy="%.1f" r="3" fill="%s"><title>%d spp</title></circle>'
                     % (px(t), py(e), col, spp))
        o.append('<text x="%d" y="%d" fill="%s">%s</text>' % (w - 100, m + 14 * k, col, name))
    o.append('</svg>')
    with open(path, "w") as f:
        f.write("\n".join(o) + "\n")


def compare(base, new):
    """Per base row (spp, base row, new row, new time to its relMSE, ratio)."""
    out = []
    for b, n in zip(base, new):
        t = time_at(new, b[2])
        out.append((b[0], b, n, t, b[1] / t if t else None))
    return out


def summary_cells(base, new):
    """ratio median (range), relMSE and worst share at the largest spp,
    CPU per sample new / base there."""
    ratios = [r for *_, r in compare(base, new) if r]
    if ratios:
        med = "%.2fx (%.2f-%.2f)" % (statistics.median(ratios), min(ratios), max(ratios))
    else:
        med = "-"
    return [med, "%.4g -> %.4g" % (base[-1][2], new[-1][2]),
            "%.3f -> %.3f" % (base[-1][3], new[-1][3]), "%.2f" % (new[-1][1] / base[-1][1])]


def main():
    ap = argparse.ArgumentParser(description="guiding.sh's table and plots")
    ap.add_argument("csv", help="guiding.sh's CSV (several of one run: joined by commas)")
    ap.add_argument("plots", help="folder for the SVG plots")
    ap.add_argument("--prefix", default="guiding_", help="plot names: PREFIX + scene + .svg")
    ap.add_argument("--label", default="new", help="the first run's new build's name")
    ap.add_argument("--also", action="append", default=[], metavar="LABEL=CSV",
                    help="another run whose new build is shown beside the first")
    a = ap.parse_args()
    runs = [(a.label, load(a.csv), loads(a.csv))]
    for spec in a.also:
        label, _, path = spec.partition("=")
        if not path:
            ap.error("--also wants LABEL=CSV, not %r" % spec)
        runs.append((label, load(path), loads(path)))
    os.makedirs(a.plots, exist_ok=True)
    scenes = []
    for (s, _, _) in runs[0][1]:
        if s not in scenes:
            scenes.append(s)
    summary = []
    for scene in scenes:
        base = series(runs[0][1], scene, "base")
        curves = [("base", base)]
        print("\n### %s\n" % scene)
        for label, rows, ld in runs:
            rbase, new = series(rows, scene, "base"), series(rows, scene, "new")
            if not rbase or not new:
                continue
            curves.append((label, new))
            print("%s against its own run's base:\n" % label)
            print("| spp | base s | base relMSE | %s s | %s relMSE | %s s to base's relMSE | ratio |"
                  % (label, label, label))
            print("|---:|---:|---:|---:|---:|---:|---:|")
            for spp, b, n, t, ratio in compare(rbase, new):
                # base spp, or base/new where BASE_SPP gave the base its own
                label_spp = "%d" % spp if n[0] == spp else "%d / %d" % (spp, n[0])
                print("| %s | %.2f | %.4g | %.2f | %.4g | %s | %s |" % (
                    label_spp, b[1], b[2], n[1], n[2], "%.2f" % t if t else "-",
                    "%.2fx" % ratio if ratio else "-"))
            print()
            ls = ld.get(scene)
            lcell = "%.1f-%.1f (median %.1f)" % (min(ls), max(ls), statistics.median(ls)) if ls else "-"
            summary.append([scene, label] + summary_cells(rbase, new) + [lcell])
        svg(os.path.join(a.plots, "%s%s.svg" % (a.prefix, scene)), scene, curves)
    print("| scene | run | time ratio base/new, median (range) | relMSE at max spp base -> new "
          "| worst 0.1 % share base -> new | CPU per sample new/base | load average |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for cells in summary:
        print("| " + " | ".join(cells) + " |")


main()
