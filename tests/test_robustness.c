/*
 * The estimator's robustness rules (README "Robustness"): time jumps, new
 * timelines, implausible inputs, the divergence guard and IMU silence. Each
 * test feeds the public API the fault and checks what the rule promises.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "unity.h"
#include "vl_test_util.h"
#include "vislam/vislam.h"
#include "vl_estimator_internal.h"
#include "vl_stereo.h"

static vl_estimator_t est;
static vl_estimator_t twin; /* a fresh estimator fed what the reset one should be equivalent to */

#define T0 VL_TEST_T0_US
#define STEP VL_TEST_STEP_US
#define NUM_POINTS 20

/* The map sink: how many landmarks it received, and their observation times' span. */
static uint32_t mapped;
static int64_t mapped_first_utime, mapped_last_utime;

static void count_sink(void *user, const vl_landmark_t *landmark)
{
    (void)user;
    if (mapped == 0 || landmark->first_utime < mapped_first_utime) {
        mapped_first_utime = landmark->first_utime;
    }
    if (mapped == 0 || landmark->last_utime > mapped_last_utime) {
        mapped_last_utime = landmark->last_utime;
    }
    mapped++;
}

/* A frame of a vehicle standing at the identity pose, seeing NUM_POINTS fixed points ahead. */
static void make_frame(const vl_config_t *cfg, vl_stereo_frame_t *f, int64_t utime)
{
    vl_test_frame_ahead(&cfg->calibration, f, utime, NUM_POINTS, 0);
}

/* A forward-speed-only IMU sample. */
static vl_imu_sample_t imu_at(int64_t utime, double vx)
{
    return vl_test_imu_at(utime, vx, 0.0);
}

/* One step of a standing vehicle: the IMU sample, then the frame at the same time. */
static void step(vl_estimator_t *e, const vl_config_t *cfg, int64_t utime, vl_status_t *imu_st, vl_status_t *frame_st)
{
    static vl_stereo_frame_t frame;
    const vl_imu_sample_t s = imu_at(utime, 0.0);
    *imu_st = vl_propagate(e, &s);
    make_frame(cfg, &frame, utime);
    *frame_st = vl_update(e, &frame);
}

/* Runs n clean steps from utime and expects every one to be used. */
static void clean_steps(vl_estimator_t *e, const vl_config_t *cfg, int64_t utime, int n)
{
    for (int k = 0; k < n; ++k) {
        vl_status_t a, b;
        step(e, cfg, utime + k * STEP, &a, &b);
        TEST_ASSERT_EQUAL_INT(VL_OK, a);
        TEST_ASSERT_EQUAL_INT(VL_OK, b);
    }
}

static void get_pose(const vl_estimator_t *e, vl_pose_t *p)
{
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(e, p));
}

/* Same state, bit for bit: pose, covariance, time. */
static void assert_same_pose(const vl_estimator_t *a, const vl_estimator_t *b)
{
    vl_pose_t pa, pb;
    get_pose(a, &pa);
    get_pose(b, &pb);
    TEST_ASSERT_EQUAL_INT64(pa.utime, pb.utime);
    TEST_ASSERT_EQUAL_MEMORY(pa.rotation, pb.rotation, sizeof(pa.rotation));
    TEST_ASSERT_EQUAL_MEMORY(pa.position, pb.position, sizeof(pa.position));
    TEST_ASSERT_EQUAL_MEMORY(pa.covariance, pb.covariance, sizeof(pa.covariance));
    TEST_ASSERT_EQUAL_UINT32(vl_window_size(a), vl_window_size(b));
}

void setUp(void)
{
}

void tearDown(void)
{
}

/* ------------------------------------------------------------ configuration */

void test_defaults_and_seed_preset_are_valid_and_limits_are_checked(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_config_check(&cfg));
    vl_config_t seed;
    vl_config_preset_seed(&seed);
    seed.calibration = cfg.calibration;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_config_check(&seed));

    vl_config_t bad = cfg;
    bad.max_time_jump = 0.0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.max_time_jump = 2e9; /* its microseconds would not fit the time arithmetic's margin */
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.new_timeline_samples = 1; /* one stray sample must never switch timelines */
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.max_speed = NAN;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.max_rotation_rate = 0.0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.image_margin = -1.0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.max_disparity = 0.0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
    bad = cfg;
    bad.max_imu_silence = INFINITY;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&bad));
}

void test_every_status_has_a_description(void)
{
    for (int s = VL_STATUS_MIN; s <= VL_STATUS_MAX; ++s) {
        TEST_ASSERT_NOT_EQUAL(0, strcmp("unknown status", vl_status_str((vl_status_t)s)));
    }
    TEST_ASSERT_EQUAL_STRING("unknown status", vl_status_str((vl_status_t)(VL_STATUS_MAX + 1)));
    TEST_ASSERT_EQUAL_STRING("unknown status", vl_status_str((vl_status_t)(VL_STATUS_MIN - 1)));
}

/* ------------------------------------------------------------ time */

void test_time_jump_ahead_or_behind_is_refused_and_leaves_the_clock(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&twin, &cfg));
    vl_imu_sample_t s = imu_at(T0, 1.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&twin, &s));

    vl_imu_sample_t ahead = imu_at(T0 + 3600000000LL, 1.0); /* one hour ahead */
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &ahead));
    vl_imu_sample_t behind = imu_at(T0 - 3600000000LL, 1.0);
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &behind));
    static vl_stereo_frame_t frame;
    make_frame(&cfg, &frame, T0 + 3600000000LL);
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_update(&est, &frame));

    vl_pose_t p;
    get_pose(&est, &p);
    TEST_ASSERT_EQUAL_INT64(T0, p.utime); /* the clock did not move */
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(3, c->time_jumps);
    TEST_ASSERT_EQUAL_UINT64(2, c->imu_rejected);
    TEST_ASSERT_EQUAL_UINT64(1, c->frames_rejected);
    TEST_ASSERT_EQUAL_UINT64(0, c->timeline_changes);

    /* The next sample on the real timeline is used as if the jumps never came. */
    for (int k = 1; k <= 3; ++k) {
        s = imu_at(T0 + k * STEP, 1.0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&twin, &s));
    }
    assert_same_pose(&est, &twin);
    get_pose(&est, &p);
    TEST_ASSERT_DOUBLE_WITHIN(1e-9, 0.3, p.position[0]);
}

void test_int64_max_sample_is_refused_and_the_drive_goes_on(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    vl_imu_sample_t s = imu_at(INT64_MAX, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &s));
    s = imu_at(INT64_MIN, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &s));
    clean_steps(&est, &cfg, T0 + 3 * STEP, 3);
    TEST_ASSERT_EQUAL_UINT64(2, vl_get_counters(&est)->time_jumps);
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->resets);
    TEST_ASSERT_EQUAL_UINT64(6, vl_get_counters(&est)->frames_accepted);
}

/*
 * A first sample at an extreme time sets the clock there; the real drive that
 * follows is refused as a jump until it has been a timeline for
 * new_timeline_samples inputs, then the estimator restarts on it, as a fresh
 * estimator started at that sample would be.
 */
static void check_recovery_from_first_sample_at(int64_t first_utime)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = imu_at(first_utime, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));

    int64_t reset_utime = 0;
    for (int k = 0; k < 10 && reset_utime == 0; ++k) {
        vl_status_t a, b;
        step(&est, &cfg, T0 + k * STEP, &a, &b);
        if (a == VL_RESET) {
            reset_utime = T0 + k * STEP;
            TEST_ASSERT_EQUAL_INT(VL_OK, b); /* the frame of the same step is used */
        } else {
            TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, a);
            TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, b);
        }
    }
    TEST_ASSERT_TRUE_MESSAGE(reset_utime != 0, "no re-initialization within 1 s of sensor time");
    TEST_ASSERT_TRUE(reset_utime - T0 <= 1000000);
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->timeline_changes);

    /* From the reset on, exactly a fresh estimator started at that sample. */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&twin, &cfg));
    vl_status_t a, b;
    step(&twin, &cfg, reset_utime, &a, &b);
    TEST_ASSERT_EQUAL_INT(VL_OK, a);
    TEST_ASSERT_EQUAL_INT(VL_OK, b);
    clean_steps(&est, &cfg, reset_utime + STEP, 10);
    clean_steps(&twin, &cfg, reset_utime + STEP, 10);
    assert_same_pose(&est, &twin);
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0); /* tracking: landmarks in the window */
    TEST_ASSERT_EQUAL_UINT64(vl_get_counters(&twin)->observations_used, vl_get_counters(&est)->observations_used);
    TEST_ASSERT_TRUE(vl_get_counters(&est)->observations_used > 0);
}

void test_first_sample_at_int64_min_recovers_within_a_second(void)
{
    check_recovery_from_first_sample_at(INT64_MIN);
}

void test_first_sample_at_int64_max_recovers_within_a_second(void)
{
    check_recovery_from_first_sample_at(INT64_MAX);
}

/* The whole stream moves by shift (a restarted log, a stepped clock): a restart within 1 s of sensor time. */
static void check_new_timeline(int64_t shift, vl_status_t refusal)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.landmark_sink = count_sink;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 20);
    const uint32_t window = vl_window_size(&est);
    TEST_ASSERT_TRUE(window > 0);
    mapped = 0;

    const int64_t start = T0 + 20 * STEP + shift;
    int64_t reset_utime = 0;
    for (int k = 0; k < 10 && reset_utime == 0; ++k) {
        vl_status_t a, b;
        step(&est, &cfg, start + k * STEP, &a, &b);
        if (a == VL_RESET) {
            reset_utime = start + k * STEP;
            TEST_ASSERT_EQUAL_INT(VL_OK, b);
        } else {
            TEST_ASSERT_EQUAL_INT(refusal, a);
            TEST_ASSERT_EQUAL_INT(refusal, b);
        }
    }
    TEST_ASSERT_TRUE_MESSAGE(reset_utime != 0, "no re-initialization within 1 s of sensor time");
    TEST_ASSERT_TRUE(reset_utime - start < 1000000);
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(1, c->timeline_changes);
    TEST_ASSERT_EQUAL_UINT64(1, c->resets);
    TEST_ASSERT_EQUAL_UINT64(0, c->divergence_resets);
    /* The old world's window went to the map before the restart, nothing dropped. */
    TEST_ASSERT_EQUAL_UINT64(0, c->landmarks_discarded);
    TEST_ASSERT_EQUAL_UINT32(window, mapped);
    TEST_ASSERT_EQUAL_UINT64(window, c->landmarks_marginalized);
    TEST_ASSERT_TRUE(mapped_first_utime >= T0 && mapped_last_utime <= T0 + 19 * STEP);
    mapped = 0;
    TEST_ASSERT_EQUAL_UINT64(21, c->imu_accepted); /* 20 before, then the one that started the new timeline */

    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&twin, &cfg));
    vl_status_t a, b;
    step(&twin, &cfg, reset_utime, &a, &b);
    clean_steps(&est, &cfg, reset_utime + STEP, 10);
    clean_steps(&twin, &cfg, reset_utime + STEP, 10);
    assert_same_pose(&est, &twin);
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0);
}

void test_stream_shifted_an_hour_back_reinitializes_and_tracks_again(void)
{
    check_new_timeline(-3600000000LL, VL_ERR_TIME_JUMP);
}

void test_stream_shifted_an_hour_ahead_reinitializes_and_tracks_again(void)
{
    check_new_timeline(3600000000LL, VL_ERR_TIME_JUMP);
}

void test_log_replayed_again_a_few_seconds_back_reinitializes(void)
{
    /* Less than max_time_jump back: refused for time order, and still a new timeline. */
    check_new_timeline(-3000000LL, VL_ERR_TIME_ORDER);
}

void test_stray_samples_and_a_stuck_clock_never_switch_timelines(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 2);
    /* A stray sample one hour ahead, consistent with the previous stray, between every clean step. */
    for (int k = 2; k < 40; ++k) {
        vl_imu_sample_t stray = imu_at(T0 + 3600000000LL + k * STEP, 0.0);
        TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &stray));
        clean_steps(&est, &cfg, T0 + k * STEP, 1);
    }
    /* A clock stuck at INT64_MAX: many refusals in a row, but no timeline. */
    for (int k = 0; k < 20; ++k) {
        vl_imu_sample_t stuck = imu_at(INT64_MAX, 0.0);
        TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_JUMP, vl_propagate(&est, &stuck));
    }
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->timeline_changes);
    TEST_ASSERT_EQUAL_UINT64(58, vl_get_counters(&est)->time_jumps);
    clean_steps(&est, &cfg, T0 + 40 * STEP, 1);
}

/* ------------------------------------------------------------ plausibility */

void test_absurd_imu_samples_are_refused_and_counted(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = imu_at(T0, 1.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_imu_sample_t absurd = imu_at(T0 + STEP, 1e300);
    TEST_ASSERT_EQUAL_INT(VL_ERR_IMPLAUSIBLE, vl_propagate(&est, &absurd));
    absurd = imu_at(T0 + STEP, 0.0);
    absurd.angular_velocity[1] = 36.0; /* over 35 rad/s */
    TEST_ASSERT_EQUAL_INT(VL_ERR_IMPLAUSIBLE, vl_propagate(&est, &absurd));
    absurd = imu_at(T0 + STEP, 0.0);
    absurd.linear_velocity[0] = 60.0;
    absurd.linear_velocity[1] = 90.0; /* each axis under 100 m/s, the speed over it */
    TEST_ASSERT_EQUAL_INT(VL_ERR_IMPLAUSIBLE, vl_propagate(&est, &absurd));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(3, c->imu_implausible);
    TEST_ASSERT_EQUAL_UINT64(3, c->imu_rejected);

    vl_imu_sample_t fast = imu_at(T0 + STEP, 99.0); /* within the limit */
    fast.angular_velocity[2] = 34.0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &fast));
    /* The refused samples left no trace: the pose is that of an estimator never shown them. */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&twin, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&twin, &s));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&twin, &fast));
    vl_pose_t p, q;
    get_pose(&est, &p);
    get_pose(&twin, &q);
    TEST_ASSERT_EQUAL_MEMORY(q.position, p.position, sizeof(p.position));
    TEST_ASSERT_EQUAL_MEMORY(q.rotation, p.rotation, sizeof(p.rotation));
    TEST_ASSERT_TRUE(p.position[0] > 0.0 && p.position[0] < 10.0); /* at most 99 m/s over 0.1 s, not 1e300 */
    TEST_ASSERT_EQUAL_UINT64(3, c->imu_implausible);
}

void test_pixels_outside_the_image_and_absurd_disparity_are_refused(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    const vl_imu_sample_t s = imu_at(T0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    static vl_stereo_frame_t f;
    make_frame(&cfg, &f, T0);
    const double w = 2.0 * cfg.calibration.cx, h = 2.0 * cfg.calibration.cy, m = cfg.image_margin;
    f.obs[0].u_left = w + m + 1.0;                                /* right of the image */
    f.obs[1].v_right = -m - 1.0;                                  /* above it */
    f.obs[2].v_left = h + m + 1.0;                                /* below it */
    f.obs[3].u_left = f.obs[3].u_right + cfg.max_disparity + 1.0; /* nearer than any camera sees */
    f.obs[4].u_left = w + m - 1.0;                                /* inside the margin: plausible */
    f.obs[4].u_right = f.obs[4].u_left - 30.0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(4, c->observations_implausible);
    TEST_ASSERT_EQUAL_UINT64(0, c->observations_invalid);

    /* An explicit image size replaces 2 cx x 2 cy. */
    cfg.image_width = 640.0;
    cfg.image_height = 480.0;
    cfg.image_margin = 0.0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    make_frame(&cfg, &f, T0);
    uint32_t outside = 0;
    for (uint32_t i = 0; i < f.count; ++i) {
        const vl_stereo_obs_t *o = &f.obs[i];
        outside += o->u_left > 640.0 || o->u_right > 640.0 || o->u_left < 0.0 || o->u_right < 0.0 ||
                   o->v_left > 480.0 || o->v_left < 0.0;
    }
    TEST_ASSERT_TRUE(outside > 0 && outside < f.count);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    TEST_ASSERT_EQUAL_UINT64(outside, vl_get_counters(&est)->observations_implausible);
}

/*
 * Step k of a standing vehicle on a sparse frame: the IMU sample, then the first count tracks
 * ahead in f, their stereo rows disagreeing by the white noise of +-0.3 px (so that no frame
 * repeats the one before it).
 */
static void sparse_step(const vl_config_t *cfg, vl_stereo_frame_t *f, int k, uint32_t count)
{
    const vl_imu_sample_t s = imu_at(T0 + k * STEP, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    make_frame(cfg, f, T0 + k * STEP);
    f->count = count;
    for (uint32_t i = 0; i < count; ++i) {
        f->obs[i].v_right += ((i + (uint32_t)k) % 2u) ? 0.3 : -0.3;
    }
}

/*
 * On a sparse frame the two-view velocity noise matching reads every track. A
 * track whose pixels jump 40 px and one whose stereo rows disagree by 30 px
 * neither poison the noise (the stereo rows' estimate moves by a capped share,
 * the velocity noise stays finite and within its bounds) nor stay: both break.
 */
void test_a_sparse_frames_bad_tracks_neither_poison_the_noise_nor_stay(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    static vl_stereo_frame_t f;
    double rows_before = 0.0;
    uint64_t broken_before = 0;
    for (int k = 0; k < 12; ++k) {
        sparse_step(&cfg, &f, k, 8u); /* sparse: under VL_NOISE_DENSE_FRAME */
        if (k == 11) {
            f.obs[2].u_left += 40.0;
            f.obs[2].u_right += 40.0;
            f.obs[5].v_right += 30.0;
        } else if (k == 10) {
            rows_before = est.stereo_row_var;
            broken_before = vl_get_counters(&est)->tracks_inconsistent;
        }
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    }
    TEST_ASSERT_TRUE(rows_before > 0.0);
    TEST_ASSERT_TRUE(est.stereo_row_var < 1.5 * rows_before);
    TEST_ASSERT_TRUE(vl_get_counters(&est)->tracks_inconsistent >= broken_before + 2u);
    vl_pose_t p;
    get_pose(&est, &p);
    TEST_ASSERT_TRUE(isfinite(p.linear_velocity_noise) && isfinite(p.angular_velocity_noise));
    TEST_ASSERT_TRUE(p.linear_velocity_noise <= cfg.linear_velocity_noise * 100.0);
    TEST_ASSERT_TRUE(p.angular_velocity_noise <= cfg.angular_velocity_noise * 100.0);
    for (int i = 0; i < 3; ++i) {
        TEST_ASSERT_TRUE(isfinite(p.position[i]));
    }
}

/*
 * A frame of three tracks cannot judge one against the other two (they leave six
 * rows for six unknowns), so a track on a moving object is absorbed by the
 * frame's motion fit. It moves on in the next frame, where a standing track's
 * motion error is drawn afresh: a track that alone contradicts the expected
 * motion in two frames in a row breaks, and not before the second.
 */
void test_a_moving_track_among_three_breaks_at_its_second_contradiction(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    static vl_stereo_frame_t f;
    uint64_t broken[3] = {0, 0, 0};
    for (int k = 0; k < 23; ++k) {
        sparse_step(&cfg, &f, k, 3u);
        if (k >= 20) { /* track 1 moves sideways, 16 px a frame: over the two-view gate, under the update's */
            f.obs[1].u_left += 16.0 * (double)(k - 19);
            f.obs[1].u_right += 16.0 * (double)(k - 19);
        }
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
        if (k >= 20) {
            broken[k - 20] = vl_get_counters(&est)->tracks_inconsistent;
        }
    }
    TEST_ASSERT_EQUAL_UINT64(0u, broken[0]); /* one contradiction: left out of the fit, kept */
    TEST_ASSERT_EQUAL_UINT64(1u, broken[1]); /* the second in a row: broken */
    TEST_ASSERT_EQUAL_UINT64(2u, broken[2]); /* its restart moves on: broken again */
}

/* Whether the window holds a landmark of track id. */
static int window_holds(const vl_estimator_t *e, int32_t id)
{
    static vl_landmark_t lm[VL_MAX_LANDMARKS];
    size_t n = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(e, lm, VL_MAX_LANDMARKS, &n));
    for (size_t i = 0; i < n; ++i) {
        if (lm[i].id == id) {
            return 1;
        }
    }
    return 0;
}

/*
 * A track that drifts against the velocities' motion by about one std of a frame's expected
 * motion error (4 px a frame sideways, as a far car across the view) never contradicts one
 * frame, but its summed two-view residuals do: it breaks, not before its third frame, and while
 * its id lasts it is neither used nor admitted again. Standing tracks on the same frames, and
 * on 200 frames of their own, never break.
 */
void test_a_track_drifting_against_the_velocities_breaks_and_stays_out(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    static vl_stereo_frame_t f;
    const int start = 20, frames = 60;
    int broke_at = -1;
    for (int k = 0; k < start + frames; ++k) {
        sparse_step(&cfg, &f, k, 3u);
        if (k >= start) {
            f.obs[1].u_left += 4.0 * (double)(k - start + 1);
            f.obs[1].u_right += 4.0 * (double)(k - start + 1);
        }
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &f));
        const uint64_t broken = vl_get_counters(&est)->tracks_inconsistent;
        if (k < start) {
            TEST_ASSERT_EQUAL_UINT64(0u, broken); /* standing tracks */
        } else if (broke_at < 0 && broken > 0u) {
            broke_at = k - start;
            TEST_ASSERT_EQUAL_UINT64(1u, broken);
        }
        if (broke_at >= 0) {
            TEST_ASSERT_FALSE(window_holds(&est, f.obs[1].id)); /* not admitted again */
            TEST_ASSERT_TRUE(window_holds(&est, f.obs[0].id) && window_holds(&est, f.obs[2].id));
        } else if (k >= 1) {
            TEST_ASSERT_TRUE(window_holds(&est, f.obs[1].id)); /* used until then */
        }
    }
    TEST_ASSERT_TRUE(broke_at >= 2);                                          /* its third frame at the earliest */
    TEST_ASSERT_TRUE(broke_at < frames);                                      /* and within the drive */
    TEST_ASSERT_EQUAL_UINT64(1u, vl_get_counters(&est)->tracks_inconsistent); /* once: then ignored */

    /* Standing tracks alone, 200 sparse frames: none breaks. */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    for (int k = 0; k < 200; ++k) {
        sparse_step(&cfg, &f, k, 5u);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    }
    TEST_ASSERT_EQUAL_UINT64(0u, vl_get_counters(&est)->tracks_inconsistent);
}

/* ------------------------------------------------------------ divergence */

void test_non_finite_covariance_from_a_pathological_input_resets_keeping_the_calibration(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.max_speed = 1e308; /* let the absurd velocity through to reach the numerical failure */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    /* The 1e300 m/s: with landmarks in the window, integrating it overflows their covariance. */
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0);
    vl_pose_t before;
    get_pose(&est, &before);
    vl_imu_sample_t absurd = imu_at(T0 + 3 * STEP, 1e300);
    TEST_ASSERT_EQUAL_INT(VL_RESET, vl_propagate(&est, &absurd)); /* interpolated to at once */
    /* The sample that led there does not carry the motion on: the next one restarts it. */
    vl_imu_sample_t next = imu_at(T0 + 4 * STEP, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &next));

    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(1, c->divergence_resets);
    TEST_ASSERT_EQUAL_UINT64(1, c->resets);
    TEST_ASSERT_EQUAL_UINT64(0, c->timeline_changes);
    TEST_ASSERT_EQUAL_MEMORY(&cfg.calibration, &est.cfg.calibration, sizeof(cfg.calibration));
    TEST_ASSERT_EQUAL_DOUBLE(cfg.max_speed, est.cfg.max_speed);
    vl_pose_t p;
    get_pose(&est, &p);                                          /* finite: vl_get_pose refuses otherwise */
    TEST_ASSERT_EQUAL_DOUBLE(before.position[0], p.position[0]); /* where it stood before that sample */
    TEST_ASSERT_EQUAL_INT64(T0 + 4 * STEP, p.utime);             /* the clock is kept */
    TEST_ASSERT_EQUAL_UINT32(0, vl_get_state_flags(&est));

    /* It tracks again from the next sample. */
    clean_steps(&est, &cfg, T0 + 5 * STEP, 5);
    TEST_ASSERT_EQUAL_UINT32(0, vl_get_state_flags(&est));
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0);
}

void test_a_divergence_restarts_at_the_pose_before_the_input_that_diverged(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    /* Offsets and a sensor position as a drive would have learned them (the sensor's, which
     * outlast a divergence). */
    est.offset_linear[1] = -0.07;
    est.offset_angular[2] = 0.005;
    est.sensor_position[0] = -1.5;
    /* Away from the start: 2 m/s forward for three steps, IMU only. */
    for (int k = 3; k < 6; ++k) {
        const vl_imu_sample_t s = imu_at(T0 + k * STEP, 2.0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    }
    vl_pose_t before, after;
    get_pose(&est, &before);
    TEST_ASSERT_TRUE(before.position[0] > 0.5);
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0);
    static double core_before[VL_CORE_DIM * VL_CORE_DIM];
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        memcpy(&core_before[VL_CORE_DIM * j], &est.P[(size_t)j * VL_COV_LD], VL_CORE_DIM * sizeof(double));
    }
    TEST_ASSERT_TRUE(core_before[VL_CORE_DIM * 6 + 0] != 0.0); /* the pose and the offsets are correlated */
    /* A negative variance: the next input's check finds it. */
    est.P[(size_t)4 * VL_COV_LD + 4] = -1e-3;
    const vl_imu_sample_t s = imu_at(T0 + 6 * STEP, 2.0);
    TEST_ASSERT_EQUAL_INT(VL_RESET, vl_propagate(&est, &s));
    get_pose(&est, &after);
    /* The world frame is kept: the pose and its covariance are the ones before that input,
     * to the bit; the window starts empty. */
    TEST_ASSERT_EQUAL_MEMORY(before.rotation, after.rotation, sizeof(before.rotation));
    TEST_ASSERT_EQUAL_MEMORY(before.position, after.position, sizeof(before.position));
    TEST_ASSERT_EQUAL_MEMORY(before.covariance, after.covariance, sizeof(before.covariance));
    TEST_ASSERT_TRUE(after.covariance[0] > 0.0);
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->divergence_resets);
    /* So are the offsets and the sensor position, with the core block of P (pose, parameters and
     * their correlation); the
     * adapted noise starts again from the configured values. */
    TEST_ASSERT_EQUAL_MEMORY(before.linear_offset, after.linear_offset, sizeof(before.linear_offset));
    TEST_ASSERT_EQUAL_MEMORY(before.angular_offset, after.angular_offset, sizeof(before.angular_offset));
    TEST_ASSERT_EQUAL_DOUBLE(-0.07, after.linear_offset[1]);
    TEST_ASSERT_EQUAL_MEMORY(before.velocity_sensor, after.velocity_sensor, sizeof(before.velocity_sensor));
    TEST_ASSERT_EQUAL_DOUBLE(-1.5, after.velocity_sensor[0]);
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        TEST_ASSERT_EQUAL_MEMORY(&core_before[VL_CORE_DIM * j], &est.P[(size_t)j * VL_COV_LD],
                                 VL_CORE_DIM * sizeof(double));
    }
    TEST_ASSERT_EQUAL_DOUBLE(cfg.linear_velocity_noise, after.linear_velocity_noise);
    /* The motion goes on from there with the next sample. */
    const vl_imu_sample_t next = imu_at(T0 + 7 * STEP, 2.0), later = imu_at(T0 + 8 * STEP, 2.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &next));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &later));
    get_pose(&est, &after);
    TEST_ASSERT_TRUE(after.position[0] > before.position[0] + 0.1);
    /* A saved covariance that would not pass the check itself is not carried: the pose
     * restarts certain, as at vl_init, rather than diverge again at once. */
    get_pose(&est, &before);
    est.sound_P[0] = -1.0;
    est.P[(size_t)4 * VL_COV_LD + 4] = -1e-3;
    const vl_imu_sample_t again = imu_at(T0 + 9 * STEP, 2.0);
    TEST_ASSERT_EQUAL_INT(VL_RESET, vl_propagate(&est, &again));
    get_pose(&est, &after);
    TEST_ASSERT_EQUAL_MEMORY(before.position, after.position, sizeof(before.position));
    for (int i = 0; i < 36; ++i) {
        TEST_ASSERT_EQUAL_DOUBLE(0.0, after.covariance[i]);
    }
    /* ... and the offsets at their prior, as at vl_init. */
    TEST_ASSERT_EQUAL_DOUBLE(0.0, after.linear_offset[1]);
    TEST_ASSERT_EQUAL_DOUBLE(cfg.linear_offset_prior * cfg.linear_offset_prior,
                             est.P[(size_t)(VL_IDX_OFFSET_LIN + 1) * VL_COV_LD + VL_IDX_OFFSET_LIN + 1]);
    TEST_ASSERT_EQUAL_UINT64(2, vl_get_counters(&est)->divergence_resets);
    /* A new timeline still starts a new world at the identity (vl_reset likewise). */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_reset(&est));
    get_pose(&est, &after);
    TEST_ASSERT_EQUAL_DOUBLE(0.0, after.position[0]);
}

void test_injected_indefinite_or_nan_covariance_resets_and_no_nan_pose_is_handed_out(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    /* A negative variance: not positive semi-definite. */
    est.P[(size_t)4 * VL_COV_LD + 4] = -1e-3;
    vl_status_t a, b;
    step(&est, &cfg, T0 + 3 * STEP, &a, &b);
    TEST_ASSERT_EQUAL_INT(VL_RESET, a);
    TEST_ASSERT_EQUAL_INT(VL_OK, b);

    /* A correlation beyond 1 in the pose block, diagonal still positive. */
    clean_steps(&est, &cfg, T0 + 4 * STEP, 2);
    const double p00 = est.P[0], p11 = est.P[(size_t)1 * VL_COV_LD + 1];
    TEST_ASSERT_TRUE(p00 > 0.0 && p11 > 0.0);
    /* Far beyond 1, so that the next prediction's added noise cannot dilute it back under. */
    est.P[(size_t)1 * VL_COV_LD] = est.P[1] = 10.0 * sqrt(p00 * p11);
    step(&est, &cfg, T0 + 6 * STEP, &a, &b);
    TEST_ASSERT_EQUAL_INT(VL_RESET, a);

    /* NaN in a landmark's variance, found after the frame that uses it. */
    clean_steps(&est, &cfg, T0 + 7 * STEP, 3);
    TEST_ASSERT_TRUE(vl_window_size(&est) > 0);
    est.P[(size_t)VL_CORE_DIM * VL_COV_LD + VL_CORE_DIM] = NAN;
    static vl_stereo_frame_t f;
    make_frame(&cfg, &f, T0 + 10 * STEP);
    TEST_ASSERT_EQUAL_INT(VL_RESET, vl_update(&est, &f));
    TEST_ASSERT_EQUAL_UINT64(3, vl_get_counters(&est)->divergence_resets);

    /* A NaN pose is never handed out, whatever put it there. */
    est.p[1] = NAN;
    vl_pose_t p;
    TEST_ASSERT_EQUAL_INT(VL_ERR_NON_FINITE, vl_get_pose(&est, &p));
}

/* Step k of a standing vehicle (the IMU sample, then the frame) whose every track jumps 150 px,
 * back and forth from one frame to the next; the frame's status. */
static vl_status_t jumped_step(const vl_config_t *cfg, int k)
{
    const vl_imu_sample_t s = imu_at(T0 + k * STEP, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    static vl_stereo_frame_t f;
    make_frame(cfg, &f, T0 + k * STEP);
    const double shift = (k % 2) ? 150.0 : -150.0;
    for (uint32_t i = 0; i < f.count; ++i) {
        f.obs[i].u_left += shift;
        f.obs[i].u_right += shift;
    }
    return vl_update(&est, &f);
}

void test_frames_contradicting_the_state_frame_after_frame_reset_the_filter(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.adaptive_noise = 0; /* so the contradiction does not widen the noise until it passes */
    cfg.divergence_frames = 6;
    for (int pass = 0; pass < 2; ++pass) {
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
        clean_steps(&est, &cfg, T0, 3);
        TEST_ASSERT_TRUE(vl_window_size(&est) >= 8);
        int resets_at = -1;
        for (int k = 3; k < 30 && resets_at < 0; ++k) {
            const vl_status_t st = jumped_step(&cfg, k);
            if (st == VL_RESET) {
                resets_at = k;
            } else {
                TEST_ASSERT_EQUAL_INT(VL_OK, st);
            }
        }
        if (pass == 0) {
            TEST_ASSERT_EQUAL_INT(3 + 6 - 1, resets_at); /* the sixth contradicting frame in a row */
            TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->divergence_resets);
            TEST_ASSERT_TRUE(vl_get_counters(&est)->landmarks_discarded > 0);
        } else {
            TEST_ASSERT_EQUAL_INT(-1, resets_at); /* divergence_frames = 0: the rule is off */
            TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->divergence_resets);
        }
        cfg.divergence_frames = 0;
    }
}

/* With the noise adapted, frames that keep contradicting the state widen the noise, but only to
 * 20x the configured std: a burst of tracks jumping back and forth is then still distrusted
 * frame after frame, and the divergence rule restarts the filter instead of the pose following
 * the jumps (unbounded, the widening let them through after five frames; README, Robustness). */
void test_contradicting_frames_widen_the_noise_only_so_far(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    int resets_at = -1;
    double widest[3] = {0.0, 0.0, 0.0};
    for (int k = 3; k < 40 && resets_at < 0; ++k) {
        const vl_status_t st = jumped_step(&cfg, k);
        if (st == VL_RESET) {
            resets_at = k;
            break;
        }
        TEST_ASSERT_EQUAL_INT(VL_OK, st);
        vl_pose_t p;
        get_pose(&est, &p);
        widest[0] = fmax(widest[0], p.linear_velocity_noise / cfg.linear_velocity_noise);
        widest[1] = fmax(widest[1], p.angular_velocity_noise / cfg.angular_velocity_noise);
        widest[2] = fmax(widest[2], p.pixel_noise / cfg.pixel_noise);
    }
    for (int i = 0; i < 3; ++i) {
        TEST_ASSERT_TRUE(widest[i] > 4.0);          /* it did widen */
        TEST_ASSERT_TRUE(widest[i] <= 20.0 + 1e-9); /* and stopped */
    }
    TEST_ASSERT_TRUE_MESSAGE(resets_at > 0, "the jumps were followed instead of distrusted");
    TEST_ASSERT_EQUAL_INT(3 + (int)cfg.divergence_frames - 1, resets_at);
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->divergence_resets);
}

void test_vl_reset_keeps_configuration_and_counters(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.max_landmarks = 7;
    cfg.landmark_sink = count_sink;
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_reset(NULL));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    clean_steps(&est, &cfg, T0, 3);
    mapped = 0;
    const uint64_t frames = vl_get_counters(&est)->frames_accepted;
    const uint32_t window = vl_window_size(&est);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_reset(&est));
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT64(frames, vl_get_counters(&est)->frames_accepted);
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->landmarks_discarded);
    TEST_ASSERT_EQUAL_UINT32(window, mapped); /* the window went to the map first */
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->resets);
    TEST_ASSERT_EQUAL_UINT32(7, est.cfg.max_landmarks);
    /* Any time may start again: the clock went with the state. */
    clean_steps(&est, &cfg, T0 - 100 * STEP, 3);
}

/* ------------------------------------------------------------ sensor silence */

void test_frames_without_imu_are_not_propagated_with_a_stale_velocity(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.mode = VL_MODE_IMU_ONLY; /* the frames only move the clock here */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    for (int k = 0; k < 10; ++k) {
        const vl_imu_sample_t s = imu_at(T0 + k * STEP, 10.0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    }
    /* The IMU falls silent at T0 + 0.9 s; frames go on for 10 s. */
    static vl_stereo_frame_t f;
    uint32_t refused = 0;
    for (int k = 10; k < 110; ++k) {
        make_frame(&cfg, &f, T0 + k * STEP);
        const vl_status_t st = vl_update(&est, &f);
        if (k * STEP - 9 * STEP <= 500000) {
            TEST_ASSERT_EQUAL_INT(VL_OK, st); /* within max_imu_silence the held velocity still holds */
            TEST_ASSERT_EQUAL_UINT32(0, vl_get_state_flags(&est));
        } else {
            TEST_ASSERT_EQUAL_INT(VL_ERR_IMU_SILENT, st);
            TEST_ASSERT_EQUAL_UINT32(VL_STATE_IMU_SILENT, vl_get_state_flags(&est));
            refused++;
        }
    }
    vl_pose_t p;
    get_pose(&est, &p);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, 10.0 * 1.4, p.position[0]); /* 0.9 s driven + 0.5 s trusted, not 10.9 s */
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(refused, c->frames_imu_silent);
    TEST_ASSERT_EQUAL_UINT64(1, c->imu_silences);

    /* The IMU comes back: the silence is not integrated either, and tracking resumes. */
    const vl_imu_sample_t back = imu_at(T0 + 110 * STEP, 2.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &back));
    TEST_ASSERT_EQUAL_UINT32(0, vl_get_state_flags(&est));
    get_pose(&est, &p);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, 14.0, p.position[0]);
    TEST_ASSERT_EQUAL_INT64(T0 + 110 * STEP, p.utime);
    make_frame(&cfg, &f, T0 + 111 * STEP);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    get_pose(&est, &p);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, 14.2, p.position[0]); /* the new velocity, 2 m/s for 0.1 s */
    TEST_ASSERT_EQUAL_UINT64(1, c->imu_silences);
}

void test_imu_back_after_a_silence_without_frames_is_not_integrated(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = imu_at(T0, 10.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    s = imu_at(T0 + 3000000, 0.0); /* 3 s later, under max_time_jump */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_pose_t p;
    get_pose(&est, &p);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, 5.0, p.position[0]); /* 0.5 s at 10 m/s, not 30 m */
    /* ... but the covariance takes it: on each axis at least the speed it had, over the 2.5 s */
    for (int i = 0; i < 3; ++i) {
        TEST_ASSERT_TRUE(p.covariance[7 * i] > (10.0 * 2.5) * (10.0 * 2.5));
    }
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->imu_silences);
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->frames_imu_silent);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_defaults_and_seed_preset_are_valid_and_limits_are_checked);
    RUN_TEST(test_every_status_has_a_description);
    RUN_TEST(test_time_jump_ahead_or_behind_is_refused_and_leaves_the_clock);
    RUN_TEST(test_int64_max_sample_is_refused_and_the_drive_goes_on);
    RUN_TEST(test_first_sample_at_int64_min_recovers_within_a_second);
    RUN_TEST(test_first_sample_at_int64_max_recovers_within_a_second);
    RUN_TEST(test_stream_shifted_an_hour_back_reinitializes_and_tracks_again);
    RUN_TEST(test_stream_shifted_an_hour_ahead_reinitializes_and_tracks_again);
    RUN_TEST(test_log_replayed_again_a_few_seconds_back_reinitializes);
    RUN_TEST(test_stray_samples_and_a_stuck_clock_never_switch_timelines);
    RUN_TEST(test_absurd_imu_samples_are_refused_and_counted);
    RUN_TEST(test_pixels_outside_the_image_and_absurd_disparity_are_refused);
    RUN_TEST(test_a_sparse_frames_bad_tracks_neither_poison_the_noise_nor_stay);
    RUN_TEST(test_a_moving_track_among_three_breaks_at_its_second_contradiction);
    RUN_TEST(test_a_track_drifting_against_the_velocities_breaks_and_stays_out);
    RUN_TEST(test_non_finite_covariance_from_a_pathological_input_resets_keeping_the_calibration);
    RUN_TEST(test_a_divergence_restarts_at_the_pose_before_the_input_that_diverged);
    RUN_TEST(test_injected_indefinite_or_nan_covariance_resets_and_no_nan_pose_is_handed_out);
    RUN_TEST(test_frames_contradicting_the_state_frame_after_frame_reset_the_filter);
    RUN_TEST(test_contradicting_frames_widen_the_noise_only_so_far);
    RUN_TEST(test_vl_reset_keeps_configuration_and_counters);
    RUN_TEST(test_frames_without_imu_are_not_propagated_with_a_stale_velocity);
    RUN_TEST(test_imu_back_after_a_silence_without_frames_is_not_integrated);
    return UNITY_END();
}
