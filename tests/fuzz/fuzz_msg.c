/*
 * fuzz_msg.c - libFuzzer target for the message decoders of protocol/msg.c.
 *
 * Input: byte 0 picks the decoder (byte0 % FUZZ_NTYPES, 17, in the order of
 * fuzz_types) and, for RESULT, the caller-buffer path (bit (byte0 / 17) & 1);
 * the rest is the payload. A payload that decodes must re-encode to the same bytes.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "tests/fuzz/fuzz_msg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    uint8_t sel = data[0];
    fuzz_decode(fuzz_types[sel % FUZZ_NTYPES], data + 1, size - 1, (sel / FUZZ_NTYPES) & 1);
    return 0;
}
