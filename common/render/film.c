#include "common/render/film.h"

#include <assert.h>
#include <math.h>

#include "common/base/alloc.h"

pt_status pt_film_new(uint32_t width, uint32_t height, pt_film **out, pt_error *err)
{
    /* The image's caps: a film is always resolved into an image. */
    pt_status st = pt_image_check_size("film", width, height, err);
    if (st != PT_OK)
        return st;
    uint64_t pixels = (uint64_t)width * height;
    pt_film *film = pt_malloc(sizeof *film);
    pt_pixel_acc *px = pt_calloc((size_t)pixels, sizeof *px);
    if (!film || !px) {
        pt_free(px);
        pt_free(film);
        return pt_error_set(err, PT_ERR_NOMEM, "film %ux%u: out of memory", width, height);
    }
    film->width = width;
    film->height = height;
    film->px = px;
    *out = film;
    return PT_OK;
}

void pt_film_free(pt_film *film)
{
    if (film) {
        pt_free(film->px);
        pt_free(film);
    }
}

void pt_film_add_tile(pt_film *film, pt_rect tile, const pt_pixel_acc *acc)
{
    assert(tile.x0 <= tile.x1 && tile.x1 <= film->width);
    assert(tile.y0 <= tile.y1 && tile.y1 <= film->height);
    uint32_t tw = tile.x1 - tile.x0;
    for (uint32_t y = tile.y0; y < tile.y1; y++) {
        pt_pixel_acc *row = film->px + (size_t)y * film->width + tile.x0;
        const pt_pixel_acc *src = acc + (size_t)(y - tile.y0) * tw;
        for (uint32_t x = 0; x < tw; x++)
            pt_pixel_acc_add(&row[x], &src[x]);
    }
}

/*
 * The variance of the mean of n samples of luminance L is s^2 / n with the
 * unbiased sample variance s^2 = (sum L^2 - n mean_L^2) / (n - 1). mean_L is
 * the luminance of the mean RGB (Rec.709 weights), which equals the mean of
 * the luminances because luminance is linear. The one-pass form cancels
 * catastrophically when the variance is tiny against the mean, so it is
 * computed in double and clamped at 0 (which also maps NaN to 0).
 */
void pt_film_resolve(const pt_film *film, pt_image *img)
{
    assert(film->width == img->width && film->height == img->height);
    size_t n_px = (size_t)film->width * film->height;
    for (size_t i = 0; i < n_px; i++) {
        const pt_pixel_acc *a = &film->px[i];
        if (a->n == 0) {
            img->r[i] = img->g[i] = img->b[i] = 0.0f;
            img->samples[i] = 0.0f;
            img->variance[i] = 0.0f;
            img->a[i] = 0.0f;
            continue;
        }
        double n = (double)a->n;
        double r = pt_acc_sum(a, 0) / n, g = pt_acc_sum(a, 1) / n, b = pt_acc_sum(a, 2) / n;
        double var = 0.0;
        if (a->n >= 2) {
            double lum = 0.2126 * r + 0.7152 * g + 0.0722 * b;
            var = (pt_acc_sum_sq(a) - n * lum * lum) / (n - 1.0) / n;
            if (!(var > 0.0))
                var = 0.0;
        }
        img->r[i] = (float)r;
        img->g[i] = (float)g;
        img->b[i] = (float)b;
        img->samples[i] = (float)a->n;
        img->variance[i] = (float)var;
        img->a[i] = (float)((double)a->hits / n);
    }
}

uint64_t pt_film_total_samples(const pt_film *film)
{
    uint64_t total = 0;
    size_t n_px = (size_t)film->width * film->height;
    for (size_t i = 0; i < n_px; i++)
        total += film->px[i].n;
    return total;
}
