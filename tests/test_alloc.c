/*
 * Zero heap allocation in the core after vl_init, proven by counting every
 * malloc-family call around each step over whole logs: the sample log in data/
 * and, where ../shared/data is present, the real datasets converted at test
 * time (CTest fixture). The core under test is the checked build, whose Eigen
 * shim also aborts on any heap use of its own.
 */
#define _GNU_SOURCE
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "unity.h"
#include "vislam/vislam.h"
#include "vl_alloc_counter.h"
#include "vl_log_reader.h"
#include "vl_worker.h"

/* ------------------------------------------------------------ the counter */

/*
 * The interposer is tests/support/vl_alloc_counter.c, linked into this test: its
 * malloc family and free count every call. A step's count is the calls during it;
 * a free inside a step means something allocated too.
 */
static uint64_t calls_now(void)
{
    return vl_alloc_counter_allocations() + vl_alloc_counter_frees();
}

/* ------------------------------------------------------------ the runs */

static vl_estimator_t est;
static vl_log_reader_t reader;
static vl_log_event_t ev;

typedef struct {
    uint64_t steps;
    uint64_t allocations;
    uint64_t landmarks;
    uint64_t deferred; /* frames whose deferred observations were applied after them */
} alloc_run_t;

static void count_landmark(void *user, const vl_landmark_t *lm)
{
    (void)lm;
    ((alloc_run_t *)user)->landmarks++;
}

/* With a started worker, the updates share their blocks with it (NULL: serial). */
static int run_log(const char *path, vl_worker_t *worker, alloc_run_t *out)
{
    char err[256];
    memset(out, 0, sizeof(*out));
    if (vl_log_reader_open(&reader, path, NULL, err, sizeof(err)) != 0) {
        return -1;
    }
    int initialized = 0;
    for (;;) {
        vl_log_event_kind_t kind = vl_log_reader_next(&reader, &ev);
        if (kind == VL_LOG_EVENT_END) {
            break;
        }
        if (kind == VL_LOG_EVENT_CALIBRATION && !initialized) {
            vl_config_t cfg;
            vl_config_default(&cfg);
            cfg.calibration = ev.calibration;
            cfg.landmark_sink = count_landmark;
            cfg.landmark_sink_user = out;
            if (worker != NULL) {
                cfg.parallel_for = vl_worker_parallel_for;
                cfg.parallel_ctx = worker;
            }
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
            initialized = 1;
            continue;
        }
        if (!initialized || (kind != VL_LOG_EVENT_IMU && kind != VL_LOG_EVENT_FRAME)) {
            continue;
        }
        const uint64_t before = calls_now();
        vl_status_t st = (kind == VL_LOG_EVENT_IMU) ? vl_propagate(&est, &ev.imu) : vl_update(&est, &ev.frame);
        vl_pose_t pose;
        vl_get_pose(&est, &pose);
        out->deferred += vl_deferred_pending(&est) > 0;
        TEST_ASSERT_TRUE(vl_update_deferred(&est) >= 0);
        out->allocations += calls_now() - before;
        TEST_ASSERT_TRUE(st >= 0);
        out->steps++;
    }
    const uint64_t before = calls_now();
    vl_flush_landmarks(&est);
    out->allocations += calls_now() - before;
    vl_log_reader_close(&reader);
    return initialized ? 0 : -1;
}

void setUp(void)
{
}

void tearDown(void)
{
}

void test_interposer_counts_allocations(void)
{
    const uint64_t before = calls_now();
    void *volatile p = malloc(64);
    free(p);
    TEST_ASSERT_EQUAL_UINT64(2, calls_now() - before);
}

static void check_log_with(const char *path, vl_worker_t *worker)
{
    alloc_run_t run;
    if (access(path, R_OK) != 0) {
        char msg[512];
        snprintf(msg, sizeof(msg), "%s not found: ../shared/data is absent, real-data allocation check skipped", path);
        TEST_IGNORE_MESSAGE(msg);
    }
    TEST_ASSERT_EQUAL_INT(0, run_log(path, worker, &run));
    printf("%s: %llu steps (%llu deferred updates), %llu landmarks mapped, %llu heap allocations inside steps\n", path,
           (unsigned long long)run.steps, (unsigned long long)run.deferred, (unsigned long long)run.landmarks,
           (unsigned long long)run.allocations);
    TEST_ASSERT_TRUE(run.steps > 100);
    TEST_ASSERT_TRUE(run.deferred > 0);
    TEST_ASSERT_TRUE(run.landmarks > 100);
    TEST_ASSERT_EQUAL_UINT64(0, run.allocations);
}

static void check_log(const char *path)
{
    check_log_with(path, NULL);
}

void test_steps_allocate_nothing_on_the_sample_log(void)
{
    check_log(VL_SOURCE_DIR "/data/sample.lcmlog");
}

/* The worker is started (its thread and stack allocated) before counting; the steps then hand it
   blocks and wake it, which must not allocate either. */
void test_steps_allocate_nothing_with_the_worker(void)
{
    static vl_worker_t worker;
    vl_worker_options_t o;
    vl_worker_options_default(&o);
    o.threads = 2;
    TEST_ASSERT_EQUAL_INT(0, vl_worker_start(&worker, &o, NULL, 0));
    TEST_ASSERT_TRUE(vl_worker_running(&worker));
    check_log_with(VL_SOURCE_DIR "/data/sample.lcmlog", &worker);
    uint64_t loops, tasks, worker_tasks;
    vl_worker_counts(&worker, &loops, &tasks, &worker_tasks);
    vl_worker_stop(&worker);
    TEST_ASSERT_TRUE(loops > 100);
    TEST_ASSERT_TRUE(worker_tasks > 0);
}

void test_steps_allocate_nothing_on_0034(void)
{
    check_log(VL_BINARY_DIR "/shared-logs/0034.lcmlog");
}

void test_steps_allocate_nothing_on_0027(void)
{
    check_log(VL_BINARY_DIR "/shared-logs/0027.lcmlog");
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_interposer_counts_allocations);
    RUN_TEST(test_steps_allocate_nothing_on_the_sample_log);
    RUN_TEST(test_steps_allocate_nothing_with_the_worker);
    RUN_TEST(test_steps_allocate_nothing_on_0034);
    RUN_TEST(test_steps_allocate_nothing_on_0027);
    return UNITY_END();
}
