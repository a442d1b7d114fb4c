/*
 * test_ptworker.c - the standalone `ptworker --scene` command, as a user runs it.
 *
 * Real process, real files: usage errors exit 2, a missing or broken scene
 * exits 1 naming the file, a render writes a valid EXR and PNG, and the
 * pixels (R, G, B, samples) are bit-identical for 1 and 2 threads.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "common/base/fsutil.h"
#include "common/image/exr.h"
#include "common/image/image.h"
#include "tests/check.h"

static char tmpdir[256];

/* Runs a shell command line; returns its exit status, stderr captured to err.txt. */
static int run(const char *args)
{
    char cmd[8192];
    snprintf(cmd, sizeof cmd, "%s/ptworker %s 2>%s/err.txt >%s/out.txt", PT_BIN_DIR, args, tmpdir,
             tmpdir);
    int st = system(cmd);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static int stderr_has(const char *needle)
{
    char path[512], buf[8192];
    snprintf(path, sizeof path, "%s/err.txt", tmpdir);
    FILE *f = fopen(path, "r");
    if (!f)
        return 0;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    return strstr(buf, needle) != NULL;
}

static pt_image *read_exr(const char *name, pt_exr_meta *meta)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", tmpdir, name);
    pt_image *img = NULL;
    pt_error err = {0};
    if (pt_exr_read(path, &img, meta, &err) != PT_OK)
        fprintf(stderr, "%s\n", err.msg);
    return img;
}

/* The bytes of tmpdir/name, malloc'd and NUL-terminated, their count in
 * *len; NULL if unread. */
static unsigned char *slurp(const char *name, size_t *len)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", tmpdir, name);
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    unsigned char *buf = malloc((1 << 20) + 1);
    *len = buf ? fread(buf, 1, 1 << 20, f) : 0;
    if (buf)
        buf[*len] = 0;
    fclose(f);
    return buf;
}

static int same_pixels(const pt_image *a, const pt_image *b)
{
    size_t n = (size_t)a->width * a->height * sizeof(float);
    return a->width == b->width && a->height == b->height && !memcmp(a->r, b->r, n) &&
           !memcmp(a->g, b->g, n) && !memcmp(a->b, b->b, n) && !memcmp(a->samples, b->samples, n);
}

int main(void)
{
    snprintf(tmpdir, sizeof tmpdir, "/tmp/pt_test_ptworker_XXXXXX");
    if (!mkdtemp(tmpdir)) {
        perror("mkdtemp");
        return 1;
    }
    char args[4096];
    const char *cornell = PT_SOURCE_DIR "/scenes/cornell_box.gltf";

    CHECK(run("--help") == 0);
    CHECK(run("") == 2);
    CHECK(run("--scene x.gltf") == 2);
    CHECK(run("--scene x.gltf -o y.exr --spp 0") == 2 && stderr_has("--spp"));
    CHECK(run("--scene x.gltf -o y.exr --res 12by4") == 2 && stderr_has("--res"));
    CHECK(run("--scene x.gltf -o y.exr --bogus") == 2);
    CHECK(run("--scene x.gltf -o y.exr --min-gain 0") == 2 && stderr_has("--min-gain"));
    CHECK(run("--scene x.gltf -o y.exr --min-gain nan") == 2 && stderr_has("--min-gain"));
    CHECK(run("--scene x.gltf -o y.exr --min-gain 1e-999") == 2 && stderr_has("--min-gain"));
    CHECK(run("--scene x.gltf -o y.exr --target-error 0.1 --min-gain 1e-6") == 2 &&
          stderr_has("two adaptive rules"));
    CHECK(run("--server 127.0.0.1:1 --min-gain 1e-6") == 2 && stderr_has("standalone option"));

    snprintf(args, sizeof args, "--scene %s/missing.gltf -o %s/m.exr", tmpdir, tmpdir);
    CHECK(run(args) == 1 && stderr_has("missing.gltf"));
    char broken[512];
    snprintf(broken, sizeof broken, "%s/broken.gltf", tmpdir);
    FILE *f = fopen(broken, "w");
    fputs("{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [", f);
    fclose(f);
    snprintf(args, sizeof args, "--scene %s -o %s/b.exr", broken, tmpdir);
    CHECK(run(args) == 1 && stderr_has("broken.gltf"));

    snprintf(args, sizeof args, "--scene %s -o %s/out/none.exr --res 8x8 --spp 1 -q", cornell,
             tmpdir);
    CHECKF(run(args) == 1 && stderr_has("none.exr"), "unwritable output must fail, naming it");

    snprintf(args, sizeof args, "--scene %s -o %s/t1.exr --res 40x30 --spp 8 --threads 1 --tile 16",
             cornell, tmpdir);
    CHECK(run(args) == 0);
    CHECK(stderr_has("samples/s") && stderr_has("rejected"));
    snprintf(args, sizeof args, "--scene %s -o %s/t2.exr --res 40x30 --spp 8 --threads 2 --tile 16",
             cornell, tmpdir);
    CHECK(run(args) == 0);
    pt_exr_meta m1, m2;
    pt_image *a = read_exr("t1.exr", &m1), *b = read_exr("t2.exr", &m2);
    CHECK(a && b);
    if (a && b) {
        CHECK(a->width == 40 && a->height == 30);
        CHECKF(same_pixels(a, b), "1 and 2 threads differ");
        CHECK(m1.total_samples == 40 * 30 * 8);
        CHECK(strlen(m1.scene_hash) == 64);
        CHECK(strstr(m1.software, "ptfarm") != NULL);
        int lit = 0;
        for (uint32_t i = 0; i < 40 * 30; i++)
            lit += a->r[i] > 0.0f && a->samples[i] == 8.0f;
        CHECK(lit > 40 * 30 / 2);
    }
    pt_image_free(a);
    pt_image_free(b);

    /* --guiding: bad values; not with adaptive sampling; a Lambert scene
     * has nothing to guide and keeps its image; a glossy one renders every
     * pass, the same bits on 1 and 2 threads (the passes' statistics merge
     * exactly, so both build the same guides). */
    CHECK(run("--scene x.gltf -o y.exr --guiding maybe") == 2 && stderr_has("--guiding"));
    snprintf(args, sizeof args,
             "--scene %s -o %s/g0.exr --res 8x8 --spp 8 --guiding on --target-error 0.1", cornell,
             tmpdir);
    CHECK(run(args) == 2 && stderr_has("--guiding"));
    snprintf(args, sizeof args,
             "--scene %s -o %s/g1.exr --res 40x30 --spp 8 --threads 1 --tile 16 --guiding on",
             cornell, tmpdir);
    CHECK(run(args) == 0 && stderr_has("nothing to guide"));
    a = read_exr("t1.exr", &m1);
    b = read_exr("g1.exr", &m2);
    CHECKF(a && b && same_pixels(a, b), "--guiding on changed a Lambert scene's image");
    pt_image_free(b);
    /* auto: off for the Lambert box (the same bits), and off, not refused,
     * with adaptive sampling. */
    snprintf(args, sizeof args,
             "--scene %s -o %s/g2.exr --res 40x30 --spp 8 --threads 1 --tile 16 --guiding auto",
             cornell, tmpdir);
    CHECK(run(args) == 0 && stderr_has("auto: off"));
    b = read_exr("g2.exr", &m2);
    CHECKF(a && b && same_pixels(a, b), "--guiding auto changed a Lambert scene's image");
    snprintf(args, sizeof args,
             "--scene %s -o %s/g3.exr --res 8x8 --spp 8 --guiding auto --target-error 0.1", cornell,
             tmpdir);
    CHECK(run(args) == 0);
    pt_image_free(a);
    pt_image_free(b);
    const char *spheres =
        PT_SHARED_SCENES "/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.glb";
    if (access(spheres, R_OK) == 0) {
        for (int t = 1; t <= 2; t++) {
            snprintf(
                args, sizeof args,
                "--scene %s -o %s/gs%d.exr --res 32x24 --spp 48 --threads %d --background 1,1,1 "
                "--guiding on -q",
                spheres, tmpdir, t, t);
            CHECK(run(args) == 0);
        }
        a = read_exr("gs1.exr", &m1);
        b = read_exr("gs2.exr", &m2);
        CHECK(a && b && m1.total_samples == 32 * 24 * 48);
        CHECKF(a && b && same_pixels(a, b), "guided renders on 1 and 2 threads differ");
        pt_image_free(a);
        pt_image_free(b);
    } else {
        CHECK_SKIP("shared scenes not found; the guided render");
        CHECK(!check_shared_required());
    }
    /* What would fail at the end fails at the start, before the scene is
     * loaded (no "N triangles" line): a missing output folder, a missing
     * map, a name of no known format (2: bad usage). A .png output is a
     * PNG, alone. */
    snprintf(args, sizeof args, "--scene %s -o %s/out/none.exr --res 8x8 --spp 1", cornell, tmpdir);
    CHECK(run(args) == 1 && stderr_has("cannot be written") && !stderr_has("triangles"));
    snprintf(args, sizeof args, "--scene %s -o %s/e.exr --env %s/missing.hdr --res 8x8", cornell,
             tmpdir, tmpdir);
    CHECK(run(args) == 1 && stderr_has("missing.hdr") && !stderr_has("triangles"));
    snprintf(args, sizeof args, "--scene %s -o %s/x.jpg --res 8x8 --spp 1", cornell, tmpdir);
    CHECK(run(args) == 2 && stderr_has(".exr") && stderr_has(".png") && !stderr_has("triangles"));
    snprintf(args, sizeof args, "--scene %s -o %s/p.PNG --res 8x8 --spp 1 -q", cornell, tmpdir);
    CHECK(run(args) == 0);
    char png_path[512];
    snprintf(png_path, sizeof png_path, "%s/p.PNG", tmpdir);
    FILE *pf = fopen(png_path, "rb");
    unsigned char magic[8] = {0};
    CHECK(pf && fread(magic, 1, 8, pf) == 8 && memcmp(magic, "\x89PNG\r\n\x1a\n", 8) == 0);
    if (pf)
        fclose(pf);
    snprintf(png_path, sizeof png_path, "%s/p.PNG.png", tmpdir);
    CHECK(access(png_path, F_OK) != 0);
    /* A folder named as the scene: the scene files in it, not "Input/output
     * error"; a FIFO named as the scene is refused, not waited on. */
    snprintf(args, sizeof args, "--scene %s/scenes -o %s/d.exr --res 8x8 --spp 1", PT_SOURCE_DIR,
             tmpdir);
    CHECK(run(args) == 1 && stderr_has("a folder; give the scene file in it") &&
          stderr_has("cornell_box.gltf"));
    char fifo[512];
    snprintf(fifo, sizeof fifo, "%s/pipe.gltf", tmpdir);
    CHECK(mkfifo(fifo, 0600) == 0);
    snprintf(args, sizeof args, "--scene %s -o %s/d.exr --res 8x8 --spp 1", fifo, tmpdir);
    CHECK(run(args) == 1 && stderr_has("not a regular file"));
    unlink(fifo);
    /* The environment options: bad maps and mixes refused with the reason. */
    snprintf(args, sizeof args, "--scene %s -o %s/e.exr --env %s/missing.hdr", cornell, tmpdir,
             tmpdir);
    CHECK(run(args) == 1 && stderr_has("--env") && stderr_has("missing.hdr"));
    snprintf(args, sizeof args, "--scene %s -o %s/e.exr --env %s", cornell, tmpdir, broken);
    CHECK(run(args) == 1 && stderr_has("not an environment map"));
    snprintf(args, sizeof args, "--scene %s -o %s/e.exr --env %s --background 1,1,1", cornell,
             tmpdir, broken);
    CHECK(run(args) == 2 && stderr_has("give one"));
    CHECK(run("--scene x.gltf -o y.exr --background 1,2") == 2 && stderr_has("R,G,B"));
    CHECK(run("--scene x.gltf -o y.exr --background 1,2,nan") == 2 && stderr_has("R,G,B"));
    CHECK(run("--scene x.gltf -o y.exr --env-strength -1") == 2 && stderr_has("--env-strength"));
    CHECK(run("--server 127.0.0.1:1 --env x.hdr") == 2 && stderr_has("standalone option"));
    /* Motion blur's shutter: refused unless 0 <= open <= close <= 1, and a
     * standalone option; on a scene where nothing moves it renders the
     * still, bit for bit. */
    CHECK(run("--scene x.gltf -o y.exr --shutter 0.5") == 2 && stderr_has("OPEN,CLOSE"));
    CHECK(run("--scene x.gltf -o y.exr --shutter 0,0.5,1") == 2 && stderr_has("OPEN,CLOSE"));
    CHECK(run("--scene x.gltf -o y.exr --shutter 0.6,0.4") == 2 && stderr_has("after it closes"));
    CHECK(run("--scene x.gltf -o y.exr --shutter 0,2") == 2 && stderr_has("[0, 1]"));
    CHECK(run("--scene x.gltf -o y.exr --shutter -1,0") == 2 && stderr_has("[0, 1]"));
    CHECK(run("--scene x.gltf -o y.exr --shutter 0,0.5 --fps 0") == 2 && stderr_has("--fps"));
    CHECK(run("--server 127.0.0.1:1 --shutter 0,0.5") == 2 && stderr_has("standalone option"));
    for (int k = 0; k < 2; k++) {
        snprintf(args, sizeof args, "--scene %s -o %s/still%d.exr --res 24x24 --spp 4 -q%s",
                 cornell, tmpdir, k, k ? " --shutter 0,0.5" : "");
        CHECK(run(args) == 0);
    }
    pt_image *st0 = read_exr("still0.exr", NULL), *st1 = read_exr("still1.exr", NULL);
    CHECK(st0 && st1 && same_pixels(st0, st1));
    pt_image_free(st0);
    pt_image_free(st1);
    /* A scene with no light is refused with the way to light it, and
     * renders with a background. */
    char dark[512];
    snprintf(dark, sizeof dark, "%s/dark.gltf", tmpdir);
    f = fopen(dark, "w");
    fputs("{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
          "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":"
          "{\"POSITION\":0}}]}],\"accessors\":[{\"bufferView\":0,\"componentType\":5126,"
          "\"count\":3,\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,1,0]}],"
          "\"bufferViews\":[{\"buffer\":0,\"byteLength\":36}],\"buffers\":[{\"byteLength\":36,"
          "\"uri\":\"data:application/octet-stream;base64,"
          "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA\"}]}",
          f);
    fclose(f);
    snprintf(args, sizeof args, "--scene %s -o %s/dark.exr --res 8x8 --spp 1 -q", dark, tmpdir);
    CHECK(run(args) == 1 && stderr_has("has no light") && stderr_has("--env"));
    snprintf(args, sizeof args, "--scene %s -o %s/dark.exr --res 8x8 --spp 1 -q --background 1,1,1",
             dark, tmpdir);
    CHECK(run(args) == 0);
    /* A uniform sky through the box's open side: brighter, the same bits on
     * one thread and two. */
    for (int t = 1; t <= 2; t++) {
        snprintf(args, sizeof args,
                 "--scene %s -o %s/sky%d.exr --res 40x30 --spp 8 --threads %d --tile 16 "
                 "--background 0.5,0.6,0.7",
                 cornell, tmpdir, t, t);
        CHECK(run(args) == 0);
    }
    pt_image *s1 = read_exr("sky1.exr", NULL), *s2 = read_exr("sky2.exr", NULL),
             *t1 = read_exr("t1.exr", NULL);
    CHECK(s1 && s2 && t1);
    if (s1 && s2 && t1) {
        CHECKF(same_pixels(s1, s2), "1 and 2 threads differ under a background");
        double with = 0, without = 0;
        for (uint32_t i = 0; i < 40 * 30; i++) {
            with += s1->b[i];
            without += t1->b[i];
        }
        CHECKF(with > without * 1.01, "the background adds no light: %g vs %g", with, without);
    }
    pt_image_free(s1);
    pt_image_free(s2);
    pt_image_free(t1);

    char png[512];
    snprintf(png, sizeof png, "%s/t1.png", tmpdir);
    struct stat sb;
    CHECK(stat(png, &sb) == 0 && sb.st_size > 100);

    /* --list: what the scene offers the options, on stdout; nothing rendered. */
    snprintf(args, sizeof args, "--list %s", cornell);
    CHECK(run(args) == 0);
    size_t lo = 0;
    unsigned char *listed = slurp("out.txt", &lo);
    CHECKF(listed && strstr((char *)listed, "cameras (1)") &&
               strstr((char *)listed, "0 'Camera'") &&
               strstr((char *)listed, "KHR_materials_emissive_strength") &&
               strstr((char *)listed, "animations (0)"),
           "--list: %s", listed ? (char *)listed : "");
    free(listed);
    snprintf(args, sizeof args, "--list %s/missing.gltf", tmpdir);
    CHECK(run(args) == 1 && stderr_has("missing.gltf"));

    /* The view transform and exposure change the PNG only: the EXR is the
     * same bits, the preview is not; a bad view or exposure is bad usage. */
    CHECK(run("--scene x.gltf -o y.exr --view aces") == 2 && stderr_has("standard, filmic or agx"));
    CHECK(run("--scene x.gltf -o y.exr --exposure 21") == 2 && stderr_has("--exposure"));
    CHECK(run("--scene x.gltf -o y.exr --exposure 1e") == 2 && stderr_has("--exposure"));
    CHECK(run("--server 127.0.0.1:1 --view agx") == 2 && stderr_has("standalone option"));
    snprintf(args, sizeof args,
             "--scene %s -o %s/v1.exr --res 40x30 --spp 8 --threads 1 --tile 16 --view agx "
             "--exposure 1 -q",
             cornell, tmpdir);
    CHECK(run(args) == 0);
    a = read_exr("t1.exr", NULL);
    b = read_exr("v1.exr", NULL);
    CHECKF(a && b && same_pixels(a, b), "--view changed the EXR");
    pt_image_free(a);
    pt_image_free(b);
    size_t la = 0, lb = 0;
    unsigned char *pa = slurp("t1.png", &la), *pb = slurp("v1.png", &lb);
    CHECKF(pa && pb && (la != lb || memcmp(pa, pb, la) != 0), "--view agx left the PNG as it was");
    free(pa);
    free(pb);
    /* --transparent: an RGBA PNG (IHDR colour type 6 at byte 25), as the
     * output and as the EXR's preview; without it RGB (type 2). */
    snprintf(args, sizeof args,
             "--scene %s -o %s/tro.png --res 16x12 --spp 2 -q --transparent --background 1,1,1",
             cornell, tmpdir);
    CHECK(run(args) == 0);
    snprintf(args, sizeof args,
             "--scene %s -o %s/tr.exr --res 16x12 --spp 2 -q --transparent --background 1,1,1",
             cornell, tmpdir);
    CHECK(run(args) == 0);
    const char *rgba[2] = {"tro.png", "tr.png"}; /* the output, the EXR's preview */
    for (int k = 0; k < 2; k++) {
        pa = slurp(rgba[k], &la);
        CHECKF(pa && la > 26 && pa[25] == 6, "%s: colour type %d", rgba[k],
               pa && la > 26 ? pa[25] : -1);
        free(pa);
    }
    pb = slurp("t1.png", &lb);
    CHECK(pb && lb > 26 && pb[25] == 2);
    free(pb);

    if (pt_remove_tree(tmpdir) != 0)
        fprintf(stderr, "could not remove %s\n", tmpdir);
    return check_report();
}
