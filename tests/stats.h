/*
 * stats.h - statistics shared by the statistical tests.
 *
 * stats_gamma_q(a, x): the regularised upper incomplete gamma Q(a, x), by the
 * series for P when x < a + 1, else the continued fraction for Q evaluated by
 * the modified Lentz method (Abramowitz & Stegun 6.5.29 and 6.5.31; Press et
 * al., Numerical Recipes, 3rd ed., sec. 6.2). stats_chi2_survival(chi2, dof)
 * = Q(dof/2, chi2/2), the p-value of a chi-square statistic.
 */
#ifndef PT_TESTS_STATS_H
#define PT_TESTS_STATS_H

#include <math.h>

static inline double stats_gamma_q(double a, double x)
{
    if (x <= 0.0)
        return 1.0;
    double lg = a * log(x) - x - lgamma(a);
    if (x < a + 1.0) {
        double term = 1.0 / a, sum = term;
        for (int n = 1; n < 10000 && fabs(term) > fabs(sum) * 1e-15; n++) {
            term *= x / (a + n);
            sum += term;
        }
        return 1.0 - sum * exp(lg);
    }
    const double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int i = 1; i < 10000; i++) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < tiny)
            d = tiny;
        c = b + an / c;
        if (fabs(c) < tiny)
            c = tiny;
        d = 1.0 / d;
        double delta = d * c;
        h *= delta;
        if (fabs(delta - 1.0) < 1e-15)
            break;
    }
    return exp(lg) * h;
}

static inline double stats_chi2_survival(double chi2, int dof)
{
    return stats_gamma_q(0.5 * dof, 0.5 * chi2);
}

/* Pearson's chi-square of observed against expected counts in n bins; bins
 * expected below min_exp are pooled into one. Returns the p-value. */
static inline double stats_chi2_gof(const double *obs, const double *expd, int n, double min_exp,
                                    double *stat, int *dof)
{
    double s = 0.0, po = 0.0, pe = 0.0;
    int bins = 0;
    for (int i = 0; i < n; i++) {
        if (expd[i] < min_exp) {
            po += obs[i];
            pe += expd[i];
            continue;
        }
        s += (obs[i] - expd[i]) * (obs[i] - expd[i]) / expd[i];
        bins++;
    }
    if (pe > 0.0) {
        s += (po - pe) * (po - pe) / pe;
        bins++;
    } else if (po > 0.0) {
        s = INFINITY; /* samples where the density is zero */
    }
    *stat = s;
    *dof = bins - 1;
    return stats_chi2_survival(s, *dof);
}

#endif
