/**
 * @file vl_latency.h
 * @brief Latency histogram in fixed memory with log-spaced buckets.
 *
 * Values are microseconds. Below 2 * VL_LATENCY_SUB (32 us) every microsecond
 * has its own bucket; above, each power of two [2^e, 2^(e+1)) is split into
 * VL_LATENCY_SUB equal buckets, so a bucket is at most 1/16 = 6.25 % wide
 * relative to its lower edge. Values from 2^VL_LATENCY_MAX_BITS us (16.8 s)
 * up go to one overflow bucket. Count, minimum, maximum and sum are exact.
 *
 * Recording is O(1), does not allocate and does not read a clock, so it is
 * safe inside a real-time loop (not from several threads at once).
 */
#ifndef VISLAM_PLATFORM_VL_LATENCY_H
#define VISLAM_PLATFORM_VL_LATENCY_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

/** log2 of the buckets per power of two. */
#define VL_LATENCY_SUB_BITS 4
/** Buckets per power of two. */
#define VL_LATENCY_SUB (1 << VL_LATENCY_SUB_BITS)
/** Values at or above 2^VL_LATENCY_MAX_BITS us overflow. */
#define VL_LATENCY_MAX_BITS 24
/** Smallest value that overflows, us. */
#define VL_LATENCY_OVERFLOW_US ((int64_t)1 << VL_LATENCY_MAX_BITS)
/** Number of regular buckets: 2*SUB exact ones, then SUB per power of two from 2^(SUB_BITS+1). */
#define VL_LATENCY_BUCKETS (2 * VL_LATENCY_SUB + (VL_LATENCY_MAX_BITS - VL_LATENCY_SUB_BITS - 1) * VL_LATENCY_SUB)

/** The histogram; plain data, zero it with vl_latency_reset. */
typedef struct {
    uint64_t buckets[VL_LATENCY_BUCKETS]; /**< counts per bucket */
    uint64_t overflow;                    /**< values >= VL_LATENCY_OVERFLOW_US */
    uint64_t count;                       /**< values recorded */
    int64_t min;                          /**< us, smallest value (0 when empty) */
    int64_t max;                          /**< us, largest value (0 when empty) */
    double sum;                           /**< us, sum of values (for the mean) */
} vl_latency_t;

/** Empties the histogram. */
void vl_latency_reset(vl_latency_t *h);

/** Records one value in us; a negative value (a clock fault) is recorded as 0. */
void vl_latency_record(vl_latency_t *h, int64_t us);

/** Values recorded. */
uint64_t vl_latency_count(const vl_latency_t *h);

/** Largest value, us (0 when empty). */
int64_t vl_latency_max(const vl_latency_t *h);

/** Mean, us (0 when empty). */
double vl_latency_mean(const vl_latency_t *h);

/**
 * Nearest-rank percentile, us: the upper edge of the bucket holding the value
 * of rank ceil(percent/100 * count), capped at the maximum. Never below the
 * true percentile, at most 6.25 % above it (exact below 32 us); in the overflow
 * bucket it is the maximum.
 * @param percent 0..100 (clamped); 0 gives the minimum
 * @return 0 when empty
 */
int64_t vl_latency_percentile(const vl_latency_t *h, double percent);

/** Bucket holding @p us (VL_LATENCY_BUCKETS for the overflow bucket; negative -> 0). */
size_t vl_latency_bucket_index(int64_t us);

/** Smallest value of bucket @p index, us (VL_LATENCY_OVERFLOW_US for the overflow bucket). */
int64_t vl_latency_bucket_lower(size_t index);

/** Largest value of bucket @p index, us (INT64_MAX for the overflow bucket). */
int64_t vl_latency_bucket_upper(size_t index);

/**
 * Prints one line: "LABEL: n N  p50 A  p90 B  p99 C  p99.9 D  max E  mean F us"
 * (and the overflow count when nonzero).
 */
void vl_latency_print(const vl_latency_t *h, FILE *f, const char *label);

/** Prints the counts per power of two ("  [64, 128) us  1234"), non-empty ranges only. */
void vl_latency_print_buckets(const vl_latency_t *h, FILE *f);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_LATENCY_H */
