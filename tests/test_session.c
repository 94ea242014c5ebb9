/*
 * Tests of the session every program drives (platform/vl_session): the innovation ratio it
 * publishes, over the run and since the last status mark, against the poses it handed out.
 */
#include <math.h>
#include <string.h>

#include "unity.h"
#include "vl_session.h"
#include "vl_sim.h"

static vl_estimator_t est;
static vl_session_t session;
static vl_sim_t sim;
static vl_log_event_t ev;

/* What on_pose saw of the frames' updates: sum of ratio x rows, and rows; what feed saw deferred. */
typedef struct {
    double nis;
    double rows;
    unsigned frames;
    uint64_t deferred_frames; /* frames whose update deferred observations (finish_frames) */
} seen_t;

static seen_t seen;
static int finish_frames; /* feed calls vl_session_finish after each frame */

static void on_pose(void *user, vl_session_step_t step, int64_t utime, uint64_t sequence, const vl_pose_t *pose)
{
    seen_t *s = (seen_t *)user;
    (void)utime;
    (void)sequence;
    if (step == VL_SESSION_STEP_UPDATE) {
        s->nis += pose->innovation_ratio * (double)pose->innovation_rows;
        s->rows += (double)pose->innovation_rows;
        s->frames++;
    }
}

void setUp(void)
{
    memset(&seen, 0, sizeof(seen));
    finish_frames = 0;
    vl_sim_config_t sc;
    vl_sim_config_default(&sc);
    sc.num_steps = 80;
    sc.pixel_noise = 0.3;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&sim, &sc));
    vl_config_t cfg;
    vl_config_default(&cfg);
    cfg.calibration = sc.calibration;
    vl_session_options_t opt;
    memset(&opt, 0, sizeof(opt));
    opt.program = "test_session";
    opt.quiet = 1;
    opt.config_has_calibration = 1;
    opt.callbacks.on_pose = on_pose;
    opt.callbacks.user = &seen;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_init(&session, &est, &cfg, &opt));
}

void tearDown(void)
{
}

/* Feeds the next `steps` simulated steps (an IMU sample, then its frame); 0 when the drive ended. */
static int feed(unsigned steps)
{
    double R[9], p[3];
    for (unsigned k = 0; k < steps; ++k) {
        vl_imu_sample_t imu;
        memset(&ev, 0, sizeof(ev));
        if (vl_sim_step(&sim, &imu, &ev.frame, R, p) != 0) {
            return 0;
        }
        const vl_stereo_frame_t frame = ev.frame;
        ev.kind = VL_LOG_EVENT_IMU;
        ev.imu = imu;
        vl_session_input(&session, &ev, NULL);
        memset(&ev, 0, sizeof(ev));
        ev.kind = VL_LOG_EVENT_FRAME;
        ev.frame = frame;
        vl_session_input(&session, &ev, NULL);
        if (finish_frames) {
            const uint32_t pending = vl_deferred_pending(&est);
            const uint64_t used = vl_get_counters(&est)->observations_deferred_used;
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_finish(&session));
            TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(&est));
            const uint64_t applied = vl_get_counters(&est)->observations_deferred_used - used;
            if (pending > 0) { /* some, at most those pending (max_deferred_work cuts the rest) */
                seen.deferred_frames++;
                TEST_ASSERT_TRUE(applied > 0 && applied <= pending);
            } else {
                TEST_ASSERT_EQUAL_UINT64(0, applied);
            }
        }
    }
    return 1;
}

/* The status carries what the estimator learned of the velocity sensor: its offsets and position. */
/* What a frame's update deferred under the work bound reaches the state after its pose, through
 * vl_session_finish, and a finish with nothing deferred does nothing. */
void test_finish_applies_what_the_frame_deferred(void)
{
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_finish(&session)); /* nothing yet */
    finish_frames = 1;
    (void)feed(79);
    finish_frames = 0;
    TEST_ASSERT_GREATER_THAN_UINT64(0, seen.deferred_frames);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_session_finish(NULL));
}

void test_the_status_carries_the_learned_offsets_and_sensor_position(void)
{
    vislam_status_t status;
    vl_session_fill_status(&session, &status);
    for (int i = 0; i < 3; ++i) { /* before a pose: none learned, the configured position */
        TEST_ASSERT_EQUAL_DOUBLE(0.0, status.linear_offset[i]);
        TEST_ASSERT_EQUAL_DOUBLE(0.0, status.angular_offset[i]);
        TEST_ASSERT_EQUAL_DOUBLE(0.0, status.velocity_sensor[i]);
    }
    TEST_ASSERT_EQUAL_INT(1, feed(40));
    vl_pose_t pose;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    vl_session_fill_status(&session, &status);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.linear_offset, status.linear_offset, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.angular_offset, status.angular_offset, 3);
    TEST_ASSERT_EQUAL_DOUBLE_ARRAY(pose.velocity_sensor, status.velocity_sensor, 3);
    TEST_ASSERT_TRUE(pose.angular_offset[0] != 0.0 && pose.velocity_sensor[0] != 0.0); /* learned */
}

void test_the_innovation_ratio_is_the_frames_ratios_weighted_by_their_rows(void)
{
    vislam_status_t status;
    vl_session_fill_status(&session, &status);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, status.innovation_ratio); /* no frame yet */
    TEST_ASSERT_EQUAL_DOUBLE(0.0, vl_session_innovation_ratio(&session, 0));

    TEST_ASSERT_EQUAL_INT(1, feed(40));
    TEST_ASSERT_EQUAL_UINT(40, seen.frames);
    TEST_ASSERT_TRUE(seen.rows > 0.0);
    const double run = seen.nis / seen.rows;
    TEST_ASSERT_TRUE(run > 0.0);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12 * run, run, vl_session_innovation_ratio(&session, 0));
    vl_session_fill_status(&session, &status);
    TEST_ASSERT_DOUBLE_WITHIN(1e-12 * run, run, status.innovation_ratio); /* no mark yet: since the start */

    /* A status mark starts a new interval: nothing in it yet, then only the frames after it. */
    vl_session_mark(&session);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, vl_session_innovation_ratio(&session, 1));
    const seen_t before = seen;
    TEST_ASSERT_EQUAL_INT(1, feed(20));
    const double interval = (seen.nis - before.nis) / (seen.rows - before.rows);
    TEST_ASSERT_DOUBLE_WITHIN(1e-9 * interval, interval, vl_session_innovation_ratio(&session, 1));
    vl_session_fill_status(&session, &status);
    TEST_ASSERT_DOUBLE_WITHIN(1e-9 * interval, interval, status.innovation_ratio);
    const double all = seen.nis / seen.rows;
    TEST_ASSERT_DOUBLE_WITHIN(1e-12 * all, all, vl_session_innovation_ratio(&session, 0));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_finish_applies_what_the_frame_deferred);
    RUN_TEST(test_the_status_carries_the_learned_offsets_and_sensor_position);
    RUN_TEST(test_the_innovation_ratio_is_the_frames_ratios_weighted_by_their_rows);
    return UNITY_END();
}
