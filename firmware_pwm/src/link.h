/* Frame layer of protocol/framing.py in C: header <BBHBH (version, msg_type, seq, flags, len),
 * payload (at most MAX_PAYLOAD_MCU bytes), CRC-32 LE over header+payload, all COBS-encoded. */
#ifndef LASERPI_LINK_H
#define LASERPI_LINK_H
#include <stdint.h>
#include "msg.h"

#define FRAME_HEADER 7
#define FRAME_OVERHEAD 11
#define FRAME_BODY_MAX (MAX_PAYLOAD_MCU + FRAME_OVERHEAD)
/* COBS adds one byte per 254 (here: one), plus the delimiter. */
#define FRAME_WIRE_MAX (FRAME_BODY_MAX + 2)

typedef struct {
    uint8_t msg_type;
    uint8_t flags;
    uint16_t seq;
    uint8_t len;
    uint8_t payload[MAX_PAYLOAD_MCU];
} frame_t;

/* Outcome of link_decode: LINK_OK or the reason a frame is refused. */
#define LINK_OK 0
#define LINK_MALFORMED 1 /* COBS error, too short, length mismatch, oversize or wrong version */
#define LINK_CRC 2

/* Decodes one COBS-encoded frame (without delimiter).  On LINK_CRC / LINK_MALFORMED the header
 * fields that could be read are still filled in (msg_type, seq) so that the NACK can name them. */
uint8_t link_decode(const uint8_t *enc, uint16_t len, frame_t *f);
/* Writes the complete wire bytes (delimiter included) into out[FRAME_WIRE_MAX]; returns length. */
uint8_t link_encode(uint8_t msg_type, uint16_t seq, uint8_t flags, const uint8_t *payload,
                    uint8_t len, uint8_t *out);

/* little-endian helpers */
static inline uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static inline uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static inline uint64_t get_u64(const uint8_t *p) { return get_u32(p) | ((uint64_t)get_u32(p + 4) << 32); }
static inline void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline void put_u64(uint8_t *p, uint64_t v) { put_u32(p, (uint32_t)v); put_u32(p + 4, (uint32_t)(v >> 32)); }
#endif
