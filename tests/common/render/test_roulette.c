/*
 * test_roulette.c - Russian roulette's survival rule against closed forms.
 *
 * A closed Lambertian sphere of albedo a = 0.98 emitting Le = 1 everywhere
 * (furnace.h, specular 0: a pure Lambert lobe, whose cosine-sampled weight is
 * a), rendered by BSDF sampling alone, so that every vertex adds Le x the
 * path's throughput. Russian roulette starts at the bounce into depth
 * rr_depth = 3 and lets a path survive with probability max(beta), at most
 * the cap (render.c's RR_MAX_SURVIVE), dividing beta by it. With a below the
 * cap a path's beta is a^3 there, becomes 1, and stays 1 (each later bounce
 * survives with probability a and is divided by a), so a sample is exactly
 *     X = 1 + a + a^2 + K,   P(K >= k) = a^3 a^(k-1) for k >= 1,
 * mean 1 / (1 - a) = 50 and variance a^3 (1 + a - a^3) / (1 - a)^2 = 2444.3
 * (K = B (1 + G), B Bernoulli(a^3), G geometric with P(G >= g) = a^g:
 * E[(1 + G)^2] = (1 + a) / (1 - a)^2). Checked:
 * - every sample is 1 + a + a^2 plus a whole number (a throughput of exactly
 *   1 after the roulette: with the old cap 0.95 it grew by 0.98 / 0.95 a
 *   bounce);
 * - the counts of K against that law, by chi-square (p > 1e-5);
 * - the mean within 5 standard errors of 50, and the samples' variance within
 *   5 standard errors of the closed form (the error of a sample variance,
 *   sqrt((mu4 - sigma^4) / n), with mu4 from the same law). With the cap at
 *   0.95 the second moment grows by a^2 / 0.95 > 1 a bounce: infinite; these
 *   65,536 samples then read 28x the closed form (and K's counts a chi2 of
 *   60,506 on 206 degrees of freedom, samples 7 % off whole numbers).
 */
#include <math.h>

#include "common/base/alloc.h"
#include "common/render/render.h"
#include "tests/check.h"
#include "tests/common/render/furnace.h"
#include "tests/stats.h"

#define ALBEDO 0.98
#define MAX_K 4096

/* The law of K: P(K = k) for k in [0, MAX_K). */
static void k_law(double *p)
{
    double a = ALBEDO, a3 = a * a * a;
    p[0] = 1.0 - a3;
    for (int k = 1; k < MAX_K; k++)
        p[k] = a3 * pow(a, k - 1) * (1.0 - a);
}

static void furnace_roulette(void)
{
    const float mrs[3] = {0.0f, 1.0f, 0.0f}; /* metallic, roughness, specular */
    pt_scene *s = flat_furnace_of((float)ALBEDO, 1.0f, mrs);
    CHECK(s != NULL);
    if (!s)
        return;
    const uint32_t W = 32, H = 32, SPP = 64;
    pt_render_params p;
    pt_render_params_default(&p);
    p.width = W;
    p.height = H;
    p.seed = 5;
    p.light_strategy = PT_LIGHT_BSDF_ONLY;
    pt_renderer *r = NULL;
    pt_error err = {0};
    CHECKF(pt_renderer_new(s, &p, &r, &err) == PT_OK, "%s", err.msg);
    double *law = pt_malloc_array(MAX_K, sizeof *law);
    double *obs = pt_calloc(MAX_K, sizeof *obs);
    double *expd = pt_malloc_array(MAX_K, sizeof *expd);
    CHECK(law && obs && expd);
    if (!r || !law || !obs || !expd)
        goto done;
    k_law(law);

    const double a = ALBEDO, head = 1.0 + a + a * a;
    double sum = 0.0, sum2 = 0.0, worst_frac = 0.0;
    uint64_t n = 0;
    for (uint32_t y = 0; y < H; y++)
        for (uint32_t x = 0; x < W; x++)
            for (uint32_t i = 0; i < SPP; i++) {
                pt_vec3 L = pt_render_sample(r, x, y, i, NULL, NULL);
                double v = L.x;
                sum += v;
                sum2 += v * v;
                n++;
                double k = v - head, kr = floor(k + 0.5);
                /* Float sums of up to a few hundred terms near 1. */
                double frac = fabs(k - kr) / (1.0 + kr);
                if (frac > worst_frac)
                    worst_frac = frac;
                if (kr >= 0.0 && kr < MAX_K)
                    obs[(int)kr] += 1.0;
            }
    CHECKF(worst_frac < 1e-5,
           "a sample is 1 + a + a^2 + K with K off a whole number by %.3g of K + 1: the "
           "throughput after the roulette is not 1",
           worst_frac);

    for (int k = 0; k < MAX_K; k++)
        expd[k] = law[k] * (double)n;
    double chi2;
    int dof;
    double pv = stats_chi2_gof(obs, expd, MAX_K, 20.0, &chi2, &dof);
    CHECKF(pv > 1e-5, "path lengths against the geometric law: chi2 %.1f, %d dof, p %.3g", chi2,
           dof, pv);

    /* Moments of X = head + K from the law. */
    double m1 = 0.0, m2 = 0.0;
    for (int k = 0; k < MAX_K; k++)
        m1 += law[k] * (head + k);
    for (int k = 0; k < MAX_K; k++)
        m2 += law[k] * (head + k - m1) * (head + k - m1);
    double m4 = 0.0;
    for (int k = 0; k < MAX_K; k++) {
        double d = head + k - m1;
        m4 += law[k] * d * d * d * d;
    }
    double var_closed = a * a * a * (1.0 + a - a * a * a) / ((1.0 - a) * (1.0 - a));
    CHECKF(fabs(m2 - var_closed) < 1e-6 * var_closed, "the law's variance %.6g, closed form %.6g",
           m2, var_closed);
    CHECKF(fabs(m1 - 1.0 / (1.0 - a)) < 1e-9, "the law's mean %.9g", m1);

    double mean = sum / (double)n;
    double var = (sum2 - sum * sum / (double)n) / (double)(n - 1);
    double se_mean = sqrt(var_closed / (double)n);
    double se_var = sqrt((m4 - m2 * m2) / (double)n);
    printf("albedo %.2f, %llu samples: mean %.4f (exact %.4f, se %.3f), variance %.1f (closed "
           "form %.1f, se %.1f), chi2 %.1f with %d dof (p %.3g)\n",
           a, (unsigned long long)n, mean, 1.0 / (1.0 - a), se_mean, var, var_closed, se_var, chi2,
           dof, pv);
    CHECKF(fabs(mean - 1.0 / (1.0 - a)) < 5.0 * se_mean, "mean %.4f, exact %.4f, se %.4f", mean,
           1.0 / (1.0 - a), se_mean);
    CHECKF(fabs(var - var_closed) < 5.0 * se_var, "variance %.2f, closed form %.2f, se %.2f", var,
           var_closed, se_var);
done:
    pt_free(law);
    pt_free(obs);
    pt_free(expd);
    pt_renderer_free(r);
    pt_scene_free(s);
}

int main(void)
{
    furnace_roulette();
    return check_report();
}
