/* Tests for common/image/image.c: the size caps that the image, the film and
 * the EXR reader share, at their boundaries, and that pt_image_new and
 * pt_film_new apply them alike; the preview's name beside an EXR. */
#include "common/image/image.h"

#include <string.h>

#include "common/base/alloc.h"
#include "common/render/film.h"
#include "tests/check.h"

static void test_check_size(void)
{
    pt_error err = {0};
    CHECK(pt_image_check_size("image", 1, 1, &err) == PT_OK);
    CHECK(pt_image_check_size("image", PT_IMAGE_MAX_SIDE, PT_IMAGE_MAX_PIXELS / PT_IMAGE_MAX_SIDE,
                              &err) == PT_OK);
    CHECK(pt_image_check_size("image", 16384, 16384, &err) == PT_OK); /* exactly the pixel cap */
    CHECK(pt_image_check_size("image", 0, 5, &err) == PT_ERR_ARG);
    CHECKF(!strcmp(err.msg, "image size 0x5: both sides must be > 0"), "%s", err.msg);
    CHECK(pt_image_check_size("film", 5, 0, &err) == PT_ERR_ARG && !strncmp(err.msg, "film", 4));
    CHECK(pt_image_check_size("image", PT_IMAGE_MAX_SIDE + 1, 1, &err) == PT_ERR_LIMIT);
    CHECK(pt_image_check_size("image", 1, PT_IMAGE_MAX_SIDE + 1, &err) == PT_ERR_LIMIT);
    CHECK(pt_image_check_size("image", 16384, 16385, &err) == PT_ERR_LIMIT);
    CHECK(pt_image_check_size("image", UINT32_MAX, UINT32_MAX, &err) == PT_ERR_LIMIT);
    CHECKF(strstr(err.msg, "is over the cap (65536 per side, 268435456 pixels)") != NULL, "%s",
           err.msg);
    CHECK(pt_image_check_size("image", 1, 1, NULL) == PT_OK);
    CHECK(pt_image_check_size("image", 0, 1, NULL) == PT_ERR_ARG);
}

static void test_new_applies_it(void)
{
    pt_error err = {0};
    int64_t live = pt_alloc_live();
    pt_image *img = NULL;
    pt_film *film = NULL;
    CHECK(pt_image_new(0, 4, &img, &err) == PT_ERR_ARG && !img);
    CHECK(pt_film_new(0, 4, &film, &err) == PT_ERR_ARG && !film);
    CHECK(pt_image_new(16384, 16385, &img, &err) == PT_ERR_LIMIT && !img);
    CHECK(pt_film_new(16384, 16385, &film, &err) == PT_ERR_LIMIT && !film);
    CHECK(strncmp(err.msg, "film size", 9) == 0);
    CHECK(pt_image_new(3, 2, &img, &err) == PT_OK && img && img->width == 3);
    CHECK(pt_film_new(3, 2, &film, &err) == PT_OK && film);
    pt_image_free(img);
    pt_film_free(film);
    CHECK(pt_alloc_live() == live);
}

static void preview_is(const char *exr, const char *want)
{
    char out[64];
    pt_png_preview_path(exr, out, sizeof out);
    CHECKF(!strcmp(out, want), "'%s': '%s', want '%s'", exr, out, want);
}

static void test_preview_path(void)
{
    preview_is("out.exr", "out.png");
    preview_is("dir/x.y.exr", "dir/x.y.png");
    preview_is(".exr", ".exr.png"); /* no name before the extension */
    preview_is("a.exr", "a.png");
    preview_is("out.EXR", "out.EXR.png");
    preview_is("out", "out.png");
    preview_is("out.exr.bak", "out.exr.bak.png");
    char small[6];
    pt_png_preview_path("image.exr", small, sizeof small);
    CHECK(!strcmp(small, "image"));
}

int main(void)
{
    test_preview_path();
    test_check_size();
    test_new_applies_it();
    return check_report();
}
