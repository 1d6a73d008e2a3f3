#include "link.h"
#include "cobs.h"
#include "crc32.h"

uint8_t link_decode(const uint8_t *enc, uint16_t len, frame_t *f)
{
    uint8_t body[FRAME_BODY_MAX];
    f->msg_type = 0;
    f->seq = 0;
    f->flags = 0;
    f->len = 0;
    int16_t n = cobs_decode(enc, len, body, sizeof body);
    if (n < FRAME_OVERHEAD)
        return LINK_MALFORMED;
    f->msg_type = body[1];
    f->seq = get_u16(body + 2);
    f->flags = body[4];
    uint16_t plen = get_u16(body + 5);
    if (plen > MAX_PAYLOAD_MCU || (uint16_t)n != FRAME_OVERHEAD + plen)
        return LINK_MALFORMED;
    if (crc32(body, (uint16_t)(n - 4)) != get_u32(body + n - 4))
        return LINK_CRC;
    if (body[0] != PROTOCOL_VERSION)
        return LINK_MALFORMED;
    f->len = (uint8_t)plen;
    for (uint8_t i = 0; i < f->len; i++)
        f->payload[i] = body[FRAME_HEADER + i];
    return LINK_OK;
}

uint8_t link_encode(uint8_t msg_type, uint16_t seq, uint8_t flags, const uint8_t *payload,
                    uint8_t len, uint8_t *out)
{
    uint8_t body[FRAME_BODY_MAX];
    if (len > MAX_PAYLOAD_MCU)
        len = MAX_PAYLOAD_MCU; /* callers never do this; never overrun */
    body[0] = PROTOCOL_VERSION;
    body[1] = msg_type;
    put_u16(body + 2, seq);
    body[4] = flags;
    put_u16(body + 5, len);
    for (uint8_t i = 0; i < len; i++)
        body[FRAME_HEADER + i] = payload[i];
    put_u32(body + FRAME_HEADER + len, crc32(body, (uint16_t)(FRAME_HEADER + len)));
    uint8_t n = (uint8_t)cobs_encode(body, (uint16_t)(FRAME_OVERHEAD + len), out);
    out[n++] = 0;
    return n;
}
