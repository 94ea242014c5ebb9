#include "vl_latency.h"

#include <math.h>
#include <string.h>

/* Bucket index e-ranges: [0, 2*SUB) are exact; from there each octave 2^e (e >= SUB_BITS + 1)
   holds SUB buckets of width 2^(e - SUB_BITS). */

static int floor_log2(uint64_t v)
{
    int e = 0;
    while (v >>= 1) {
        ++e;
    }
    return e;
}

void vl_latency_reset(vl_latency_t *h)
{
    memset(h, 0, sizeof(*h));
}

size_t vl_latency_bucket_index(int64_t us)
{
    if (us < 0) {
        us = 0;
    }
    if (us < 2 * VL_LATENCY_SUB) {
        return (size_t)us;
    }
    if (us >= VL_LATENCY_OVERFLOW_US) {
        return VL_LATENCY_BUCKETS;
    }
    const int e = floor_log2((uint64_t)us);
    const int shift = e - VL_LATENCY_SUB_BITS;
    const size_t mantissa = (size_t)((uint64_t)us >> shift); /* SUB .. 2*SUB-1 */
    return 2 * VL_LATENCY_SUB + (size_t)(e - VL_LATENCY_SUB_BITS - 1) * VL_LATENCY_SUB + (mantissa - VL_LATENCY_SUB);
}

int64_t vl_latency_bucket_lower(size_t index)
{
    if (index >= VL_LATENCY_BUCKETS) {
        return VL_LATENCY_OVERFLOW_US;
    }
    if (index < 2 * VL_LATENCY_SUB) {
        return (int64_t)index;
    }
    const size_t rel = index - 2 * VL_LATENCY_SUB;
    const int e = (int)(rel / VL_LATENCY_SUB) + VL_LATENCY_SUB_BITS + 1;
    const int64_t mantissa = (int64_t)(rel % VL_LATENCY_SUB) + VL_LATENCY_SUB;
    return mantissa << (e - VL_LATENCY_SUB_BITS);
}

int64_t vl_latency_bucket_upper(size_t index)
{
    if (index >= VL_LATENCY_BUCKETS) {
        return INT64_MAX;
    }
    if (index + 1 == VL_LATENCY_BUCKETS) {
        return VL_LATENCY_OVERFLOW_US - 1;
    }
    return vl_latency_bucket_lower(index + 1) - 1;
}

void vl_latency_record(vl_latency_t *h, int64_t us)
{
    if (us < 0) {
        us = 0;
    }
    const size_t i = vl_latency_bucket_index(us);
    if (i >= VL_LATENCY_BUCKETS) {
        h->overflow++;
    } else {
        h->buckets[i]++;
    }
    if (h->count == 0 || us < h->min) {
        h->min = us;
    }
    if (h->count == 0 || us > h->max) {
        h->max = us;
    }
    h->count++;
    h->sum += (double)us;
}

uint64_t vl_latency_count(const vl_latency_t *h)
{
    return h->count;
}

int64_t vl_latency_max(const vl_latency_t *h)
{
    return h->max;
}

double vl_latency_mean(const vl_latency_t *h)
{
    return h->count == 0 ? 0.0 : h->sum / (double)h->count;
}

int64_t vl_latency_percentile(const vl_latency_t *h, double percent)
{
    if (h->count == 0) {
        return 0;
    }
    if (!(percent > 0.0)) { /* also NaN */
        return h->min;
    }
    if (percent > 100.0) {
        percent = 100.0;
    }
    /* Nearest rank, computed so that 99.9 % of 1000 is exactly 999 despite rounding. */
    double r = ceil(percent / 100.0 * (double)h->count - 1e-9);
    uint64_t rank = r < 1.0 ? 1 : (uint64_t)r;
    if (rank > h->count) {
        rank = h->count;
    }
    uint64_t seen = 0;
    for (size_t i = 0; i < VL_LATENCY_BUCKETS; ++i) {
        seen += h->buckets[i];
        if (seen >= rank) {
            const int64_t upper = vl_latency_bucket_upper(i);
            return upper < h->max ? upper : h->max;
        }
    }
    return h->max; /* the rank lies in the overflow bucket */
}

void vl_latency_print(const vl_latency_t *h, FILE *f, const char *label)
{
    fprintf(f, "%s: n %llu  p50 %lld  p90 %lld  p99 %lld  p99.9 %lld  max %lld  mean %.1f us", label,
            (unsigned long long)h->count, (long long)vl_latency_percentile(h, 50.0),
            (long long)vl_latency_percentile(h, 90.0), (long long)vl_latency_percentile(h, 99.0),
            (long long)vl_latency_percentile(h, 99.9), (long long)h->max, vl_latency_mean(h));
    if (h->overflow != 0) {
        fprintf(f, "  (%llu >= %lld us)", (unsigned long long)h->overflow, (long long)VL_LATENCY_OVERFLOW_US);
    }
    fputc('\n', f);
}

void vl_latency_print_buckets(const vl_latency_t *h, FILE *f)
{
    /* Group the fine buckets by power of two: [0,1) [1,2) [2,4) ... */
    int64_t lo = 0;
    int64_t hi = 1;
    while (lo < VL_LATENCY_OVERFLOW_US) {
        uint64_t n = 0;
        for (size_t i = vl_latency_bucket_index(lo); i < VL_LATENCY_BUCKETS && vl_latency_bucket_lower(i) < hi; ++i) {
            n += h->buckets[i];
        }
        if (n != 0) {
            fprintf(f, "  [%lld, %lld) us  %llu\n", (long long)lo, (long long)hi, (unsigned long long)n);
        }
        lo = hi;
        hi *= 2;
    }
    if (h->overflow != 0) {
        fprintf(f, "  [%lld, inf) us  %llu\n", (long long)VL_LATENCY_OVERFLOW_US, (unsigned long long)h->overflow);
    }
}
