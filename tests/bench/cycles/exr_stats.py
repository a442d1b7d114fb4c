# Mean brightness of EXRs, and their difference, read through Blender (Debian's
# python3 has no OpenEXR module; Blender's image loader reads EXR):
#
#   blender -b --factory-startup --python exr_stats.py -- A.exr [B.exr]
#
# Prints "EXR_MEAN path r g b" for each file and, with two files,
# "EXR_DIFF rmse=... relmse=... mean_ratio=..." with A compared to B as the
# reference. RMSE is over the R, G, B values of all pixels; relMSE is the mean of
# (a - b)^2 / (b^2 + 1e-2). compare.sh uses `ptbench error` for the numbers it
# reports; this script gives the calibration means (and a cross-check).
import sys

import bpy
import numpy as np


def load(path):
    img = bpy.data.images.load(path, check_existing=False)
    img.colorspace_settings.name = "Non-Color"  # the values as stored, linear
    w, h = img.size
    px = np.empty(w * h * img.channels, dtype=np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, img.channels)[:, :, :3].astype(np.float64)
    return px


def main():
    paths = sys.argv[sys.argv.index("--") + 1:]
    imgs = [load(p) for p in paths]
    for p, a in zip(paths, imgs):
        m = a.reshape(-1, 3).mean(axis=0)
        print("EXR_MEAN %s %.6g %.6g %.6g" % (p, m[0], m[1], m[2]))
    if len(imgs) == 2:
        a, b = imgs
        d = a - b
        rmse = float(np.sqrt((d * d).mean()))
        rel = float((d * d / (b * b + 1e-2)).mean())
        print("EXR_DIFF rmse=%.6g relmse=%.6g mean_ratio=%.6g" % (rmse, rel, a.mean() / b.mean()))


main()
