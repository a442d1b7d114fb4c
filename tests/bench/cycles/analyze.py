#!/usr/bin/env python3
"""Summarise compare.sh's runs.tsv and refs.tsv as Markdown (standard library only).

  analyze.py runs.tsv refs.tsv

Per scene, renderer and spp: median path-tracing time, median whole-render
time (Cycles' bpy.ops.render.render; = trace for ptfarm), median RMSE against
the renderer's own converged reference and against the other renderer's.
Then the time each renderer needs to reach the same RMSE (own references),
interpolated piecewise linearly in log(time)-log(RMSE) between the medians
and extrapolated from the end segments, evaluated at every RMSE either
renderer measured; ratio = ptfarm time / Cycles time (target: <= 0.5).
"""
import math
import statistics
import sys
from collections import defaultdict


def read(path):
    rows = []
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            rows.append(line.rstrip("\n").split("\t"))
    return rows


def time_at(curve, err):
    """curve: [(time, rmse)] sorted by time; log-log interpolation of time at err."""
    pts = [(math.log(t), math.log(e)) for t, e in curve if t > 0 and e > 0]
    if len(pts) < 2:
        return float("nan")
    le = math.log(err)
    # segment whose RMSE range holds err, else the nearest end segment
    for i in range(len(pts) - 1):
        (t0, e0), (t1, e1) = pts[i], pts[i + 1]
        if min(e0, e1) <= le <= max(e0, e1):
            break
    else:
        i = 0 if le > pts[0][1] else len(pts) - 2
        (t0, e0), (t1, e1) = pts[i], pts[i + 1]
    if e1 == e0:
        return math.exp(t0)
    return math.exp(t0 + (le - e0) * (t1 - t0) / (e1 - e0))


def main():
    runs = read(sys.argv[1])
    refs = read(sys.argv[2]) if len(sys.argv) > 2 else []
    groups = defaultdict(list)
    for r in runs:
        scene, rn, spp = r[0], r[1], int(r[2])
        groups[(scene, rn, spp)].append((float(r[5]), float(r[6]), float(r[7]), float(r[8])))
    scenes = []
    for s, _, _ in groups:
        if s not in scenes:
            scenes.append(s)
    out = []
    for ref in refs:
        out.append("Converged references, %s: RMSE(ptfarm ref vs Cycles ref) = %s; "
                   "means ptfarm %s, Cycles %s" % (ref[0], ref[1], ref[3], ref[4]))
    if refs:
        out.append("")
    for s in scenes:
        out.append("### %s" % s)
        out.append("")
        out.append("| renderer | spp | trace s (median) | whole render s | RMSE vs own ref | RMSE vs other ref | spp/s |")
        out.append("|---|---:|---:|---:|---:|---:|---:|")
        curves = {}
        for rn in ("ptfarm", "cycles"):
            pts = []
            for spp in sorted(k[2] for k in groups if k[0] == s and k[1] == rn):
                g = groups[(s, rn, spp)]
                tr = statistics.median(x[0] for x in g)
                tot = statistics.median(x[1] for x in g)
                own = statistics.median(x[2] for x in g)
                oth = statistics.median(x[3] for x in g)
                pts.append((tr, own))
                out.append("| %s | %d | %.3f | %.3f | %.4g | %.4g | %s |" % (
                    rn, spp, tr, tot, own, oth, "%.3g" % (spp / tr) if tr > 0 else "-"))
            curves[rn] = sorted(pts)
        out.append("")
        out.append("Time to equal RMSE (own references; log-log interpolation):")
        out.append("")
        out.append("| RMSE | ptfarm s | Cycles s | ptfarm / Cycles |")
        out.append("|---:|---:|---:|---:|")
        ratios = []
        errs = sorted({e for c in curves.values() for _, e in c}, reverse=True)
        for e in errs:
            tp = time_at(curves["ptfarm"], e)
            tc = time_at(curves["cycles"], e)
            ratio = tp / tc
            ratios.append(ratio)
            out.append("| %.4g | %.3f | %.3f | %.2f |" % (e, tp, tc, ratio))
        finite = [r for r in ratios if math.isfinite(r)]
        if finite:
            gm = math.exp(statistics.mean(math.log(r) for r in finite))
            out.append("")
            out.append("%s: ptfarm needs %.2f of Cycles' time for equal RMSE (geometric mean; "
                       "range %.2f-%.2f); target <= 0.5: %s" % (
                           s, gm, min(finite), max(finite), "met" if gm <= 0.5 else "NOT met"))
        out.append("")
    print("\n".join(out))


main()
