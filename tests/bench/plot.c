#include "tests/bench/plot.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <stb_image_write.h>

#include "common/base/alloc.h"

/* ---- the font: 5x7 cells, '#' is ink, rows top to bottom ---------------- */

typedef struct glyph {
    char c;
    const char *rows; /* 7 rows of 5 characters */
} glyph;

/* clang-format off */
static const glyph font[] = {
    {'0', ".###.#...##..###.#.###..##...#.###."},
    {'1', "..#...##....#....#....#....#...###."},
    {'2', ".###.#...#....#...#...#...#...#####"},
    {'3', "#####...#...#.....#.....##...#.###."},
    {'4', "...#...##..#.#.#..#.#####...#....#."},
    {'5', "######....####.....#....##...#.###."},
    {'6', "..##..#...#....####.#...##...#.###."},
    {'7', "#####....#...#...#...#....#....#..."},
    {'8', ".###.#...##...#.###.#...##...#.###."},
    {'9', ".###.#...##...#.####....#...#..##.."},
    {'A', ".###.#...##...#######...##...##...#"},
    {'B', "####.#...##...#####.#...##...#####."},
    {'C', ".###.#...##....#....#....#...#.###."},
    {'D', "####.#...##...##...##...##...#####."},
    {'E', "######....#....####.#....#....#####"},
    {'F', "######....#....####.#....#....#...."},
    {'G', ".###.#...##....#.####...##...#.####"},
    {'H', "#...##...##...#######...##...##...#"},
    {'I', ".###...#....#....#....#....#...###."},
    {'J', "..###...#....#....#....#.#..#..##.."},
    {'K', "#...##..#.#.#..##...#.#..#..#.#...#"},
    {'L', "#....#....#....#....#....#....#####"},
    {'M', "#...###.###.#.##.#.##...##...##...#"},
    {'N', "#...##...###..##.#.##..###...##...#"},
    {'O', ".###.#...##...##...##...##...#.###."},
    {'P', "####.#...##...#####.#....#....#...."},
    {'Q', ".###.#...##...##...##.#.##..#..##.#"},
    {'R', "####.#...##...#####.#.#..#..#.#...#"},
    {'S', ".#####....#.....###.....#....#####."},
    {'T', "#####..#....#....#....#....#....#.."},
    {'U', "#...##...##...##...##...##...#.###."},
    {'V', "#...##...##...##...##...#.#.#...#.."},
    {'W', "#...##...##...##.#.##.#.##.#.#.#.#."},
    {'X', "#...##...#.#.#...#...#.#.#...##...#"},
    {'Y', "#...##...#.#.#...#....#....#....#.."},
    {'Z', "#####....#...#...#...#...#....#####"},
    {'e', "...........###.#...#######.....###."},
    {'.', "..........................##...##.."},
    {'-', "...............#####..............."},
    {'_', "..............................#####"},
    {'(', "...#...#...#....#....#.....#.....#."},
    {')', ".#.....#.....#....#....#...#...#..."},
    {'/', ".........#...#...#...#...#........."},
    {':', "......##...##.........##...##......"},
    {',', "....................##....#...#...."},
    {'=', "..........#####.....#####.........."},
    {'+', ".......#....#..#####..#....#......."},
    {' ', "..................................."},
    {'?', ".###.#...#....#...#...#.........#.."},
};
/* clang-format on */

#define GLYPH_W 5
#define GLYPH_H 7

/* fold: lower case drawn as upper case (labels); else 'e' is the exponent's. */
static const char *glyph_rows(char c, int fold)
{
    if (c >= 'a' && c <= 'z' && (fold || c != 'e'))
        c = (char)(c - 'a' + 'A');
    for (size_t i = 0; i < sizeof font / sizeof font[0]; i++)
        if (font[i].c == c)
            return font[i].rows;
    return glyph_rows('?', 1);
}

/* ---- the canvas ---------------------------------------------------------- */

typedef struct rgb {
    uint8_t r, g, b;
} rgb;

typedef struct canvas {
    uint32_t w, h;
    uint8_t *px; /* RGB, row-major, row 0 at the top */
} canvas;

static void put(canvas *c, int x, int y, rgb col)
{
    if (x < 0 || y < 0 || (uint32_t)x >= c->w || (uint32_t)y >= c->h)
        return;
    uint8_t *p = &c->px[3 * ((size_t)y * c->w + (size_t)x)];
    p[0] = col.r;
    p[1] = col.g;
    p[2] = col.b;
}

static void fill_rect(canvas *c, int x0, int y0, int x1, int y1, rgb col)
{
    for (int y = y0; y <= y1; y++)
        for (int x = x0; x <= x1; x++)
            put(c, x, y, col);
}

/* Bresenham; `thick` squares of side 2*thick+1 along the line; a dash
 * pattern (on, off in steps) when dash > 0. */
static void line(canvas *c, int x0, int y0, int x1, int y1, int thick, int dash, rgb col)
{
    int dx = abs(x1 - x0), dy = -abs(y1 - y0);
    int sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1, e = dx + dy;
    for (int step = 0;; step++) {
        if (dash <= 0 || (step / dash) % 2 == 0)
            fill_rect(c, x0 - thick, y0 - thick, x0 + thick, y0 + thick, col);
        if (x0 == x1 && y0 == y1)
            break;
        int e2 = 2 * e;
        if (e2 >= dy) {
            e += dy;
            x0 += sx;
        }
        if (e2 <= dx) {
            e += dx;
            y0 += sy;
        }
    }
}

static void disc(canvas *c, int cx, int cy, int r, rgb col)
{
    for (int y = -r; y <= r; y++)
        for (int x = -r; x <= r; x++)
            if (x * x + y * y <= r * r + r)
                put(c, cx + x, cy + y, col);
}

#define TEXT_SCALE 2
#define TEXT_ADVANCE ((GLYPH_W + 1) * TEXT_SCALE)

static int text_width(const char *s)
{
    int n = (int)strlen(s);
    return n ? n * TEXT_ADVANCE - TEXT_SCALE : 0;
}

/* Draws s with its top-left corner at (x, y); see glyph_rows for fold. */
static void text_folded(canvas *c, int x, int y, const char *s, rgb col, int fold)
{
    for (; *s; s++, x += TEXT_ADVANCE) {
        const char *rows = glyph_rows(*s, fold);
        for (int gy = 0; gy < GLYPH_H; gy++)
            for (int gx = 0; gx < GLYPH_W; gx++)
                if (rows[gy * GLYPH_W + gx] == '#')
                    fill_rect(c, x + gx * TEXT_SCALE, y + gy * TEXT_SCALE,
                              x + gx * TEXT_SCALE + TEXT_SCALE - 1,
                              y + gy * TEXT_SCALE + TEXT_SCALE - 1, col);
    }
}

static void text(canvas *c, int x, int y, const char *s, rgb col)
{
    text_folded(c, x, y, s, col, 1);
}

/* "0.01", "0.1", "1", "10", "100", "1000" near 1; "1e-4", "1e4" further out. */
static void decade_label(int k, char *buf, size_t n)
{
    if (k >= 0 && k <= 3)
        snprintf(buf, n, "%.0f", pow(10.0, k));
    else if (k < 0 && k >= -2)
        snprintf(buf, n, "%.*f", -k, pow(10.0, k));
    else
        snprintf(buf, n, "1e%d", k);
}

/* ---- series and CSV input ------------------------------------------------- */

plot_series *plot_series_get(plot *p, const char *label)
{
    char name[PLOT_MAX_LABEL];
    snprintf(name, sizeof name, "%s", label);
    for (uint32_t i = 0; i < p->num_series; i++)
        if (!strcmp(p->series[i].label, name))
            return &p->series[i];
    if (p->num_series == PLOT_MAX_SERIES)
        return NULL;
    plot_series *s = &p->series[p->num_series++];
    memset(s, 0, sizeof *s);
    memcpy(s->label, name, sizeof name);
    return s;
}

pt_status plot_series_add(plot_series *s, double x, double y)
{
    if (s->n == PLOT_MAX_POINTS)
        return PT_ERR_LIMIT;
    s->x[s->n] = x;
    s->y[s->n] = y;
    s->n++;
    return PT_OK;
}

/* Splits line (modified in place) at commas into at most max fields. */
static int split_csv(char *line_buf, char **fields, int max)
{
    int n = 0;
    line_buf[strcspn(line_buf, "\r\n")] = '\0';
    for (char *p = line_buf; n < max;) {
        fields[n++] = p;
        char *comma = strchr(p, ',');
        if (!comma)
            break;
        *comma = '\0';
        p = comma + 1;
    }
    return n;
}

static int find_col(char **fields, int n, const char *name)
{
    for (int i = 0; i < n; i++)
        if (!strcmp(fields[i], name))
            return i;
    return -1;
}

pt_status plot_read_csv(plot *p, const char *path, const char *xcol, const char *ycol,
                        pt_error *err)
{
    FILE *f = fopen(path, "r");
    if (!f)
        return pt_error_errno(err, PT_ERR_IO, "%s", path);
    pt_status st = PT_OK;
    char buf[4096], *fields[64];
    if (!fgets(buf, sizeof buf, f)) {
        st = pt_error_set(err, PT_ERR_FORMAT, "%s: empty file", path);
        goto fail;
    }
    int nf = split_csv(buf, fields, 64);
    int cl = find_col(fields, nf, "label"), cx = find_col(fields, nf, xcol),
        cy = find_col(fields, nf, ycol);
    if (cx < 0 || cy < 0) {
        st = pt_error_set(err, PT_ERR_FORMAT, "%s: no column '%s'", path, cx < 0 ? xcol : ycol);
        goto fail;
    }
    const char *base = strrchr(path, '/') ? strrchr(path, '/') + 1 : path;
    for (int row = 2; fgets(buf, sizeof buf, f); row++) {
        nf = split_csv(buf, fields, 64);
        if (nf == 1 && fields[0][0] == '\0')
            continue; /* blank line */
        if (nf <= cx || nf <= cy || (cl >= 0 && nf <= cl)) {
            st = pt_error_set(err, PT_ERR_FORMAT, "%s:%d: too few fields", path, row);
            goto fail;
        }
        char *ex, *ey;
        double x = strtod(fields[cx], &ex), y = strtod(fields[cy], &ey);
        if (ex == fields[cx] || *ex || ey == fields[cy] || *ey) {
            st = pt_error_set(err, PT_ERR_FORMAT, "%s:%d: '%s' or '%s' is not a number", path, row,
                              fields[cx], fields[cy]);
            goto fail;
        }
        plot_series *s = plot_series_get(p, cl >= 0 ? fields[cl] : base);
        if (!s || plot_series_add(s, x, y) != PT_OK) {
            st = pt_error_set(err, PT_ERR_LIMIT, "%s:%d: more than %d series or %d points", path,
                              row, PLOT_MAX_SERIES, PLOT_MAX_POINTS);
            goto fail;
        }
    }
    if (ferror(f))
        st = pt_error_errno(err, PT_ERR_IO, "%s", path);
fail:
    fclose(f);
    return st;
}

/* ---- drawing -------------------------------------------------------------- */

static const rgb palette[] = {
    {0x1f, 0x77, 0xb4}, {0xd6, 0x27, 0x28}, {0x2c, 0xa0, 0x2c}, {0xff, 0x7f, 0x0e},
    {0x94, 0x67, 0xbd}, {0x8c, 0x56, 0x4b}, {0xe3, 0x77, 0xc2}, {0x17, 0xbe, 0xcf},
};

static int usable(double x, double y)
{
    return isfinite(x) && isfinite(y) && x > 0 && y > 0;
}

/* Decade range [lo, hi] (exponents) covering [vmin, vmax], at least one decade wide. */
static void decades(double vmin, double vmax, int *lo, int *hi)
{
    *lo = (int)floor(log10(vmin) + 1e-9);
    *hi = (int)ceil(log10(vmax) - 1e-9);
    if (*hi <= *lo)
        *hi = *lo + 1;
}

typedef struct axes {
    int left, right, top, bottom; /* plot area, pixels */
    int xlo, xhi, ylo, yhi;       /* decade exponents */
} axes;

static int map_x(const axes *a, double x)
{
    double t = (log10(x) - a->xlo) / (a->xhi - a->xlo);
    return a->left + (int)lround(t * (a->right - a->left));
}

static int map_y(const axes *a, double y)
{
    double t = (log10(y) - a->ylo) / (a->yhi - a->ylo);
    return a->bottom - (int)lround(t * (a->bottom - a->top));
}

static void draw_grid(canvas *c, const axes *a)
{
    const rgb minor = {0xec, 0xec, 0xec}, major = {0xb8, 0xb8, 0xb8}, ink = {0, 0, 0};
    char lab[32];
    for (int k = a->xlo; k <= a->xhi; k++) {
        for (int m = 2; m <= 9 && k < a->xhi; m++) {
            int x = map_x(a, m * pow(10.0, k));
            line(c, x, a->top, x, a->bottom, 0, 0, minor);
        }
        int x = map_x(a, pow(10.0, k));
        line(c, x, a->top, x, a->bottom, 0, 0, major);
        line(c, x, a->bottom, x, a->bottom + 5, 0, 0, ink);
        decade_label(k, lab, sizeof lab);
        text_folded(c, x - text_width(lab) / 2, a->bottom + 10, lab, ink, 0);
    }
    for (int k = a->ylo; k <= a->yhi; k++) {
        for (int m = 2; m <= 9 && k < a->yhi; m++) {
            int y = map_y(a, m * pow(10.0, k));
            line(c, a->left, y, a->right, y, 0, 0, minor);
        }
        int y = map_y(a, pow(10.0, k));
        line(c, a->left, y, a->right, y, 0, 0, major);
        line(c, a->left - 5, y, a->left, y, 0, 0, ink);
        decade_label(k, lab, sizeof lab);
        text_folded(c, a->left - 10 - text_width(lab), y - GLYPH_H * TEXT_SCALE / 2, lab, ink, 0);
    }
    line(c, a->left, a->top, a->right, a->top, 0, 0, ink);
    line(c, a->left, a->bottom, a->right, a->bottom, 0, 0, ink);
    line(c, a->left, a->top, a->left, a->bottom, 0, 0, ink);
    line(c, a->right, a->top, a->right, a->bottom, 0, 0, ink);
}

/* The slope guide (-e) through (x0, y0), clipped to the plot's decades. */
static void draw_guide(canvas *c, const axes *a, double x0, double y0, double e, rgb col)
{
    double xa = pow(10.0, a->xlo), xb = pow(10.0, a->xhi);
    /* y = y0 * (x / x0)^-e; clip x so that y stays within [ylo, yhi]. */
    double ymax = pow(10.0, a->yhi), ymin = pow(10.0, a->ylo);
    double xa_clip = x0 * pow(y0 / ymax, 1.0 / e), xb_clip = x0 * pow(y0 / ymin, 1.0 / e);
    if (xa_clip > xa)
        xa = xa_clip;
    if (xb_clip < xb)
        xb = xb_clip;
    if (xa >= xb)
        return;
    line(c, map_x(a, xa), map_y(a, y0 * pow(x0 / xa, e)), map_x(a, xb),
         map_y(a, y0 * pow(x0 / xb, e)), 0, 4, col);
}

pt_status plot_write_png(const plot *p, const char *path, uint32_t width, uint32_t height,
                         pt_error *err)
{
    double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY;
    int first = -1;
    for (uint32_t i = 0; i < p->num_series; i++)
        for (uint32_t j = 0; j < p->series[i].n; j++) {
            double x = p->series[i].x[j], y = p->series[i].y[j];
            if (!usable(x, y))
                continue;
            if (first < 0)
                first = (int)(i * PLOT_MAX_POINTS + j);
            xmin = fmin(xmin, x);
            xmax = fmax(xmax, x);
            ymin = fmin(ymin, y);
            ymax = fmax(ymax, y);
        }
    if (first < 0)
        return pt_error_set(err, PT_ERR_ARG, "%s: no point with positive finite coordinates", path);
    if (width < 320 || height < 240 || width > 8192 || height > 8192)
        return pt_error_set(err, PT_ERR_ARG, "%s: plot size %ux%u out of range", path, width,
                            height);
    canvas c = {width, height, pt_malloc_array((size_t)width * height, 3)};
    if (!c.px)
        return pt_error_set(err, PT_ERR_NOMEM, "%s: canvas %ux%u", path, width, height);
    memset(c.px, 0xff, (size_t)width * height * 3);

    const rgb ink = {0, 0, 0}, guide = {0x90, 0x90, 0x90};
    axes a = {.left = 110, .right = (int)width - 30, .top = 60, .bottom = (int)height - 70};
    decades(xmin, xmax, &a.xlo, &a.xhi);
    decades(ymin, ymax, &a.ylo, &a.yhi);
    draw_grid(&c, &a);
    text(&c, ((int)width - text_width(p->title)) / 2, 14, p->title, ink);
    text(&c, a.left - text_width(p->ylabel) / 2, a.top - 26, p->ylabel, ink);
    text(&c, (a.left + a.right - text_width(p->xlabel)) / 2, a.bottom + 40, p->xlabel, ink);

    const plot_series *s0 = &p->series[first / PLOT_MAX_POINTS];
    draw_guide(&c, &a, s0->x[first % PLOT_MAX_POINTS], s0->y[first % PLOT_MAX_POINTS],
               p->squared ? 1.0 : 0.5, guide);

    for (uint32_t i = 0; i < p->num_series; i++) {
        const plot_series *s = &p->series[i];
        rgb col = palette[i % (sizeof palette / sizeof palette[0])];
        int px = 0, py = 0, have = 0;
        for (uint32_t j = 0; j < s->n; j++) {
            if (!usable(s->x[j], s->y[j]))
                continue;
            int x = map_x(&a, s->x[j]), y = map_y(&a, s->y[j]);
            if (have)
                line(&c, px, py, x, y, 1, 0, col);
            px = x;
            py = y;
            have = 1;
        }
        for (uint32_t j = 0; j < s->n; j++)
            if (usable(s->x[j], s->y[j]))
                disc(&c, map_x(&a, s->x[j]), map_y(&a, s->y[j]), 4, col);
    }

    /* Legend in the top-right corner, where error-against-time curves are not. */
    const char *slope = p->squared ? "SLOPE -1" : "SLOPE -1/2";
    int rows = (int)p->num_series + 1, widest = text_width(slope);
    for (uint32_t i = 0; i < p->num_series; i++)
        if (text_width(p->series[i].label) > widest)
            widest = text_width(p->series[i].label);
    int lw = widest + 60, lh = rows * 24 + 12, lx = a.right - lw - 10, ly = a.top + 10;
    fill_rect(&c, lx, ly, lx + lw, ly + lh, (rgb){0xff, 0xff, 0xff});
    line(&c, lx, ly, lx + lw, ly, 0, 0, ink);
    line(&c, lx, ly + lh, lx + lw, ly + lh, 0, 0, ink);
    line(&c, lx, ly, lx, ly + lh, 0, 0, ink);
    line(&c, lx + lw, ly, lx + lw, ly + lh, 0, 0, ink);
    for (int i = 0; i < rows; i++) {
        int y = ly + 12 + i * 24 + GLYPH_H * TEXT_SCALE / 2;
        if (i < (int)p->num_series) {
            rgb col = palette[i % (int)(sizeof palette / sizeof palette[0])];
            line(&c, lx + 10, y, lx + 40, y, 1, 0, col);
            disc(&c, lx + 25, y, 4, col);
            text(&c, lx + 50, y - GLYPH_H * TEXT_SCALE / 2, p->series[i].label, ink);
        } else {
            line(&c, lx + 10, y, lx + 40, y, 0, 4, guide);
            text(&c, lx + 50, y - GLYPH_H * TEXT_SCALE / 2, slope, ink);
        }
    }

    pt_status st = PT_OK;
    if (!stbi_write_png(path, (int)width, (int)height, 3, c.px, (int)width * 3))
        st = pt_error_set(err, PT_ERR_IO, "%s: cannot write the PNG", path);
    pt_free(c.px);
    return st;
}
