/* Tests of the fixed-memory latency histogram (platform/vl_latency). */
#define _POSIX_C_SOURCE 200809L /* fmemopen */

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "unity.h"
#include "vl_latency.h"

static vl_latency_t g_h;

void setUp(void)
{
    vl_latency_reset(&g_h);
}

void tearDown(void)
{
}

static int cmp_i64(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a;
    const int64_t y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Nearest-rank percentile of sorted values: the reference the histogram approximates. */
static int64_t reference_percentile(const int64_t *sorted, size_t n, double percent)
{
    size_t rank = (size_t)ceil(percent / 100.0 * (double)n - 1e-9);
    if (rank < 1) {
        rank = 1;
    }
    if (rank > n) {
        rank = n;
    }
    return sorted[rank - 1];
}

/* Deterministic generator (xorshift64*), so the test data never changes. */
static uint64_t g_rng = 0x9E3779B97F4A7C15ull;
static uint64_t next_u64(void)
{
    g_rng ^= g_rng >> 12;
    g_rng ^= g_rng << 25;
    g_rng ^= g_rng >> 27;
    return g_rng * 0x2545F4914F6CDD1Dull;
}

static void test_vl_latency_empty_reports_zero(void)
{
    TEST_ASSERT_EQUAL_UINT64(0, vl_latency_count(&g_h));
    TEST_ASSERT_EQUAL_INT64(0, vl_latency_percentile(&g_h, 50.0));
    TEST_ASSERT_EQUAL_INT64(0, vl_latency_max(&g_h));
    TEST_ASSERT_EQUAL_DOUBLE(0.0, vl_latency_mean(&g_h));
}

static void test_vl_latency_bucket_index_small_values_are_exact(void)
{
    for (int64_t v = 0; v < 2 * VL_LATENCY_SUB; ++v) {
        const size_t i = vl_latency_bucket_index(v);
        TEST_ASSERT_EQUAL_UINT64((uint64_t)((size_t)v), (uint64_t)i);
        TEST_ASSERT_EQUAL_INT64(v, vl_latency_bucket_lower(i));
        TEST_ASSERT_EQUAL_INT64(v, vl_latency_bucket_upper(i));
    }
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(0), (uint64_t)vl_latency_bucket_index(-5));
}

static void test_vl_latency_bucket_edges_are_contiguous_and_tight(void)
{
    /* Every bucket starts right after the previous one ends and is at most 1/16 of its lower edge wide. */
    TEST_ASSERT_EQUAL_INT64(0, vl_latency_bucket_lower(0));
    for (size_t i = 1; i < VL_LATENCY_BUCKETS; ++i) {
        TEST_ASSERT_EQUAL_INT64(vl_latency_bucket_upper(i - 1) + 1, vl_latency_bucket_lower(i));
        const int64_t lo = vl_latency_bucket_lower(i);
        const int64_t hi = vl_latency_bucket_upper(i);
        TEST_ASSERT_TRUE(hi >= lo);
        TEST_ASSERT_TRUE((hi - lo + 1) * VL_LATENCY_SUB <= lo || lo < 2 * VL_LATENCY_SUB);
        /* Both edges map back to the bucket. */
        TEST_ASSERT_EQUAL_UINT64((uint64_t)(i), (uint64_t)vl_latency_bucket_index(lo));
        TEST_ASSERT_EQUAL_UINT64((uint64_t)(i), (uint64_t)vl_latency_bucket_index(hi));
    }
    TEST_ASSERT_EQUAL_INT64(VL_LATENCY_OVERFLOW_US - 1, vl_latency_bucket_upper(VL_LATENCY_BUCKETS - 1));
}

static void test_vl_latency_bucket_index_at_powers_of_two(void)
{
    /* 32 = 2^5 opens the first log-spaced octave: buckets of width 2 from index 32. */
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(32), (uint64_t)vl_latency_bucket_index(32));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(32), (uint64_t)vl_latency_bucket_index(33));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(33), (uint64_t)vl_latency_bucket_index(34));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(47), (uint64_t)vl_latency_bucket_index(63));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(48), (uint64_t)vl_latency_bucket_index(64));
    /* 1000 us: octave 512..1023 (width 32), mantissa 1000 >> 5 = 31 -> last bucket of it. */
    TEST_ASSERT_EQUAL_INT64(992, vl_latency_bucket_lower(vl_latency_bucket_index(1000)));
    TEST_ASSERT_EQUAL_INT64(1023, vl_latency_bucket_upper(vl_latency_bucket_index(1000)));
}

static void test_vl_latency_overflow_goes_to_its_own_bucket(void)
{
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(VL_LATENCY_BUCKETS - 1),
                             (uint64_t)vl_latency_bucket_index(VL_LATENCY_OVERFLOW_US - 1));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(VL_LATENCY_BUCKETS), (uint64_t)vl_latency_bucket_index(VL_LATENCY_OVERFLOW_US));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(VL_LATENCY_BUCKETS), (uint64_t)vl_latency_bucket_index(INT64_MAX));
    vl_latency_record(&g_h, 10);
    vl_latency_record(&g_h, VL_LATENCY_OVERFLOW_US + 123);
    vl_latency_record(&g_h, 50LL * 1000 * 1000 * 1000); /* 50 000 s */
    TEST_ASSERT_EQUAL_UINT64(2, g_h.overflow);
    TEST_ASSERT_EQUAL_UINT64(3, vl_latency_count(&g_h));
    TEST_ASSERT_EQUAL_INT64(50LL * 1000 * 1000 * 1000, vl_latency_max(&g_h));
    /* Ranks inside the overflow bucket report the exact maximum. */
    TEST_ASSERT_EQUAL_INT64(50LL * 1000 * 1000 * 1000, vl_latency_percentile(&g_h, 99.0));
    TEST_ASSERT_EQUAL_INT64(10, vl_latency_percentile(&g_h, 33.0));
}

static void test_vl_latency_negative_value_counts_as_zero(void)
{
    vl_latency_record(&g_h, -7);
    TEST_ASSERT_EQUAL_UINT64(1, vl_latency_count(&g_h));
    TEST_ASSERT_EQUAL_UINT64(1, g_h.buckets[0]);
    TEST_ASSERT_EQUAL_INT64(0, vl_latency_max(&g_h));
}

static void test_vl_latency_percentile_exact_below_32_us(void)
{
    /* 1..20 once each: every percentile is exact. */
    for (int64_t v = 20; v >= 1; --v) {
        vl_latency_record(&g_h, v);
    }
    TEST_ASSERT_EQUAL_INT64(10, vl_latency_percentile(&g_h, 50.0));
    TEST_ASSERT_EQUAL_INT64(18, vl_latency_percentile(&g_h, 90.0));
    TEST_ASSERT_EQUAL_INT64(20, vl_latency_percentile(&g_h, 99.0));
    TEST_ASSERT_EQUAL_INT64(20, vl_latency_percentile(&g_h, 100.0));
    TEST_ASSERT_EQUAL_INT64(1, vl_latency_percentile(&g_h, 0.0));
    TEST_ASSERT_EQUAL_INT64(1, vl_latency_percentile(&g_h, 5.0));
    TEST_ASSERT_EQUAL_DOUBLE(10.5, vl_latency_mean(&g_h));
}

static void test_vl_latency_percentile_matches_sorted_reference(void)
{
    /* Log-uniform values from 1 us to about 1 s, like step latencies with a long tail. */
    enum { N = 20000 };
    static int64_t values[N];
    for (size_t i = 0; i < N; ++i) {
        const double u = (double)(next_u64() >> 11) / 9007199254740992.0; /* [0, 1) */
        values[i] = (int64_t)floor(pow(10.0, 6.0 * u));
        vl_latency_record(&g_h, values[i]);
    }
    qsort(values, N, sizeof(values[0]), cmp_i64);
    TEST_ASSERT_EQUAL_UINT64(N, vl_latency_count(&g_h));
    TEST_ASSERT_EQUAL_INT64(values[N - 1], vl_latency_max(&g_h));
    const double percents[] = {1.0, 10.0, 50.0, 90.0, 99.0, 99.9, 99.99, 100.0};
    for (size_t k = 0; k < sizeof(percents) / sizeof(percents[0]); ++k) {
        const int64_t ref = reference_percentile(values, N, percents[k]);
        const int64_t got = vl_latency_percentile(&g_h, percents[k]);
        char msg[96];
        snprintf(msg, sizeof(msg), "p%g: reference %lld, histogram %lld", percents[k], (long long)ref, (long long)got);
        /* Never below the truth, and within one bucket (1/16) above it. */
        TEST_ASSERT_TRUE_MESSAGE(got >= ref, msg);
        TEST_ASSERT_TRUE_MESSAGE(got <= ref + ref / VL_LATENCY_SUB + 1, msg);
        TEST_ASSERT_TRUE_MESSAGE(got <= values[N - 1], msg);
    }
}

static void test_vl_latency_percentile_rank_boundaries(void)
{
    /* 999 fast steps and one slow one: p99.9 is still fast, p99.95 and max see the slow one. */
    for (int i = 0; i < 999; ++i) {
        vl_latency_record(&g_h, 100);
    }
    vl_latency_record(&g_h, 5000);
    TEST_ASSERT_EQUAL_INT64(103, vl_latency_percentile(&g_h, 99.9)); /* bucket [100, 103] */
    TEST_ASSERT_EQUAL_INT64(5000, vl_latency_percentile(&g_h, 99.95));
    TEST_ASSERT_EQUAL_INT64(5000, vl_latency_max(&g_h));
}

static void test_vl_latency_percentile_capped_at_max(void)
{
    /* A single value in a wide bucket reports itself, not the bucket's upper edge. */
    vl_latency_record(&g_h, 1000000);
    TEST_ASSERT_EQUAL_INT64(1000000, vl_latency_percentile(&g_h, 50.0));
}

static void test_vl_latency_print_writes_summary(void)
{
    for (int64_t v = 1; v <= 100; ++v) {
        vl_latency_record(&g_h, v * 10);
    }
    char buf[1024];
    memset(buf, 0, sizeof(buf));
    FILE *f = fmemopen(buf, sizeof(buf) - 1, "w");
    TEST_ASSERT_NOT_NULL(f);
    vl_latency_print(&g_h, f, "steps");
    vl_latency_print_buckets(&g_h, f);
    fclose(f);
    TEST_ASSERT_NOT_NULL(strstr(buf, "steps: n 100  p50 "));
    TEST_ASSERT_NOT_NULL(strstr(buf, "max 1000"));
    TEST_ASSERT_NOT_NULL(strstr(buf, "[512, 1024) us  49"));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_vl_latency_empty_reports_zero);
    RUN_TEST(test_vl_latency_bucket_index_small_values_are_exact);
    RUN_TEST(test_vl_latency_bucket_edges_are_contiguous_and_tight);
    RUN_TEST(test_vl_latency_bucket_index_at_powers_of_two);
    RUN_TEST(test_vl_latency_overflow_goes_to_its_own_bucket);
    RUN_TEST(test_vl_latency_negative_value_counts_as_zero);
    RUN_TEST(test_vl_latency_percentile_exact_below_32_us);
    RUN_TEST(test_vl_latency_percentile_matches_sorted_reference);
    RUN_TEST(test_vl_latency_percentile_rank_boundaries);
    RUN_TEST(test_vl_latency_percentile_capped_at_max);
    RUN_TEST(test_vl_latency_print_writes_summary);
    return UNITY_END();
}
