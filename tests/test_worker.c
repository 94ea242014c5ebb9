/*
 * The worker thread (platform/vl_worker) and the core's parallel update: every
 * index of a loop runs once, the two threads really run at the same time, and
 * an update shared with the worker gives the serial update's bits, alone on
 * random covariances and through a session over the sample log.
 */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "unity.h"
#include "vislam/vislam.h"
#include "vl_clock.h"
#include "vl_linalg.h"
#include "vl_log_reader.h"
#include "vl_random_update.h"
#include "vl_session.h"
#include "vl_worker.h"

#define LD VL_COV_LD
#define MAX_ROWS (VL_OBS_DIM * VL_MAX_LANDMARKS)

static vl_worker_t worker;

void setUp(void)
{
    vl_worker_options_t o;
    vl_worker_options_default(&o);
    o.threads = 2;
    char msg[256];
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, vl_worker_start(&worker, &o, msg, sizeof(msg)), msg);
    TEST_ASSERT_TRUE(vl_worker_running(&worker));
}

void tearDown(void)
{
    vl_worker_stop(&worker);
    TEST_ASSERT_FALSE(vl_worker_running(&worker));
}

/* ------------------------------------------------------------ the loop */

typedef struct {
    uint32_t runs[1000];
    pthread_t caller;
    uint32_t on_other_thread;
} count_arg_t;

static void count_task(void *arg, uint32_t index)
{
    count_arg_t *c = (count_arg_t *)arg;
    __atomic_add_fetch(&c->runs[index], 1u, __ATOMIC_RELAXED);
    if (!pthread_equal(pthread_self(), c->caller)) {
        __atomic_add_fetch(&c->on_other_thread, 1u, __ATOMIC_RELAXED);
    }
}

void test_every_index_runs_once_per_loop(void)
{
    static count_arg_t c;
    memset(&c, 0, sizeof(c));
    c.caller = pthread_self();
    const uint32_t loops = 200, count = 1000;
    for (uint32_t l = 0; l < loops; ++l) {
        vl_worker_parallel_for(&worker, count_task, &c, count);
        for (uint32_t i = 0; i < count; ++i) {
            TEST_ASSERT_EQUAL_UINT32(l + 1, c.runs[i]); /* all done on return, none twice */
        }
    }
    uint64_t n_loops, tasks, worker_tasks;
    vl_worker_counts(&worker, &n_loops, &tasks, &worker_tasks);
    TEST_ASSERT_EQUAL_UINT64(loops, n_loops);
    TEST_ASSERT_EQUAL_UINT64((uint64_t)loops * count, tasks);
    TEST_ASSERT_EQUAL_UINT64(c.on_other_thread, worker_tasks);
}

/* Two tasks that each wait (up to 5 s) for the other to start: only two threads at once pass. */
typedef struct {
    uint32_t started;
    uint32_t met;
} meet_arg_t;

static void meet_task(void *arg, uint32_t index)
{
    (void)index;
    meet_arg_t *m = (meet_arg_t *)arg;
    __atomic_add_fetch(&m->started, 1u, __ATOMIC_SEQ_CST);
    const int64_t until = vl_clock_monotonic_us() + 5000000;
    while (__atomic_load_n(&m->started, __ATOMIC_SEQ_CST) < 2u && vl_clock_monotonic_us() < until) {
    }
    if (__atomic_load_n(&m->started, __ATOMIC_SEQ_CST) >= 2u) {
        __atomic_add_fetch(&m->met, 1u, __ATOMIC_SEQ_CST);
    }
}

void test_the_worker_runs_beside_the_caller(void)
{
    meet_arg_t m = {0u, 0u};
    vl_worker_parallel_for(&worker, meet_task, &m, 2);
    TEST_ASSERT_EQUAL_UINT32(2, m.met);
}

void test_one_thread_runs_the_loop_on_the_caller(void)
{
    vl_worker_t serial;
    vl_worker_options_t o;
    vl_worker_options_default(&o);
    TEST_ASSERT_EQUAL_INT(1, o.threads);
    TEST_ASSERT_EQUAL_INT(0, vl_worker_start(&serial, &o, NULL, 0));
    TEST_ASSERT_FALSE(vl_worker_running(&serial));
    static count_arg_t c;
    memset(&c, 0, sizeof(c));
    c.caller = pthread_self();
    vl_worker_parallel_for(&serial, count_task, &c, 100);
    TEST_ASSERT_EQUAL_UINT32(1, c.runs[0]);
    TEST_ASSERT_EQUAL_UINT32(1, c.runs[99]);
    TEST_ASSERT_EQUAL_UINT32(0, c.on_other_thread);
    vl_worker_stop(&serial);
}

void test_shared_options_parse(void)
{
    vl_worker_options_t o;
    vl_worker_options_default(&o);
    TEST_ASSERT_EQUAL_INT(1, vl_worker_parse_option("t", "--threads", "2", &o));
    TEST_ASSERT_EQUAL_INT(2, o.threads);
    TEST_ASSERT_EQUAL_INT(1, vl_worker_parse_option("t", "--worker-cpu", "0", &o));
    TEST_ASSERT_EQUAL_INT(0, o.cpu);
    TEST_ASSERT_EQUAL_INT(0, vl_worker_parse_option("t", "--cpu", "1", &o));
    TEST_ASSERT_EQUAL_INT(-1, vl_worker_parse_option("t", "--threads", "3", &o));
    TEST_ASSERT_EQUAL_INT(-1, vl_worker_parse_option("t", "--threads", NULL, &o));
    TEST_ASSERT_EQUAL_INT(-1, vl_worker_parse_option("t", "--worker-cpu", "x", &o));
}

/* ------------------------------------------------------------ the update */

static double P0[LD * LD], P_serial[LD * LD], P_parallel[LD * LD], G[LD * VL_RANDOM_FACTOR_RANK];
static double PHt[LD * MAX_ROWS], S[MAX_ROWS * MAX_ROWS], dx_serial[LD], dx_parallel[LD];
static vl_obs_row_t obs[VL_MAX_LANDMARKS];

void test_update_with_the_worker_equals_the_serial_update_bit_for_bit(void)
{
    /* Sizes on and off the block edges (32-column panels, 96-row blocks), up to the full window. */
    static const int cases[][2] = {{18, 1}, {54, 5}, {111, 12}, {186, 17}, {294, 40}, {390, 56}, {390, 128}};
    unsigned state = 7u;
    uint64_t worker_before = 0, loops_before = 0, unused_tasks;
    vl_worker_counts(&worker, &loops_before, &unused_tasks, &worker_before);
    for (size_t c = 0; c < sizeof(cases) / sizeof(cases[0]); ++c) {
        const int n = cases[c][0], k = cases[c][1];
        vl_random_covariance(P0, LD, n, G, &state);
        vl_random_observations(obs, n, k, &state);
        const size_t bytes = sizeof(double) * (size_t)LD * (size_t)n;
        memcpy(P_serial, P0, bytes);
        memcpy(P_parallel, P0, bytes);
        const vl_la_workspace_t serial = {PHt, S, dx_serial, NULL, NULL};
        const vl_la_workspace_t parallel = {PHt, S, dx_parallel, vl_worker_parallel_for, &worker};
        TEST_ASSERT_EQUAL_INT(0, vl_la_update(P_serial, LD, n, obs, k, &serial, NULL));
        TEST_ASSERT_EQUAL_INT(0, vl_la_update(P_parallel, LD, n, obs, k, &parallel, NULL));
        TEST_ASSERT_EQUAL_INT_MESSAGE(0, memcmp(P_serial, P_parallel, bytes), "covariance");
        TEST_ASSERT_EQUAL_INT_MESSAGE(0, memcmp(dx_serial, dx_parallel, sizeof(double) * (size_t)n), "correction");
        TEST_ASSERT_TRUE(memcmp(P_serial, P0, bytes) != 0); /* the update did something */
    }
    uint64_t worker_after = 0, loops_after = 0;
    vl_worker_counts(&worker, &loops_after, &unused_tasks, &worker_after);
    /* Loops of 8 Mflop or more are shared: both of the two full-window cases' (whitening n m^2,
     * landmark downdate (n - 15)^2 m), the downdate alone at n = 294 and k = 40 (9.4 against 4.3
     * Mflop), the rest serial. */
    TEST_ASSERT_EQUAL_UINT64(5, loops_after - loops_before);
    printf("the worker ran %llu blocks of these updates\n", (unsigned long long)(worker_after - worker_before));
}

/* ------------------------------------------------------------ a session */

static vl_estimator_t est_serial, est_parallel;
static vl_session_t s_serial, s_parallel;
static vl_log_reader_t reader;
static vl_log_event_t ev;

void test_session_with_the_worker_gives_the_serial_run_bit_for_bit(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_session_options_t so;
    memset(&so, 0, sizeof(so));
    so.program = "test_worker";
    so.quiet = 1;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_init(&s_serial, &est_serial, &cfg, &so));
    so.worker = &worker;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_init(&s_parallel, &est_parallel, &cfg, &so));
    TEST_ASSERT_TRUE(vl_session_config(&s_parallel)->parallel_for == vl_worker_parallel_for);
    TEST_ASSERT_NULL(vl_session_config(&s_serial)->parallel_for);

    char err[256];
    TEST_ASSERT_EQUAL_INT_MESSAGE(
        0, vl_log_reader_open(&reader, VL_SOURCE_DIR "/data/sample.lcmlog", NULL, err, sizeof(err)), err);
    uint64_t updates = 0, deferred = 0, w0 = 0, w1 = 0, unused_loops, unused_tasks;
    uint32_t largest = 0;
    vl_worker_counts(&worker, &unused_loops, &unused_tasks, &w0);
    /* The first 60 frames: the window fills from the second frame, so the updates are large
       enough to be shared (the whole log would take 15 s under the sanitizers). */
    while (updates < 60 && vl_log_reader_next(&reader, &ev) != VL_LOG_EVENT_END) {
        vl_status_t a = VL_OK, b = VL_OK;
        const vl_session_step_t step = vl_session_input(&s_serial, &ev, &a);
        TEST_ASSERT_EQUAL_INT(step, vl_session_input(&s_parallel, &ev, &b));
        TEST_ASSERT_EQUAL_INT(a, b);
        if (step != VL_SESSION_STEP_UPDATE) {
            continue;
        }
        ++updates;
        /* What the work bound deferred goes through the same shared loops after the pose. */
        TEST_ASSERT_EQUAL_UINT32(vl_deferred_pending(&est_serial), vl_deferred_pending(&est_parallel));
        deferred += vl_deferred_pending(&est_parallel) > 0;
        TEST_ASSERT_EQUAL_INT(vl_session_finish(&s_serial), vl_session_finish(&s_parallel));
        TEST_ASSERT_EQUAL_UINT32(vl_state_dim(&est_serial), vl_state_dim(&est_parallel));
        largest = vl_state_dim(&est_parallel) > largest ? vl_state_dim(&est_parallel) : largest;
        TEST_ASSERT_EQUAL_INT(0, memcmp(est_serial.P, est_parallel.P, sizeof(est_serial.P)));
        TEST_ASSERT_EQUAL_INT(0, memcmp(est_serial.R, est_parallel.R, sizeof(est_serial.R)));
        TEST_ASSERT_EQUAL_INT(0, memcmp(est_serial.p, est_parallel.p, sizeof(est_serial.p)));
        TEST_ASSERT_EQUAL_INT(
            0, memcmp(est_serial.landmark_state, est_parallel.landmark_state, sizeof(est_serial.landmark_state)));
    }
    vl_log_reader_close(&reader);
    vl_worker_counts(&worker, &unused_loops, &unused_tasks, &w1);
    printf("sample log: %llu updates identical (%llu with a deferred update after the pose); the worker ran %llu "
           "blocks\n",
           (unsigned long long)updates, (unsigned long long)deferred, (unsigned long long)(w1 - w0));
    TEST_ASSERT_EQUAL_UINT64(60, updates);
    TEST_ASSERT_TRUE(deferred > 0);
    TEST_ASSERT_TRUE(w1 > w0);       /* the worker took part */
    TEST_ASSERT_TRUE(largest > 300); /* the window filled: many blocks per update */
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_every_index_runs_once_per_loop);
    RUN_TEST(test_the_worker_runs_beside_the_caller);
    RUN_TEST(test_one_thread_runs_the_loop_on_the_caller);
    RUN_TEST(test_shared_options_parse);
    RUN_TEST(test_update_with_the_worker_equals_the_serial_update_bit_for_bit);
    RUN_TEST(test_session_with_the_worker_gives_the_serial_run_bit_for_bit);
    return UNITY_END();
}
