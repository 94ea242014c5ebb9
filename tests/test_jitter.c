/* Tests of the scheduling-jitter probe (platform/vl_jitter). */
#define _POSIX_C_SOURCE 200809L /* nanosleep */

#include <stdint.h>
#include <time.h>

#include "unity.h"
#include "vl_jitter.h"

static vl_jitter_t g_j;

void setUp(void)
{
}

void tearDown(void)
{
}

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) != 0) {
    }
}

void test_each_probe_wakes_on_its_cpu_and_records_its_lateness(void)
{
    TEST_ASSERT_EQUAL_INT(1, vl_jitter_start(&g_j, 1, 0));
    sleep_ms(200);
    vl_jitter_stop(&g_j);
    const vl_jitter_probe_t *p = &g_j.probes[0];
    TEST_ASSERT_EQUAL_INT(0, p->cpu);
    TEST_ASSERT_TRUE(p->pinned);
    TEST_ASSERT_FALSE(p->fifo); /* not asked for */
    /* 200 ms at 1 kHz: about 200 wake-ups; a busy machine may swallow some (a late one skips ahead). */
    TEST_ASSERT_TRUE(vl_latency_count(&p->late) >= 20);
    TEST_ASSERT_TRUE(vl_latency_count(&p->late) <= 201);
    TEST_ASSERT_TRUE(p->late.min >= 0);
    TEST_ASSERT_TRUE(vl_latency_max(&p->late) >= p->late.min);
    /* Stopped: nothing more is recorded. */
    const uint64_t n = vl_latency_count(&p->late);
    sleep_ms(20);
    TEST_ASSERT_EQUAL_UINT64(n, vl_latency_count(&p->late));
}

void test_merged_histogram_is_the_sum_of_the_probes(void)
{
    TEST_ASSERT_EQUAL_INT(2, vl_jitter_start(&g_j, 2, 0));
    sleep_ms(100);
    vl_jitter_stop(&g_j);
    static vl_latency_t merged;
    vl_jitter_merged(&g_j, &merged);
    const vl_latency_t *a = &g_j.probes[0].late, *b = &g_j.probes[1].late;
    TEST_ASSERT_EQUAL_INT(1, g_j.probes[1].cpu);
    TEST_ASSERT_EQUAL_UINT64(vl_latency_count(a) + vl_latency_count(b), vl_latency_count(&merged));
    TEST_ASSERT_EQUAL_INT64(vl_latency_max(a) > vl_latency_max(b) ? vl_latency_max(a) : vl_latency_max(b),
                            vl_latency_max(&merged));
    TEST_ASSERT_EQUAL_INT64(a->min < b->min ? a->min : b->min, merged.min);
    TEST_ASSERT_EQUAL_INT64(vl_latency_percentile(a, 100.0) > vl_latency_percentile(b, 100.0)
                                ? vl_latency_percentile(a, 100.0)
                                : vl_latency_percentile(b, 100.0),
                            vl_latency_percentile(&merged, 100.0));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_each_probe_wakes_on_its_cpu_and_records_its_lateness);
    RUN_TEST(test_merged_histogram_is_the_sum_of_the_probes);
    return UNITY_END();
}
