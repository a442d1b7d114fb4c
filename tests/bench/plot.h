/*
 * plot.h - log-log line plots written as PNG, for the benchmarks.
 *
 * A plot holds up to PLOT_MAX_SERIES series of up to PLOT_MAX_POINTS (x, y)
 * points each, in fixed arrays (no allocation besides the canvas at write
 * time). plot_write_png draws both axes in log10 with a grid line at every
 * decade (lighter ones at 2..9 x each decade), joins each series' points in
 * the order given, marks them, and draws a legend with the labels and a dashed
 * guide of slope -1/2 (Monte Carlo's error ~ time^-1/2; -1 for a squared
 * error, `squared`) through the first series' first point. Text uses a built-in 5x7 bitmap font
 * (digits, upper case letters, a lower case 'e' for exponents, a little punctuation); lower case
 * letters in labels are drawn as upper case. Points with a non-finite or non-positive coordinate
 * cannot be placed on log axes and are skipped. The PNG is written with stb_image_write
 * (implementation in libptcore). Not thread-safe: one owner per plot.
 */
#ifndef PT_TESTS_BENCH_PLOT_H
#define PT_TESTS_BENCH_PLOT_H

#include <stdint.h>

#include "common/base/error.h"

#define PLOT_MAX_SERIES 12
#define PLOT_MAX_POINTS 256
#define PLOT_MAX_LABEL 48

typedef struct plot_series {
    char label[PLOT_MAX_LABEL];
    uint32_t n;
    double x[PLOT_MAX_POINTS], y[PLOT_MAX_POINTS];
} plot_series;

typedef struct plot {
    char title[96], xlabel[48], ylabel[48];
    uint32_t num_series;
    int squared; /* y is a squared error (MSE, relMSE): the guide's slope is -1 */
    plot_series series[PLOT_MAX_SERIES];
} plot;

/* The series labelled `label` (truncated to PLOT_MAX_LABEL - 1 bytes), added
 * when absent; NULL when the plot already has PLOT_MAX_SERIES others. */
plot_series *plot_series_get(plot *p, const char *label);

/* Appends a point; returns PT_ERR_LIMIT when the series is full. */
pt_status plot_series_add(plot_series *s, double x, double y);

/* Adds the rows of a CSV file with a header line: each row's `label` column
 * names its series (a file without that column is one series named after the
 * file), xcol and ycol are the columns plotted. Fields are separated by
 * commas, unquoted. PT_ERR_IO when the file cannot be read, PT_ERR_FORMAT when
 * a column is missing or a value is not a number, PT_ERR_LIMIT when a cap is hit. */
pt_status plot_read_csv(plot *p, const char *path, const char *xcol, const char *ycol,
                        pt_error *err);

/* Draws the plot (width x height pixels, at least 320 x 240) to a PNG file.
 * PT_ERR_ARG when there is no point to draw, PT_ERR_IO when the write fails. */
pt_status plot_write_png(const plot *p, const char *path, uint32_t width, uint32_t height,
                         pt_error *err);

#endif
