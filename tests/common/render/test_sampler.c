/*
 * test_sampler.c - the Owen-scrambled Sobol sampler: range, determinism,
 * the direction numbers, (0,2)-sequence stratification of 2D pairs before
 * and after scrambling, convergence faster than Monte Carlo, decorrelation
 * of padded dimensions.
 */
#include "common/render/sampler.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "tests/check.h"

/* Direction vectors (most significant bit first) from Joe & Kuo's constants:
 * degree s, interior polynomial coefficients a (a_1 is the high bit), and
 * initial m_1..m_s; m_k = 2 a_1 m_{k-1} ^ ... ^ 2^{s-1} a_{s-1} m_{k-s+1} ^
 * 2^s m_{k-s} ^ m_{k-s}, V_k = m_k << (32 - k). */
static void joe_kuo_dirs(int s, uint32_t a, const uint32_t *m_init, uint32_t v[32])
{
    uint32_t m[32];
    for (int k = 0; k < s; k++)
        m[k] = m_init[k];
    for (int k = s; k < 32; k++) {
        uint32_t x = m[k - s] ^ (m[k - s] << s);
        for (int j = 1; j < s; j++)
            if ((a >> (s - 1 - j)) & 1u)
                x ^= m[k - j] << j;
        m[k] = x;
    }
    for (int k = 0; k < 32; k++)
        v[k] = m[k] << (31 - k);
}

static void test_direction_numbers(void)
{
    static const uint32_t m1[] = {1}, m2[] = {1, 3}, m3[] = {1, 3, 1};
    uint32_t v[4][32];
    for (int k = 0; k < 32; k++)
        v[0][k] = 1u << (31 - k);
    joe_kuo_dirs(1, 0, m1, v[1]);
    joe_kuo_dirs(2, 1, m2, v[2]);
    joe_kuo_dirs(3, 1, m3, v[3]);
    int bad = 0;
    for (uint32_t d = 0; d < 4; d++)
        for (int k = 0; k < 32; k++)
            bad += pt_sobol_bits(1u << k, d) != v[d][k];
    CHECKF(bad == 0, "%d direction vectors differ from Joe & Kuo's", bad);
    /* Linearity: the value of an index is the XOR of its bits' vectors. */
    bad = 0;
    for (uint32_t d = 0; d < 4; d++)
        for (uint32_t i = 0; i < 5000; i++) {
            uint32_t idx = i * 2654435761u, x = 0;
            for (int k = 0; k < 32; k++)
                if ((idx >> k) & 1u)
                    x ^= v[d][k];
            bad += pt_sobol_bits(idx, d) != x;
        }
    CHECK(bad == 0);
}

/* 1D stratification of the first N = 2^k unscrambled points of each dim. */
static void test_unscrambled_strata(void)
{
    static unsigned char hit[1 << 12];
    int bad = 0;
    for (uint32_t d = 0; d < 4; d++)
        for (int k = 0; k <= 12; k++) {
            uint32_t n = 1u << k;
            memset(hit, 0, n);
            for (uint32_t i = 0; i < n; i++) {
                uint32_t cell = k ? pt_sobol_bits(i, d) >> (32 - k) : 0;
                hit[cell]++;
            }
            for (uint32_t c = 0; c < n; c++)
                bad += hit[c] != 1;
        }
    CHECKF(bad == 0, "%d 1D strata of unscrambled Sobol not hit exactly once", bad);
    /* Sobol dims (0, 1) unscrambled are a (0,2)-sequence (the first 4096). */
    static unsigned short cnt[1 << 12];
    bad = 0;
    for (int m = 1; m <= 12; m++)
        for (int a = 0; a <= m; a++) {
            memset(cnt, 0, sizeof cnt);
            for (uint32_t i = 0; i < (1u << m); i++) {
                uint32_t x = a ? pt_sobol_bits(i, 0) >> (32 - a) : 0;
                uint32_t y = m - a ? pt_sobol_bits(i, 1) >> (32 - (m - a)) : 0;
                cnt[(x << (m - a)) | y]++;
            }
            for (uint32_t c = 0; c < (1u << m); c++)
                bad += cnt[c] != 1;
        }
    CHECKF(bad == 0, "%d elementary intervals of Sobol (0,1) miss", bad);
}

static void test_range_and_determinism(void)
{
    int out = 0, mismatch = 0, equal = 0, n = 0;
    for (uint32_t seed = 0; seed < 16; seed++) {
        uint32_t ps = pt_pixel_seed(7, seed, 3 * seed);
        for (uint32_t i = 0; i < 2048; i++)
            for (uint32_t d = 0; d < 12; d++) {
                float v = pt_sample_1d(ps, i, d);
                out += !(v >= 0.0f && v < 1.0f);
                mismatch += v != pt_sample_1d(ps, i, d);
                float p[2];
                pt_sample_2d(ps, i, d, p);
                out += !(p[0] >= 0.0f && p[0] < 1.0f && p[1] >= 0.0f && p[1] < 1.0f);
                /* 2D equals the two 1D values, for even and odd dims. */
                mismatch += p[0] != v || p[1] != pt_sample_1d(ps, i, d + 1);
                equal += v == pt_sample_1d(pt_pixel_seed(7, seed + 1, 3 * seed), i, d);
                n++;
            }
    }
    CHECKF(out == 0, "%d values outside [0,1)", out);
    CHECKF(mismatch == 0, "%d values not reproducible", mismatch);
    /* Two pixels share a 24-bit value by chance with probability 2^-24 per
     * pair; allow a few. */
    CHECKF(equal <= 3, "%d of %d values equal across pixel seeds", equal, n);
    /* Extreme keys stay in range. */
    float v = pt_sample_1d(0xffffffffu, 0xffffffffu, 0xffffffffu);
    CHECK(v >= 0.0f && v < 1.0f);
    CHECK(pt_pixel_seed(1, 2, 3) == pt_pixel_seed(1, 2, 3));
    CHECK(pt_pixel_seed(1, 2, 3) != pt_pixel_seed(1, 3, 2));
    CHECK(pt_pixel_seed(1, 2, 3) != pt_pixel_seed(2, 2, 3));
}

/* After scrambling, the pairs (0,1), (2,3), (6,7) of any aligned block of 256
 * samples are (0,8,2)-nets: every 2^a x 2^b interval (a + b = 8) holds one. */
static void test_scrambled_nets(void)
{
    static unsigned short cnt[256];
    int bad = 0, nets = 0;
    static const uint32_t dims[] = {0, 2, 6, 40};
    for (uint32_t seed = 0; seed < 8; seed++)
        for (uint32_t di = 0; di < 4; di++)
            for (uint32_t block = 0; block < 3; block++) {
                uint32_t ps = pt_pixel_seed(99, seed, 5), base = block * 256u;
                for (int a = 0; a <= 8; a++) {
                    memset(cnt, 0, sizeof cnt);
                    for (uint32_t i = 0; i < 256; i++) {
                        float p[2];
                        pt_sample_2d(ps, base + i, dims[di], p);
                        uint32_t x = (uint32_t)(p[0] * (float)(1u << a));
                        uint32_t y = (uint32_t)(p[1] * (float)(1u << (8 - a)));
                        cnt[(x << (8 - a)) | y]++;
                    }
                    for (int c = 0; c < 256; c++)
                        bad += cnt[c] != 1;
                    nets++;
                }
            }
    CHECKF(bad == 0, "%d empty or doubled intervals in %d scrambled nets", bad, nets);
}

static void test_mean(void)
{
    uint32_t ps = pt_pixel_seed(3, 1, 4);
    for (uint32_t d = 0; d < 6; d++) {
        double s = 0.0;
        for (uint32_t i = 0; i < (1u << 16); i++)
            s += pt_sample_1d(ps, i, d);
        double mean = s / 65536.0;
        CHECKF(fabs(mean - 0.5) < 1e-3, "dim %u mean %.6f", (unsigned)d, mean);
    }
}

/*
 * Integration of the smooth f(x, y) = x y e^{x+y}: integral (int_0^1 x e^x)^2
 * = 1, variance E[f^2] - 1 with int_0^1 x^2 e^{2x} = (e^2 - 1) / 4. Plain
 * Monte Carlo has standard deviation sigma / sqrt(N); Owen-scrambled Sobol
 * converges at about N^{-3/2} for such a function, so at N = 4096 its RMS error
 * over 32 pixels must be far under a tenth of Monte Carlo's.
 */
static void test_convergence(void)
{
    const double e2 = exp(2.0);
    const double var = ((e2 - 1.0) / 4.0) * ((e2 - 1.0) / 4.0) - 1.0;
    const uint32_t n = 4096;
    double mc_sd = sqrt(var / n);
    static const uint32_t dims[] = {0, 2, 10};
    for (int di = 0; di < 3; di++) {
        double se = 0.0;
        for (uint32_t px = 0; px < 32; px++) {
            uint32_t ps = pt_pixel_seed(11, px, 0);
            double s = 0.0;
            for (uint32_t i = 0; i < n; i++) {
                float p[2];
                pt_sample_2d(ps, i, dims[di], p);
                s += p[0] * p[1] * exp((double)p[0] + p[1]);
            }
            double err = s / n - 1.0;
            se += err * err;
        }
        double rms = sqrt(se / 32.0);
        CHECKF(rms < 0.1 * mc_sd, "dims %u: rms error %.3g vs MC sd %.3g", (unsigned)dims[di], rms,
               mc_sd);
    }
}

/* Dimensions in different pairs are independently padded: their sample
 * correlation over N samples has standard deviation 1/sqrt(N). */
static void test_decorrelation(void)
{
    const uint32_t n = 4096;
    static const uint32_t pairs[][2] = {{0, 4}, {0, 2}, {1, 3}, {3, 5}, {5, 13}};
    for (int k = 0; k < 5; k++) {
        uint32_t ps = pt_pixel_seed(5, 17, 23);
        double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
        for (uint32_t i = 0; i < n; i++) {
            double x = pt_sample_1d(ps, i, pairs[k][0]);
            double y = pt_sample_1d(ps, i, pairs[k][1]);
            sx += x, sy += y, sxx += x * x, syy += y * y, sxy += x * y;
        }
        double cov = sxy / n - (sx / n) * (sy / n);
        double r = cov / sqrt((sxx / n - (sx / n) * (sx / n)) * (syy / n - (sy / n) * (sy / n)));
        CHECKF(fabs(r) < 5.0 / sqrt((double)n), "dims %u,%u correlation %.4f",
               (unsigned)pairs[k][0], (unsigned)pairs[k][1], r);
    }
}

/* The hot path's groups (seeds hashed once per pixel, 8 dimensions at once)
 * give pt_sample_1d's values bit for bit, for any even first dimension. */
static void test_groups(void)
{
    int bad = 0;
    for (uint32_t seed = 0; seed < 8; seed++) {
        uint32_t ps = pt_pixel_seed(11, seed, 5 * seed + 1);
        for (uint32_t dim0 = 0; dim0 < 140; dim0 += 2) {
            pt_sample_group g;
            pt_sample_group_init(&g, ps, dim0);
            for (uint32_t i = 0; i < 300; i++) {
                uint32_t idx = i < 200 ? i : i * 2654435761u;
                float v[8], w[2];
                pt_sample_group_eval(&g, idx, v);
                pt_sample_group_eval2(&g, idx, w);
                for (uint32_t k = 0; k < 8; k++)
                    bad += v[k] != pt_sample_1d(ps, idx, dim0 + k);
                bad += w[0] != v[0] || w[1] != v[1];
            }
        }
    }
    CHECKF(bad == 0, "%d group values differ from pt_sample_1d", bad);

    /* Many groups and indices in one call, odd and even counts. */
    enum { N = 37 };
    pt_sample_group gs[N];
    const pt_sample_group *gp[N];
    uint32_t idx[N];
    float out[N][8];
    bad = 0;
    for (uint32_t j = 0; j < N; j++) {
        pt_sample_group_init(&gs[j], pt_pixel_seed(3, j, 7 * j), 4 + 8 * (j % 5));
        gp[j] = &gs[j];
        idx[j] = j < 20 ? j : j * 2654435761u;
    }
    for (uint32_t n = 0; n <= N; n++) {
        for (int portable = 0; portable < 2; portable++) {
            memset(out, 0, sizeof out);
            if (portable)
                pt_sample_group_eval_n_portable(gp, idx, n, out);
            else
                pt_sample_group_eval_n(gp, idx, n, out);
            for (uint32_t j = 0; j < N; j++) {
                float v[8] = {0};
                if (j < n)
                    pt_sample_group_eval(gp[j], idx[j], v);
                bad += memcmp(v, out[j], sizeof v) != 0;
            }
        }
    }
    CHECKF(bad == 0, "%d pt_sample_group_eval_n results differ from pt_sample_group_eval", bad);
}

int main(void)
{
    test_groups();
    test_direction_numbers();
    test_unscrambled_strata();
    test_range_and_determinism();
    test_scrambled_nets();
    test_mean();
    test_convergence();
    test_decorrelation();
    return check_report();
}
