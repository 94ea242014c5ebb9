/*
 * Tests of the spinner that keeps a CPU awake (platform/vl_awake): it runs pinned to its CPU at
 * SCHED_IDLE, spins until stopped, and a CPU that does not exist starts nothing. Nothing here
 * depends on timing beyond "the count grows within a generous bound".
 */
#define _GNU_SOURCE /* pthread_getaffinity_np, SCHED_IDLE, CPU_COUNT */
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "unity.h"
#include "vl_awake.h"

#define GROW_TIMEOUT_MS 20000 /* a SCHED_IDLE thread on a loaded machine may wait long for its CPU */

void setUp(void)
{
}

void tearDown(void)
{
}

static void sleep_ms(long ms)
{
    struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
    while (nanosleep(&t, &t) != 0) {
    }
}

/* Threads of this process, from /proc/self/status; -1 unreadable. */
static int thread_count(void)
{
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    int n = -1;
    while (f != NULL && fgets(line, sizeof(line), f) != NULL) {
        if (sscanf(line, "Threads: %d", &n) == 1) {
            break;
        }
    }
    if (f != NULL) {
        fclose(f);
    }
    return n;
}

/* The thread count once it has settled at @p want (or after GROW_TIMEOUT_MS): a joined thread
 * leaves /proc/self/status a moment after pthread_join returns (the kernel wakes the joiner when
 * the thread clears its tid, before it has left the thread group). */
static int thread_count_settled(int want)
{
    int n = thread_count();
    for (long waited = 0; n != want && waited < GROW_TIMEOUT_MS; waited += 5) {
        sleep_ms(5);
        n = thread_count();
    }
    return n;
}

/* Waits until the spinner's count passes @p above; 1 when it did within GROW_TIMEOUT_MS. */
static int grows_past(const vl_awake_t *a, uint64_t above)
{
    for (long waited = 0; waited < GROW_TIMEOUT_MS; waited += 5) {
        if (vl_awake_loops(a) > above) {
            return 1;
        }
        sleep_ms(5);
    }
    return 0;
}

void test_spins_on_its_cpu_at_sched_idle_until_stopped(void)
{
    static vl_awake_t a;
    char msg[160];
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, vl_awake_start(&a, 0, msg, sizeof(msg)), msg);
    TEST_ASSERT_TRUE(vl_awake_running(&a));
    TEST_ASSERT_NOT_NULL(strstr(msg, "CPU 0"));
    /* Counted while it runs, not before the start: a sanitizer's runtime may add a thread of its
       own at the first pthread_create. */
    const int threads = thread_count();
    TEST_ASSERT_TRUE(threads >= 2);

    int policy = -1;
    struct sched_param sp;
    TEST_ASSERT_EQUAL_INT(0, pthread_getschedparam(a.thread, &policy, &sp));
    TEST_ASSERT_EQUAL_INT(SCHED_IDLE, policy);
    TEST_ASSERT_EQUAL_INT(0, sp.sched_priority);
    cpu_set_t set;
    CPU_ZERO(&set);
    TEST_ASSERT_EQUAL_INT(0, pthread_getaffinity_np(a.thread, sizeof(set), &set));
    TEST_ASSERT_EQUAL_INT(1, CPU_COUNT(&set));
    TEST_ASSERT_TRUE(CPU_ISSET(0, &set));

    TEST_ASSERT_TRUE_MESSAGE(grows_past(&a, 0), "the spinner never counted a loop");
    const uint64_t first = vl_awake_loops(&a);
    TEST_ASSERT_TRUE_MESSAGE(grows_past(&a, first), "the spinner stopped counting while running");

    vl_awake_stop(&a);
    TEST_ASSERT_FALSE(vl_awake_running(&a));
    TEST_ASSERT_EQUAL_INT(threads - 1, thread_count_settled(threads - 1));
    const uint64_t stopped = vl_awake_loops(&a);
    TEST_ASSERT_TRUE(stopped > first);
    sleep_ms(20);
    TEST_ASSERT_EQUAL_UINT64(stopped, vl_awake_loops(&a));
    vl_awake_stop(&a); /* again: nothing to do */
    TEST_ASSERT_FALSE(vl_awake_running(&a));
}

void test_a_cpu_that_does_not_exist_starts_nothing(void)
{
    static vl_awake_t a;
    char msg[160] = "";
    const int threads = thread_count();
    const long ncpu = sysconf(_SC_NPROCESSORS_CONF);
    const int bad[] = {(int)ncpu, -1, CPU_SETSIZE};
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); ++i) {
        TEST_ASSERT_EQUAL_INT(-1, vl_awake_start(&a, bad[i], msg, sizeof(msg)));
        TEST_ASSERT_NOT_NULL_MESSAGE(strstr(msg, "outside"), msg);
        TEST_ASSERT_FALSE(vl_awake_running(&a));
        TEST_ASSERT_EQUAL_UINT64(0, vl_awake_loops(&a));
        TEST_ASSERT_EQUAL_INT(threads, thread_count());
        vl_awake_stop(&a); /* a failed handle: nothing to do */
    }
    TEST_ASSERT_EQUAL_INT(-1, vl_awake_start(&a, (int)ncpu, NULL, 0)); /* no message asked for */
}

void test_stop_on_a_zeroed_handle_is_safe(void)
{
    static vl_awake_t a; /* zeroed */
    vl_awake_stop(&a);
    vl_awake_stop(NULL);
    TEST_ASSERT_FALSE(vl_awake_running(&a));
    TEST_ASSERT_EQUAL_UINT64(0, vl_awake_loops(&a));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_spins_on_its_cpu_at_sched_idle_until_stopped);
    RUN_TEST(test_a_cpu_that_does_not_exist_starts_nothing);
    RUN_TEST(test_stop_on_a_zeroed_handle_is_safe);
    return UNITY_END();
}
