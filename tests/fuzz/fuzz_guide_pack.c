/*
 * fuzz_guide_pack.c - libFuzzer target for GUIDE_CHUNK's packed bytes
 * (proto_guide_unpack, protocol/guide.h): what a worker inflates before it
 * hashes and decodes a guiding distribution, so hostile zlib data from a
 * peer.
 *
 * Input: the packed bytes. Invariants: a refusal is PT_ERR_FORMAT (or
 * PT_ERR_NOMEM) with a message and leaves nothing allocated; the output is
 * exactly the length the header declared, never more than
 * PROTO_MAX_GUIDE_BYTES nor more than PROTO_GUIDE_PACK_RATIO times the
 * stream; packed again, it unpacks to the same bytes; and the unpacked bytes
 * go through proto_guide_decode as a worker's do. Seeds (corpus/
 * fuzz_guide_pack/, written by gen_corpus): a uniform guide and one built
 * from statistics, packed, and refused ones (a cut stream, a declared length
 * one short, a bomb declaring 256 MiB in a few bytes, trailing bytes).
 */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "common/base/alloc.h"
#include "common/render/guide.h"
#include "protocol/guide.h"
#include "tests/fuzz/fuzz_util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int64_t live = pt_alloc_live();
    uint8_t *raw = NULL;
    size_t n = 0;
    pt_error err = {0};
    pt_status st = proto_guide_unpack(data, size, &raw, &n, &err);
    fuzz_note("guide_pack", st, &err);
    FUZZ_CHECK(st == PT_OK || ((st == PT_ERR_FORMAT || st == PT_ERR_NOMEM) && err.msg[0]));
    if (st != PT_OK) {
        FUZZ_CHECK(!raw && pt_alloc_live() == live);
        return 0;
    }
    FUZZ_CHECK(raw && n == proto_get_u64(data + 4) && n <= PROTO_MAX_GUIDE_BYTES &&
               n <= (uint64_t)(size - PROTO_GUIDE_PACK_HEADER) * PROTO_GUIDE_PACK_RATIO);
    uint8_t *again = NULL, *back = NULL;
    size_t alen = 0, blen = 0;
    FUZZ_CHECK(proto_guide_pack(raw, n, &again, &alen, &err) == PT_OK);
    FUZZ_CHECK(proto_guide_unpack(again, alen, &back, &blen, &err) == PT_OK && blen == n &&
               memcmp(back, raw, n) == 0);
    pt_free(again);
    pt_free(back);
    pt_guide *g = NULL;
    if (proto_guide_decode(raw, n, &g, &err) == PT_OK)
        (void)pt_guide_check(g, &err);
    pt_guide_free(g);
    pt_free(raw);
    FUZZ_CHECK(pt_alloc_live() == live);
    return 0;
}
