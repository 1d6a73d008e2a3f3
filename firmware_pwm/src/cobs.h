#ifndef LASERPI_COBS_H
#define LASERPI_COBS_H
#include <stdint.h>
/* Consistent Overhead Byte Stuffing, byte-compatible with the Python `cobs` package
 * (protocol/framing.py).  The 0x00 frame delimiter is not part of either buffer. */

/* Encodes len bytes; out needs len + len/254 + 1 bytes.  Returns the encoded length. */
uint16_t cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out);
/* Decodes len bytes into out (capacity cap).  Returns the decoded length, or -1 if the input
 * contains a zero byte, a length code runs past the end, or the output would exceed cap. */
int16_t cobs_decode(const uint8_t *in, uint16_t len, uint8_t *out, uint16_t cap);
#endif
