/*
 * Tests of the predictive wake's predictor (platform/vl_warm): when the next frame is due, from
 * the frames' own times and arrivals, and when it predicts nothing. Times are the caller's, so
 * nothing here sleeps or reads a clock.
 */
#include <stdint.h>
#include <string.h>

#include "unity.h"
#include "vl_warm.h"

#define PERIOD 100000 /* us: a 10 Hz camera */

void setUp(void)
{
}

void tearDown(void)
{
}

/* Frames at PERIOD from utime 1 s, arriving at arrival0 + their offset (+ jitter of frame k). */
static void feed(vl_warm_t *w, int frames, int64_t arrival0, const int64_t *jitter)
{
    for (int k = 0; k < frames; ++k) {
        const int64_t offset = (int64_t)k * PERIOD;
        vl_warm_note_frame(w, 1000000 + offset, arrival0 + offset + (jitter != NULL ? jitter[k] : 0));
    }
}

void test_off_or_too_few_frames_predict_nothing(void)
{
    vl_warm_t w;
    int64_t from = 0, until = 0;
    vl_warm_init(&w, 0);
    feed(&w, 5, 7000, NULL);
    TEST_ASSERT_EQUAL_INT(0, vl_warm_window(&w, 0, &from, &until));
    vl_warm_init(&w, 1000);
    feed(&w, 1, 7000, NULL);
    TEST_ASSERT_EQUAL_INT(0, vl_warm_window(&w, 0, &from, &until));
    feed(&w, 2, 7000, NULL); /* the second frame gives the first interval */
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&w, 0, &from, &until));
}

void test_the_window_is_around_the_last_arrival_plus_the_period(void)
{
    vl_warm_t w;
    vl_warm_init(&w, 1000);
    feed(&w, 4, 7000, NULL);
    TEST_ASSERT_EQUAL_INT64(PERIOD, w.period_us);
    int64_t from = 0, until = 0;
    const int64_t last = 7000 + 3 * PERIOD;
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&w, last + 10, &from, &until));
    TEST_ASSERT_EQUAL_INT64(last + PERIOD - 1000, from);
    TEST_ASSERT_EQUAL_INT64(last + PERIOD + 1000, until);
    /* Inside it still; over once the frame is later than warm_us after it was due. */
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&w, until - 1, &from, &until));
    TEST_ASSERT_EQUAL_INT(0, vl_warm_window(&w, until, &from, &until));
}

void test_the_period_is_the_median_so_a_dropped_frame_does_not_move_it(void)
{
    vl_warm_t w;
    vl_warm_init(&w, 1000);
    feed(&w, 6, 0, NULL);
    vl_warm_note_frame(&w, 1000000 + 7 * PERIOD, 7 * PERIOD); /* frame 6 never came */
    TEST_ASSERT_EQUAL_INT64(PERIOD, w.period_us);
    /* The arrival jitter moves the next window with the last arrival, not the period. */
    vl_warm_t j;
    vl_warm_init(&j, 1000);
    const int64_t jitter[4] = {0, 30, -20, 55};
    feed(&j, 4, 0, jitter);
    TEST_ASSERT_EQUAL_INT64(PERIOD, j.period_us);
    int64_t from = 0, until = 0;
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&j, 0, &from, &until));
    TEST_ASSERT_EQUAL_INT64(3 * PERIOD + 55 + PERIOD - 1000, from);
}

void test_a_period_under_four_warm_times_is_not_warmed(void)
{
    vl_warm_t w;
    int64_t from = 0, until = 0;
    vl_warm_init(&w, PERIOD / 4 + 1);
    feed(&w, 3, 0, NULL);
    TEST_ASSERT_EQUAL_INT(0, vl_warm_window(&w, 0, &from, &until));
    vl_warm_init(&w, PERIOD / 4);
    feed(&w, 3, 0, NULL);
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&w, 0, &from, &until));
    /* warm_us is clamped to VL_WARM_MAX_US. */
    vl_warm_init(&w, 10 * VL_WARM_MAX_US);
    TEST_ASSERT_EQUAL_INT64(VL_WARM_MAX_US, w.warm_us);
}

void test_time_that_does_not_advance_restarts_the_period(void)
{
    vl_warm_t w;
    int64_t from = 0, until = 0;
    vl_warm_init(&w, 1000);
    feed(&w, 4, 0, NULL);
    vl_warm_note_frame(&w, 5, 4 * PERIOD); /* a new log, or a restarted sensor */
    TEST_ASSERT_EQUAL_INT64(0, w.period_us);
    TEST_ASSERT_EQUAL_INT(0, vl_warm_window(&w, 0, &from, &until));
    vl_warm_note_frame(&w, 5 + 2 * PERIOD, 6 * PERIOD); /* the new period, from the new timeline only */
    TEST_ASSERT_EQUAL_INT64(2 * PERIOD, w.period_us);
    TEST_ASSERT_EQUAL_INT(1, vl_warm_window(&w, 0, &from, &until));
    TEST_ASSERT_EQUAL_INT64(6 * PERIOD + 2 * PERIOD - 1000, from);
}

void test_a_frame_is_due_from_an_eighth_of_a_period_before_its_time(void)
{
    vl_warm_t w;
    vl_warm_init(&w, 0); /* the prediction of the frame's time holds with warming off */
    TEST_ASSERT_EQUAL_INT(0, vl_warm_frame_due(&w, 5000000));
    feed(&w, 3, 0, NULL);
    const int64_t next = 1000000 + 3 * PERIOD; /* the next frame's time */
    TEST_ASSERT_EQUAL_INT(1, vl_warm_frame_due(&w, next));
    TEST_ASSERT_EQUAL_INT(1, vl_warm_frame_due(&w, next + 5 * PERIOD)); /* overdue */
    TEST_ASSERT_EQUAL_INT(1, vl_warm_frame_due(&w, next - PERIOD / 8));
    TEST_ASSERT_EQUAL_INT(0, vl_warm_frame_due(&w, next - PERIOD / 8 - 1));
    TEST_ASSERT_EQUAL_INT(0, vl_warm_frame_due(&w, next - PERIOD / 2)); /* an IMU sample between frames */
}

void test_touch_reads_one_byte_of_every_line(void)
{
    static unsigned char buf[64 * 100 + 10];
    memset(buf, 0, sizeof(buf));
    uint64_t want = 0;
    for (size_t i = 0; i < sizeof(buf); ++i) {
        buf[i] = (unsigned char)(i % 251);
        want += (i % 64 == 0) ? buf[i] : 0;
    }
    TEST_ASSERT_EQUAL_UINT64(want, vl_warm_touch(buf, sizeof(buf)));
    TEST_ASSERT_EQUAL_UINT64(0, vl_warm_touch(buf, 0));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_off_or_too_few_frames_predict_nothing);
    RUN_TEST(test_the_window_is_around_the_last_arrival_plus_the_period);
    RUN_TEST(test_the_period_is_the_median_so_a_dropped_frame_does_not_move_it);
    RUN_TEST(test_a_period_under_four_warm_times_is_not_warmed);
    RUN_TEST(test_time_that_does_not_advance_restarts_the_period);
    RUN_TEST(test_a_frame_is_due_from_an_eighth_of_a_period_before_its_time);
    RUN_TEST(test_touch_reads_one_byte_of_every_line);
    return UNITY_END();
}
