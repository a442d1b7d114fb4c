/*
 * anim.c - ptbench-anim: the per-frame set-up cost of an animated scene.
 *
 *   ptbench-anim SCENE [ANIMATION [FRAMES]]
 *
 * For FRAMES frames at 24 fps over the animation's range (default 24), the
 * median wall time of three ways to get a frame's scene ready to render:
 * a fresh load (pt_scene_load posed at the frame's time) plus the
 * accelerator's build (pt_accel_new: a new Embree device and BVH); a re-pose
 * of the loaded rig (pt_anim_pose) plus pt_accel_new; the re-pose alone; and
 * on one Embree scene kept across frames (built as accel.c builds, robust,
 * high quality), the re-pose into its vertex buffer (pt_anim_pose_into)
 * plus a rebuild, and plus a refit (RTC_BUILD_QUALITY_REFIT: the topology
 * never changes between poses). Wall times, and the process's CPU time for
 * the first two (steadier on a shared machine). Not pass/fail.
 */
#include <embree3/rtcore.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

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

/* The process's CPU time (all its threads): steadier than wall time on a
 * loaded machine. */
static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
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
    double *rebuild = calloc((size_t)frames, sizeof(double));
    double *refit = calloc((size_t)frames, sizeof(double));
    double *reload_cpu = calloc((size_t)frames, sizeof(double));
    double *repose_cpu = calloc((size_t)frames, sizeof(double));
    if (!reload || !repose || !pose || !rebuild || !refit || !reload_cpu || !repose_cpu)
        return 1;
    /* Two kept Embree scenes over the same vertices: one rebuilt, one refitted. */
    RTCDevice dev = rtcNewDevice("");
    RTCScene sc[2];
    RTCGeometry geo[2];
    float *vb[2];
    for (int k = 0; k < 2; k++) {
        sc[k] = rtcNewScene(dev);
        rtcSetSceneFlags(sc[k], RTC_SCENE_FLAG_ROBUST);
        rtcSetSceneBuildQuality(sc[k], RTC_BUILD_QUALITY_HIGH);
        geo[k] = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetGeometryBuildQuality(geo[k], k ? RTC_BUILD_QUALITY_REFIT : RTC_BUILD_QUALITY_HIGH);
        vb[k] = rtcSetNewGeometryBuffer(geo[k], RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 12,
                                        s->num_vertices);
        uint32_t *ib = rtcSetNewGeometryBuffer(geo[k], RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                               12, s->num_triangles);
        if (!vb[k] || !ib)
            return 1;
        for (size_t i = 0; i < 3 * (size_t)s->num_vertices; i++)
            vb[k][i] = s->positions[i];
        for (size_t i = 0; i < 3 * (size_t)s->num_triangles; i++)
            ib[i] = s->indices[i];
        rtcCommitGeometry(geo[k]);
        rtcAttachGeometry(sc[k], geo[k]);
        rtcCommitScene(sc[k]);
    }
    int rc = 0;
    for (int f = 0; f < frames && rc == 0; f++) {
        double t = t0 + f / 24.0;
        if (t > t1)
            t = t0 + (t1 - t0) * f / frames;
        /* A fresh load, then its accelerator. */
        double c0 = pt_now_s(), u0 = cpu_now();
        pt_scene *fresh = NULL;
        pt_accel *acc = NULL;
        o.time = t;
        if (pt_scene_load(argv[1], &o, &fresh, &err) != PT_OK ||
            pt_accel_new(fresh, &acc, &err) != PT_OK)
            rc = 1;
        reload[f] = pt_now_s() - c0;
        reload_cpu[f] = cpu_now() - u0;
        pt_accel_free(acc);
        pt_scene_free(fresh);
        acc = NULL;
        /* The re-pose, then its accelerator. */
        c0 = pt_now_s();
        u0 = cpu_now();
        if (pt_anim_pose(a, t, s, &err) != PT_OK)
            rc = 1;
        double c1 = pt_now_s();
        if (rc == 0 && pt_accel_new(s, &acc, &err) != PT_OK)
            rc = 1;
        repose[f] = pt_now_s() - c0;
        repose_cpu[f] = cpu_now() - u0;
        pose[f] = c1 - c0;
        pt_accel_free(acc);
        /* The kept scenes: pose into the vertex buffer, then commit. */
        for (int k = 0; k < 2 && rc == 0; k++) {
            pt_anim_pose_out out = {0};
            out.positions = vb[k];
            c0 = pt_now_s();
            if (pt_anim_pose_into(a, t, s, &out, &err) != PT_OK)
                rc = 1;
            rtcUpdateGeometryBuffer(geo[k], RTC_BUFFER_TYPE_VERTEX, 0);
            rtcCommitGeometry(geo[k]);
            rtcCommitScene(sc[k]);
            (k ? refit : rebuild)[f] = pt_now_s() - c0;
        }
    }
    for (int k = 0; k < 2; k++) {
        rtcReleaseGeometry(geo[k]);
        rtcReleaseScene(sc[k]);
    }
    rtcReleaseDevice(dev);
    if (rc) {
        fprintf(stderr, "ptbench-anim: %s\n", err.msg);
    } else {
        printf("%s: %u vertices, %u triangles, %d frames over [%g, %g] s\n", argv[1],
               s->num_vertices, s->num_triangles, frames, t0, t1);
        printf("median per frame: reload+BVH %.3f ms, re-pose+BVH %.3f ms, re-pose %.3f ms\n",
               1e3 * median(reload, frames), 1e3 * median(repose, frames),
               1e3 * median(pose, frames));
        printf("median cpu per frame: reload+BVH %.3f ms, re-pose+BVH %.3f ms\n",
               1e3 * median(reload_cpu, frames), 1e3 * median(repose_cpu, frames));
        printf("kept Embree scene: re-pose+rebuild %.3f ms, re-pose+refit %.3f ms\n",
               1e3 * median(rebuild, frames), 1e3 * median(refit, frames));
    }
    free(reload);
    free(repose);
    free(pose);
    free(rebuild);
    free(refit);
    free(reload_cpu);
    free(repose_cpu);
    pt_anim_free(a);
    pt_scene_free(s);
    return rc;
}
