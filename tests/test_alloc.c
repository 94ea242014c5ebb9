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
#include "vl_log_reader.h"

/* ------------------------------------------------------------ the interposer */

extern void *__libc_malloc(size_t size);
extern void *__libc_calloc(size_t n, size_t size);
extern void *__libc_realloc(void *p, size_t size);
extern void *__libc_memalign(size_t alignment, size_t size);
extern void __libc_free(void *p);

static volatile int counting;
static volatile uint64_t allocations;

void *malloc(size_t size)
{
    if (counting) {
        allocations++;
    }
    return __libc_malloc(size);
}

void *calloc(size_t n, size_t size)
{
    if (counting) {
        allocations++;
    }
    return __libc_calloc(n, size);
}

void *realloc(void *p, size_t size)
{
    if (counting) {
        allocations++;
    }
    return __libc_realloc(p, size);
}

void *memalign(size_t alignment, size_t size)
{
    if (counting) {
        allocations++;
    }
    return __libc_memalign(alignment, size);
}

void *aligned_alloc(size_t alignment, size_t size)
{
    return memalign(alignment, size);
}

int posix_memalign(void **out, size_t alignment, size_t size)
{
    void *p = memalign(alignment, size);
    if (p == NULL) {
        return 12; /* ENOMEM */
    }
    *out = p;
    return 0;
}

void free(void *p)
{
    if (counting && p != NULL) {
        allocations++; /* a free inside a step means something allocated */
    }
    __libc_free(p);
}

/* ------------------------------------------------------------ the runs */

static vl_estimator_t est;
static vl_log_reader_t reader;
static vl_log_event_t ev;

typedef struct {
    uint64_t steps;
    uint64_t allocations;
    uint64_t landmarks;
} alloc_run_t;

static void count_landmark(void *user, const vl_landmark_t *lm)
{
    (void)lm;
    ((alloc_run_t *)user)->landmarks++;
}

static int run_log(const char *path, alloc_run_t *out)
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
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
            initialized = 1;
            continue;
        }
        if (!initialized || (kind != VL_LOG_EVENT_IMU && kind != VL_LOG_EVENT_FRAME)) {
            continue;
        }
        counting = 1;
        vl_status_t st = (kind == VL_LOG_EVENT_IMU) ? vl_propagate(&est, &ev.imu) : vl_update(&est, &ev.frame);
        vl_pose_t pose;
        vl_get_pose(&est, &pose);
        counting = 0;
        TEST_ASSERT_TRUE(st >= 0);
        out->steps++;
    }
    counting = 1;
    vl_flush_landmarks(&est);
    counting = 0;
    out->allocations = allocations;
    vl_log_reader_close(&reader);
    return initialized ? 0 : -1;
}

void setUp(void)
{
    allocations = 0;
}

void tearDown(void)
{
}

void test_interposer_counts_allocations(void)
{
    counting = 1;
    void *p = malloc(64);
    free(p);
    counting = 0;
    TEST_ASSERT_EQUAL_UINT64(2, allocations);
}

static void check_log(const char *path)
{
    alloc_run_t run;
    if (access(path, R_OK) != 0) {
        char msg[512];
        snprintf(msg, sizeof(msg), "%s not found: ../shared/data is absent, real-data allocation check skipped", path);
        TEST_IGNORE_MESSAGE(msg);
    }
    TEST_ASSERT_EQUAL_INT(0, run_log(path, &run));
    printf("%s: %llu steps, %llu landmarks mapped, %llu heap allocations inside steps\n", path,
           (unsigned long long)run.steps, (unsigned long long)run.landmarks, (unsigned long long)run.allocations);
    TEST_ASSERT_TRUE(run.steps > 100);
    TEST_ASSERT_TRUE(run.landmarks > 100);
    TEST_ASSERT_EQUAL_UINT64(0, run.allocations);
}

void test_steps_allocate_nothing_on_the_sample_log(void)
{
    check_log(VL_SOURCE_DIR "/data/sample.lcmlog");
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
    RUN_TEST(test_steps_allocate_nothing_on_0034);
    RUN_TEST(test_steps_allocate_nothing_on_0027);
    return UNITY_END();
}
