/*
 * anim.c - ptbench-anim: the per-frame set-up cost of an animated scene.
 *
 *   ptbench-anim SCENE [ANIMATION [FRAMES]]
 *
 * For FRAMES frames at 24 fps over the animation's range (default 24), the
 * median wall time of three ways to get a frame's scene ready to render:
 * a fresh load (pt_scene_load posed at the frame's time) plus the
 * accelerator's build; a re-pose of the loaded rig (pt_anim_pose) plus the
 * accelerator's build; the re-pose alone. Not pass/fail.
 */
#include <stdio.h>
#include <stdlib.h>

#include "common/base/clock.h"
#include "common/scene/accel.h"
#include "common/scene/anim.h"

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static void quiet(void *user, const char *msg)
{
    (void)user;
    (void)msg;
}

int main(int argc, char **argv)
{
    if (argc < 2 || argc > 4) {
        fprintf(stderr, "usage: ptbench-anim SCENE [ANIMATION [FRAMES]]\n");
        return 2;
    }
    int frames = argc > 3 ? atoi(argv[3]) : 24;
    if (frames < 1 || frames > 10000)
        frames = 24;
    pt_scene_opts o = {0};
    o.animate = 1;
    o.animation = argc > 2 && argv[2][0] ? argv[2] : NULL;
    o.warn = quiet;
    pt_error err = {0};
    pt_scene *s = NULL;
    pt_anim *a = NULL;
    if (pt_anim_load(argv[1], &o, &s, &a, &err) != PT_OK) {
        fprintf(stderr, "ptbench-anim: %s\n", err.msg);
        return 1;
    }
    double t0, t1;
    pt_anim_range(a, &t0, &t1);
    double *reload = calloc((size_t)frames, sizeof(double));
    double *repose = calloc((size_t)frames, sizeof(double));
    double *pose = calloc((size_t)frames, sizeof(double));
    if (!reload || !repose || !pose)
        return 1;
    int rc = 0;
    for (int f = 0; f < frames && rc == 0; f++) {
        double t = t0 + f / 24.0;
        if (t > t1)
            t = t0 + (t1 - t0) * f / frames;
        /* A fresh load, then its accelerator. */
        double c0 = pt_now_s();
        pt_scene *fresh = NULL;
        pt_accel *acc = NULL;
        o.time = t;
        if (pt_scene_load(argv[1], &o, &fresh, &err) != PT_OK ||
            pt_accel_new(fresh, &acc, &err) != PT_OK)
            rc = 1;
        reload[f] = pt_now_s() - c0;
        pt_accel_free(acc);
        pt_scene_free(fresh);
        acc = NULL;
        /* The re-pose, then its accelerator. */
        c0 = pt_now_s();
        if (pt_anim_pose(a, t, s, &err) != PT_OK)
            rc = 1;
        double c1 = pt_now_s();
        if (rc == 0 && pt_accel_new(s, &acc, &err) != PT_OK)
            rc = 1;
        repose[f] = pt_now_s() - c0;
        pose[f] = c1 - c0;
        pt_accel_free(acc);
    }
    if (rc) {
        fprintf(stderr, "ptbench-anim: %s\n", err.msg);
    } else {
        printf("%s: %u vertices, %u triangles, %d frames over [%g, %g] s\n", argv[1],
               s->num_vertices, s->num_triangles, frames, t0, t1);
        printf("median per frame: reload+BVH %.3f ms, re-pose+BVH %.3f ms, re-pose %.3f ms\n",
               1e3 * median(reload, frames), 1e3 * median(repose, frames),
               1e3 * median(pose, frames));
    }
    free(reload);
    free(repose);
    free(pose);
    pt_anim_free(a);
    pt_scene_free(s);
    return rc;
}
