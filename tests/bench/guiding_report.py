#!/usr/bin/env python3
"""guiding_report.py - guiding.sh's table and plots from its CSV.

    python3 tests/bench/guiding_report.py guiding.csv PLOT_DIR

Rows: scene, build (base or new), spp (0: the 1-spp load run), rep, cpu,
relmse, worst. Per scene and build, a row's time is the median CPU time over
the repetitions less the median of the 1-spp runs (the scene's load), its
relMSE and worst-0.1 % share the means over the repetitions. For each base
row, the new build's time to the same relMSE is interpolated log-log between
its rows around it; ratio = base time / new time (above 1: the new build gets
there sooner). Prints a Markdown table per scene and writes
PLOT_DIR/guiding_SCENE.svg: relMSE against CPU seconds, log-log, both builds.
Standard library only.
"""

import csv
import math
import os
import statistics
import sys


def load(path):
    rows = {}
    with open(path) as f:
        for r in csv.DictReader(f):
            key = (r["scene"], r["build"], int(r["spp"]))
            rows.setdefault(key, []).append(r)
    return rows


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


def svg(path, scene, base, new):
    w, h, m = 420, 300, 50
    pts = base + new
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
    for name, ser, col in (("base", base, "#888"), ("new", new, "#c22")):
        p = " ".join("%.1f,%.1f" % (px(t), py(e)) for _, t, e, _ in ser)
        o.append('<polyline points="%s" fill="none" stroke="%s" stroke-width="2"/>' % (p, col))
        for spp, t, e, _ in ser:
            o.append('<circle cx="%.1f" cy="%.1f" r="3" fill="%s"><title>%d spp</title></circle>'
                     % (px(t), py(e), col, spp))
    o.append('<text x="%d" y="%d" fill="#888">base</text>' % (w - 100, m))
    o.append('<text x="%d" y="%d" fill="#c22">new</text>' % (w - 100, m + 14))
    o.append('</svg>')
    with open(path, "w") as f:
        f.write("\n".join(o) + "\n")


def main():
    rows = load(sys.argv[1])
    plots = sys.argv[2]
    scenes = []
    for (s, _, _) in rows:
        if s not in scenes:
            scenes.append(s)
    summary = []
    for scene in scenes:
        base, new = series(rows, scene, "base"), series(rows, scene, "new")
        print("\n### %s\n" % scene)
        print("| spp | base s | base relMSE | new s | new relMSE | new s to base's relMSE | ratio |")
        print("|---:|---:|---:|---:|---:|---:|---:|")
        ratios = []
        for b, n in zip(base, new):
            t = time_at(new, b[2])
            ratio = b[1] / t if t else None
            if ratio:
                ratios.append(ratio)
            print("| %d | %.2f | %.4g | %.2f | %.4g | %s | %s |" % (
                b[0], b[1], b[2], n[1], n[2], "%.2f" % t if t else "-",
                "%.2fx" % ratio if ratio else "-"))
        med = statistics.median(ratios) if ratios else None
        wb, wn = base[-1][3], new[-1][3]
        print("\nmedian time ratio base/new at equal relMSE: %s; worst-0.1%% share at %d spp: "
              "base %.3f, new %.3f" % ("%.2fx" % med if med else "- (no common level)",
                                       base[-1][0], wb, wn))
        summary.append((scene, med, base[-1][2], new[-1][2], wb, wn))
        svg(os.path.join(plots, "guiding_%s.svg" % scene), scene, base, new)
    print("\n| scene | time ratio base/new | relMSE base | relMSE new | worst 0.1 % base | new |")
    print("|---|---:|---:|---:|---:|---:|")
    for scene, med, rb, rn, wb, wn in summary:
        print("| %s | %s | %.4g | %.4g | %.3f | %.3f |" % (
            scene, "%.2fx" % med if med else "-", rb, rn, wb, wn))


main()
