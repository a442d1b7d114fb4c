/*
 * ortho.h - the tests' camera straight down: orthographic, at (x, y, height)
 * looking along -z with +x to the right and +y up, a square view half_width
 * across from its centre, named "cam". The renderer tests that build a
 * plane lit from above read it pixel by pixel through this view.
 */
#ifndef PT_TESTS_COMMON_RENDER_ORTHO_H
#define PT_TESTS_COMMON_RENDER_ORTHO_H

#include <stdio.h>

#include "common/scene/scene.h"

static inline pt_camera pt_test_ortho_down(float x, float y, float height, float half_width)
{
    pt_camera cam = {0};
    cam.position = pt_v3(x, y, height);
    cam.forward = pt_v3(0, 0, -1);
    cam.right = pt_v3(1, 0, 0);
    cam.up = pt_v3(0, 1, 0);
    cam.ortho = 1;
    cam.xmag = cam.ymag = half_width;
    cam.aspect = 1.0f;
    snprintf(cam.name, sizeof cam.name, "cam");
    return cam;
}

#endif
