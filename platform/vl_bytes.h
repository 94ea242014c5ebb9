/**
 * @file vl_bytes.h
 * @brief Big-endian integers as LCM writes them, in its messages and its log event headers.
 */
#ifndef VISLAM_VL_BYTES_H
#define VISLAM_VL_BYTES_H

#include <stdint.h>
#include <string.h>

/** The unsigned 32-bit big-endian integer at p. */
static inline uint32_t vl_be32(const unsigned char *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | (uint32_t)p[3];
}

/** The signed 64-bit big-endian integer at p (two's complement, as LCM's int64_t). */
static inline int64_t vl_be64(const unsigned char *p)
{
    const uint64_t v = ((uint64_t)vl_be32(p) << 32) | (uint64_t)vl_be32(p + 4);
    int64_t s;
    memcpy(&s, &v, sizeof(s));
    return s;
}

#endif /* VISLAM_VL_BYTES_H */
