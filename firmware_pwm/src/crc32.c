/* CRC-32 (IEEE 802.3, the zlib.crc32 used by protocol/framing.py).
 *
 * Why not a library: avr-libc ships only CRC-16/CRC-8 helpers (util/crc16.h), no CRC-32, and a
 * byte-wise 256-entry table would cost 1 KiB.  This nibble-table version keeps 64 bytes of
 * table (in flash on the AVR) and costs two lookups per byte, plenty for a 250 kbaud link.
 */
#include "crc32.h"

#ifdef __AVR__
#include <avr/pgmspace.h>
#define TABLE_ATTR PROGMEM
#define TABLE_READ(i) pgm_read_dword(&crc_nibble[(i)])
#else
#define TABLE_ATTR
#define TABLE_READ(i) crc_nibble[(i)]
#endif

/* crc_nibble[i] = CRC register after shifting nibble i through the reflected polynomial. */
static const uint32_t crc_nibble[16] TABLE_ATTR = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL,
    0x4DB26158UL, 0x5005713CUL, 0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL,
    0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL,
};

uint32_t crc32_update(uint32_t crc, const uint8_t *data, uint16_t len)
{
    crc = ~crc;
    while (len--) {
        crc ^= *data++;
        crc = (crc >> 4) ^ TABLE_READ(crc & 0x0F);
        crc = (crc >> 4) ^ TABLE_READ(crc & 0x0F);
    }
    return ~crc;
}

uint32_t crc32(const uint8_t *data, uint16_t len) { return crc32_update(0, data, len); }
