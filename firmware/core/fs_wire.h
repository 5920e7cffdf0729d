/* Framing shared by the device and the host: CRC-16/CCITT-FALSE, COBS, little-endian
 * fields. Portable C99, no allocation; used by the core and its unit tests. */
#ifndef FS_WIRE_H
#define FS_WIRE_H

#include <stddef.h>
#include <stdint.h>

/* CRC-16/CCITT-FALSE (a.k.a. CRC-16/IBM-3740): polynomial 0x1021, initial value 0xFFFF,
 * no reflection, no final XOR. Check value of "123456789": 0x29B1. The host computes
 * the same with Python's binascii.crc_hqx(data, 0xFFFF). */
uint16_t fs_crc16(const uint8_t *data, size_t len);

/* COBS-encodes len bytes (len <= 254) into out, which needs len + 1 bytes; the result
 * holds no zero byte. Returns the encoded length. The caller appends the 0x00 delimiter. */
size_t fs_cobs_encode(const uint8_t *in, size_t len, uint8_t *out);

/* Decodes one COBS frame (delimiter excluded) into out (room for len - 1 bytes). Returns
 * the decoded length, or -1 when the input is not valid COBS (a zero byte inside, a code
 * byte pointing past the end). */
int fs_cobs_decode(const uint8_t *in, size_t len, uint8_t *out);

static inline void fs_put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void fs_put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline uint16_t fs_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static inline uint32_t fs_get_u32(const uint8_t *p) { return fs_get_u16(p) | (uint32_t)fs_get_u16(p + 2) << 16; }

#endif
