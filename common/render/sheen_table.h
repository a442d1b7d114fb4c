/*
 * sheen_table.h - the sheen lobe's directional albedo for white colour,
 * E(mu, r), tabulated (layers.h reads it bilinearly): row j is sheen
 * roughness r = j / (N - 1), column i is mu = cos(theta_o) = i / (N - 1)
 * (1e-3 at i = 0). Computed once, when the table was generated, by the
 * quadrature in tests/common/render/test_layers.c (`test_layers
 * --sheen-table` prints sheen_table.c), and compiled in: every worker of the
 * farm reads the same numbers and none spends time building them. Read-only.
 */
#ifndef PT_COMMON_RENDER_SHEEN_TABLE_H
#define PT_COMMON_RENDER_SHEEN_TABLE_H

#define PT_SHEEN_TABLE_N 32

extern const float pt_sheen_table[PT_SHEEN_TABLE_N][PT_SHEEN_TABLE_N]; /* [roughness][mu] */

#endif
