/*
 * fuzz_state.h - what the fuzz targets of the state folder (fuzz_queue,
 * fuzz_checkpoint, fuzz_results_log) and gen_corpus share: the jobs the
 * checkpoints and logs belong to, the mode byte, and checksum sealing.
 *
 * Input of those targets: a mode byte, then the file's bytes. Mode bit 0
 * picks the job (FUZZ_JOB_PARAMS[bit 0]: one plain, one adaptive); bit 1
 * "seals" the file: the harness rewrites its CRC32C (the last 4 bytes of a
 * queue file or checkpoint; each record's of a results log) to match, so
 * that mutations reach the parsers behind the checksum instead of dying at
 * it. Unsealed inputs test the checksum and envelope checks themselves.
 * Layouts: server/store/state.h (files), server/sched/job.h (srv_job_save).
 */
#ifndef PT_TESTS_FUZZ_STATE_H
#define PT_TESTS_FUZZ_STATE_H

#include <stdint.h>
#include <string.h>

#include "protocol/frame.h"
#include "protocol/wire.h"
#include "server/sched/job.h"

#define FUZZ_JOB_ID 1u
#define FUZZ_MODE_ADAPTIVE 1u
#define FUZZ_MODE_SEAL 2u

static const uint8_t FUZZ_JOB_HASH[32] = {0x50, 0x54, 0x46, 0x5a, 7};

/* Small, so that a checkpoint or log is a few KiB: 12x8 at 48 spp in 4x4
 * tiles and 16-sample chunks (6 tiles, 3 passes); 8x8 at 64 spp, adaptive
 * from 32 samples on, with a named camera, an environment map, a material
 * variant, a shutter, an indirect clamp and every render pass (4 tiles, 4
 * passes). */
static const srv_job_params FUZZ_JOB_PARAMS[2] = {
    {12,
     8,
     48,
     4,
     16,
     7,
     8,
     3,
     0.0,
     0,
     0.0,
     "",
     {"", 1.0f, 0.0f, 0, {0, 0, 0}},
     0,
     "",
     {0, 0},
     {0, 0},
     0,
     {0}},
    {8,
     8,
     64,
     4,
     16,
     9,
     6,
     2,
     0.05,
     32,
     0.001,
     "cam",
     {".ptfarm/environment", 2.0f, 30.0f, 0, {0, 0, 0}},
     PROTO_FILM_TRANSPARENT | PROTO_FILM_PASSES,
     "Peacock Velvet",
     {0.0, 0.5 / 24.0},
     {0.0f, 4.0f},
     0,
     {0}},
};

/* Rewrites the trailing CRC32C of a whole-file format (queue, checkpoint). */
static inline void fuzz_seal_file(uint8_t *f, size_t len)
{
    if (len >= 12)
        proto_put_u32(f + len - 4, proto_crc32c(0, f, len - 4));
}

/* Rewrites the CRC32C of every whole record of a results log (16-byte
 * header, then records of u32 length, u32 CRC32C, payload). */
static inline void fuzz_seal_log(uint8_t *f, size_t len)
{
    size_t off = 16;
    while (len >= off && len - off >= 8) {
        uint32_t n = proto_get_u32(f + off);
        if (n > len - off - 8)
            break;
        proto_put_u32(f + off + 4, proto_crc32c(0, f + off + 8, n));
        off += 8 + (size_t)n;
    }
}

#endif
