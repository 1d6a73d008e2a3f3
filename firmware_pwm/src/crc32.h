#ifndef LASERPI_CRC32_H
#define LASERPI_CRC32_H
#include <stdint.h>
/* CRC-32 as zlib.crc32 / IEEE 802.3 (reflected poly 0xEDB88320, init and xorout 0xFFFFFFFF). */
uint32_t crc32_update(uint32_t crc, const uint8_t *data, uint16_t len);
uint32_t crc32(const uint8_t *data, uint16_t len);
#endif
