/*
 * fuzz_camera_look.c - libFuzzer target for the camera placement text
 * (pt_camera_look_parse, common/scene/scene.c): "look:X,Y,Z:X,Y,Z[:fov=D|
 * :ortho=W]", which a client's job carries in its camera field to the
 * coordinator and every worker.
 *
 * Input: the text's bytes (cut at the first NUL and at 256 bytes, as a
 * job's field is shorter still). Invariants: a refusal is PT_ERR_ARG with a
 * message; a camera read has a finite position, unit orthonormal axes
 * looking along forward, and either a field of view in (0, pi) or an
 * orthographic width > 0; the same text reads the same bits twice; the
 * text pt_camera_look_text makes of finite numbers reads back. Seeds
 * (corpus/fuzz_camera_look/): a perspective and an orthographic
 * placement, one looking straight down, and three refused, committed as
 * written.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "common/scene/scene.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int unit(pt_vec3 v)
{
    return fabsf(pt_v3_len(v) - 1.0f) < 1e-3f;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char text[257];
    size_t n = size < 256 ? size : 256;
    memcpy(text, data, n);
    text[n] = '\0';
    pt_camera c, again;
    pt_error err = {0};
    pt_status st = pt_camera_look_parse(text, &c, &err);
    fuzz_note("look", st, &err);
    FUZZ_CHECK(st == PT_OK || (st == PT_ERR_ARG && err.msg[0]));
    if (st != PT_OK)
        return 0;
    FUZZ_CHECK(isfinite(c.position.x) && isfinite(c.position.y) && isfinite(c.position.z));
    FUZZ_CHECK(unit(c.forward) && unit(c.right) && unit(c.up));
    FUZZ_CHECK(fabsf(pt_v3_dot(c.forward, c.right)) < 1e-3f &&
               fabsf(pt_v3_dot(c.forward, c.up)) < 1e-3f &&
               fabsf(pt_v3_dot(c.right, c.up)) < 1e-3f);
    FUZZ_CHECK(c.ortho ? c.xmag > 0.0f && c.yfov == 0.0f
                       : c.yfov > 0.0f && c.yfov < 3.1416f && !c.framed);
    FUZZ_CHECK(pt_camera_look_parse(text, &again, &err) == PT_OK &&
               memcmp(&c, &again, sizeof c) == 0);
    /* Its numbers written again as a placement read back. */
    double from[3] = {c.position.x, c.position.y, c.position.z};
    double at[3] = {c.position.x + c.forward.x, c.position.y + c.forward.y,
                    c.position.z + c.forward.z};
    char out[256];
    if (pt_camera_look_text(from, at, c.ortho ? 0.0 : c.yfov * 180.0 / 3.14159265358979,
                            c.ortho ? 2.0 * c.xmag : 0.0, out, sizeof out, &err) == PT_OK)
        FUZZ_CHECK(pt_camera_look_parse(out, &again, &err) == PT_OK);
    return 0;
}
