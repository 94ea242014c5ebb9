/* Unit tests of the estimator API and of the shim's update and marginalization. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "unity.h"
#include "vl_random_update.h"
#include "vl_test_util.h"
#include "vislam/vislam.h"
#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_stereo.h"
#include "vl_window.h"
#include "vl_work.h"

static vl_estimator_t est;

/* A frame seeing n landmarks ahead of the vehicle (IMU x forward). */
static void make_frame(const vl_config_t *cfg, vl_stereo_frame_t *f, int64_t utime, uint32_t n, int32_t first_id)
{
    vl_test_frame_ahead(&cfg->calibration, f, utime, n, first_id);
}

/* vl_init, then the first IMU sample (at rest) at utime, which sets the clock. */
static vl_imu_sample_t start_at(const vl_config_t *cfg, int64_t utime)
{
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, cfg));
    vl_imu_sample_t s = vl_test_imu_at(utime, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    return s;
}

void setUp(void)
{
}

void tearDown(void)
{
}

/* ------------------------------------------------------------ configuration and misuse */

void test_init_rejects_null_and_missing_calibration(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg); /* no calibration yet */
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_init(NULL, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_init(&est, NULL));
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_init(&est, &cfg));
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
}

void test_init_rejects_misaligned_estimator(void)
{
    static unsigned char storage[sizeof(vl_estimator_t) + VL_ESTIMATOR_ALIGN] VL_ALIGNED(VL_ESTIMATOR_ALIGN);
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    vl_estimator_t *shifted = (vl_estimator_t *)(void *)(storage + 8);
    TEST_ASSERT_EQUAL_INT(VL_ERR_MISALIGNED, vl_init(shifted, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init((vl_estimator_t *)(void *)storage, &cfg));
}

void test_config_check_rejects_out_of_range_values(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_config_check(&cfg));
    cfg.max_landmarks = VL_MAX_LANDMARKS + 1u;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
    vl_test_kitti_config(&cfg);
    cfg.max_landmarks = 0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
    vl_test_kitti_config(&cfg);
    cfg.pixel_noise = NAN;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
    vl_test_kitti_config(&cfg);
    cfg.linear_velocity_noise = -1.0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
    vl_test_kitti_config(&cfg);
    cfg.calibration.cam_T_imu[0] = 2.0; /* not a rotation */
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
    vl_test_kitti_config(&cfg);
    cfg.mode = (vl_mode_t)7;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CONFIG, vl_config_check(&cfg));
}

void test_propagate_rejects_nan_and_counts_it(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = vl_test_imu_at(1000000, 1.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    s = vl_test_imu_at(1100000, NAN, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_ERR_NON_FINITE, vl_propagate(&est, &s));
    s = vl_test_imu_at(1100000, 1.0, INFINITY);
    TEST_ASSERT_EQUAL_INT(VL_ERR_NON_FINITE, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_UINT64(2, vl_get_counters(&est)->imu_rejected);
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->imu_accepted);
    vl_pose_t pose;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    TEST_ASSERT_TRUE(isfinite(pose.position[0]));
}

void test_propagate_rejects_non_increasing_time(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = vl_test_imu_at(2000000, 1.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_propagate(&est, &s));
    s.utime = 1999999;
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_UINT64(2, vl_get_counters(&est)->imu_rejected);
}

void test_update_before_first_imu_is_not_ready(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    make_frame(&cfg, &frame, 1000000, 10, 0);
    TEST_ASSERT_EQUAL_INT(VL_ERR_NOT_READY, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->frames_rejected);
}

void test_update_rejects_frame_out_of_time_order(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, 10, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_update(&est, &frame));
    frame.utime = 900000;
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT64(2, vl_get_counters(&est)->frames_rejected);
}

void test_update_truncates_oversized_frame_and_counts_it(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, VL_MAX_FRAME_FEATURES, 0);
    frame.count = VL_MAX_FRAME_FEATURES + 17u;
    TEST_ASSERT_EQUAL_INT(VL_FRAME_TRUNCATED, vl_update(&est, &frame));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(1, c->frames_truncated);
    TEST_ASSERT_EQUAL_UINT64(17, c->observations_truncated);
    TEST_ASSERT_LESS_OR_EQUAL_UINT32(cfg.max_landmarks, vl_window_size(&est));
}

void test_update_counts_invalid_observations(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, 6, 0);
    frame.obs[0].u_left = NAN;                        /* non-finite */
    frame.obs[1].id = -3;                             /* negative id */
    frame.obs[2].u_right = frame.obs[2].u_left + 2.0; /* negative disparity */
    frame.obs[3].id = frame.obs[4].id;                /* duplicate id */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(3, c->observations_invalid);
    TEST_ASSERT_EQUAL_UINT64(1, c->observations_low_disparity);
    TEST_ASSERT_EQUAL_UINT32(2, vl_window_size(&est));
}

void test_update_counts_a_repeated_image_and_nothing_else(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1100000, 6, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    frame.utime = 1200000; /* the same pixels again, later: a stale image */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->frames_repeated);
    frame.utime = 1300000; /* one pixel moved: a new image */
    frame.obs[5].u_left += 0.25;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    frame.utime = 1400000; /* new ids only: nothing shared, nothing repeated */
    make_frame(&cfg, &frame, 1400000, 6, 100);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->frames_repeated);
    TEST_ASSERT_EQUAL_UINT64(4, vl_get_counters(&est)->frames_accepted);
}

/* A window of 6 landmarks (ids 0..5): the same frame twice admits its tracks. */
static void window_of_six(vl_config_t *cfg, vl_stereo_frame_t *frame)
{
    vl_test_kitti_config(cfg);
    start_at(cfg, 1000000);
    make_frame(cfg, frame, 1100000, 6, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, frame));
    frame->utime = 1200000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, frame));
    TEST_ASSERT_EQUAL_UINT32(6, vl_window_size(&est));
}

/* window_of_six's frame reduced to ids 0, 2 and 4 and one outside the window; which slots it observes. */
static void observe_even_ids(vl_stereo_frame_t *frame, int observed[6])
{
    frame->count = 4;
    frame->obs[1] = frame->obs[2];
    frame->obs[2] = frame->obs[4];
    frame->obs[3].id = 99;
    for (uint32_t slot = 0; slot < 6; ++slot) {
        observed[slot] = est.slots[slot].id % 2 == 0 && est.slots[slot].id <= 4;
    }
}

/* The 3x3 block a noise should have added to the landmark blocks (a, b) of P (row-major; zero: none). */
typedef void (*landmark_noise_fn)(const void *ctx, uint32_t a, uint32_t b, double Q[9]);

/* What a noise added to P since `before`: the expected blocks on the landmarks (to 1e-12) and, bit
 * for bit, nothing elsewhere. Returns the largest expected entry. */
static double check_landmark_noise(const double *before, landmark_noise_fn expected, const void *ctx)
{
    const uint32_t n = vl_state_dim(&est);
    double largest = 0.0;
    for (uint32_t col = 0; col < n; ++col) {
        for (uint32_t row = 0; row < n; ++row) {
            const size_t at = (size_t)col * VL_COV_LD + row;
            const double added = est.P[at] - before[at];
            double e = 0.0;
            if (row >= VL_CORE_DIM && col >= VL_CORE_DIM) {
                double Q[9];
                expected(ctx, (row - VL_CORE_DIM) / 3u, (col - VL_CORE_DIM) / 3u, Q);
                e = Q[3 * ((row - VL_CORE_DIM) % 3u) + (col - VL_CORE_DIM) % 3u];
            }
            if (e == 0.0) {
                TEST_ASSERT_EQUAL_DOUBLE(0.0, added); /* bit-identical elsewhere */
            } else {
                TEST_ASSERT_DOUBLE_WITHIN(1e-12 * (1.0 + fabs(e)), e, added);
                largest = fmax(largest, fabs(e));
            }
        }
    }
    return largest;
}

typedef struct {
    double G[6][18]; /* G of each slot, 3x6 row-major */
    double Sigma[36];
    int carried[6];
} repeat_noise_t;

static void repeat_noise_block(const void *ctx, uint32_t a, uint32_t b, double Q[9])
{
    const repeat_noise_t *r = ctx;
    memset(Q, 0, 9 * sizeof(double));
    if (r->carried[a] && r->carried[b]) {
        double GS[18];
        vl_matmul(r->G[a], r->Sigma, GS, 3, 6, 6);
        vl_matmul_bt(GS, r->G[b], Q, 3, 6, 3);
    }
}

/*
 * The repeated image's noise: one rigid motion about the vehicle, rho and phi isotropic
 * with s^2 times the step's squared translation and angle, shared by the landmarks the
 * frame observes: Q_ab = G_a Sigma G_b^T with G_a = [I, -hat(l_a - p)], on their blocks
 * of P and nowhere else.
 */
void test_repeat_noise_moves_the_observed_landmarks_together_and_nothing_else(void)
{
    static vl_stereo_frame_t frame;
    static double before[VL_COV_LD * VL_COV_LD];
    static repeat_noise_t expected;
    vl_config_t cfg;
    window_of_six(&cfg, &frame);
    const double s = 0.5, step[3] = {1.0, 0.2, 0.0}, phi[3] = {0.0, 0.01, 0.03};
    est.cfg.repeat_anchor_noise = s;
    double dR[9];
    vl_so3_exp(phi, dR);
    vl_matmul_at(dR, est.R, est.frame_R, 3, 3, 3); /* frame_R = dR^T R: the step R frame_R^T is dR */
    for (int i = 0; i < 3; ++i) {
        est.frame_p[i] = est.p[i] - step[i];
    }
    memcpy(before, est.P, sizeof(before));
    observe_even_ids(&frame, expected.carried);
    TEST_ASSERT_EQUAL_UINT32(3, vl_window_repeat_noise(&est, &frame, frame.count));

    const double qt = s * s * (step[0] * step[0] + step[1] * step[1]);
    const double qr = s * s * (phi[1] * phi[1] + phi[2] * phi[2]);
    memset(expected.Sigma, 0, sizeof(expected.Sigma));
    for (int i = 0; i < 6; ++i) {
        expected.Sigma[7 * i] = i < 3 ? qt : qr;
    }
    for (uint32_t slot = 0; slot < 6; ++slot) {
        const double *l = &est.landmark_state[3 * slot];
        const double a[3] = {l[0] - est.p[0], l[1] - est.p[1], l[2] - est.p[2]};
        double S[9];
        vl_skew(a, S);
        memset(expected.G[slot], 0, sizeof(expected.G[slot]));
        for (int r = 0; r < 3; ++r) {
            expected.G[slot][6 * r + r] = 1.0;
            for (int c = 0; c < 3; ++c) {
                expected.G[slot][6 * r + 3 + c] = -S[3 * r + c];
            }
        }
    }
    const double largest = check_landmark_noise(before, repeat_noise_block, &expected);
    /* a step of a metre, at s = 0.5: a quarter of a square metre along the step, and more off it */
    TEST_ASSERT_TRUE(largest > 0.25 * (step[0] * step[0] + step[1] * step[1]));
}

typedef struct {
    double Q[6][9]; /* each slot's own block */
    int carried[6];
} carried_walk_t;

static void carried_walk_block(const void *ctx, uint32_t a, uint32_t b, double Q[9])
{
    const carried_walk_t *w = ctx;
    memset(Q, 0, 9 * sizeof(double));
    if (a == b && w->carried[a]) {
        memcpy(Q, w->Q[a], 9 * sizeof(double));
    }
}

/*
 * The carried tracks' walk: each landmark flagged at a repeated image gets, on its own 3x3
 * block of P, A diag((z s / fx)^2, (z s / fy)^2, (z^2 s / (fx b))^2) A^T with A = R Rc^T and z
 * its depth in the camera; nothing else in P moves, and P stays exactly symmetric.
 */
void test_carried_walk_widens_the_carried_landmarks_alone(void)
{
    static vl_stereo_frame_t frame;
    static double before[VL_COV_LD * VL_COV_LD];
    static carried_walk_t expected;
    vl_config_t cfg;
    window_of_six(&cfg, &frame);
    const double s = 0.5;
    est.cfg.repeat_track_walk = s;
    /* window_of_six's second frame repeats its first (a repeated image): all six were carried. */
    for (uint32_t slot = 0; slot < 6; ++slot) {
        TEST_ASSERT_EQUAL_UINT32(1, est.slots[slot].carried);
        est.slots[slot].carried = 0;
    }
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_carried_walk(&est));
    observe_even_ids(&frame, expected.carried);
    vl_window_mark_carried(&est, &frame, frame.count);
    for (uint32_t slot = 0; slot < 6; ++slot) {
        TEST_ASSERT_EQUAL_UINT32((uint32_t)expected.carried[slot], est.slots[slot].carried);
    }
    memcpy(before, est.P, sizeof(before));
    TEST_ASSERT_EQUAL_UINT32(3, vl_window_carried_walk(&est));

    const vl_calibration_t *cal = &est.cfg.calibration;
    double Rc[9], A[9];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Rc[3 * i + j] = cal->cam_T_imu[4 * i + j];
        }
    }
    vl_matmul_bt(est.R, Rc, A, 3, 3, 3);
    for (uint32_t slot = 0; slot < 6; ++slot) {
        const double *l = &est.landmark_state[3 * slot];
        const double d[3] = {l[0] - est.p[0], l[1] - est.p[1], l[2] - est.p[2]};
        double body[3], z = cal->cam_T_imu[11];
        vl_matmul_at(est.R, d, body, 3, 3, 1);
        for (int j = 0; j < 3; ++j) {
            z += Rc[6 + j] * body[j];
        }
        const double q[3] = {pow(z * s / cal->fx, 2), pow(z * s / cal->fy, 2),
                             pow(z * z * s / (cal->fx * cal->baseline), 2)};
        for (int r = 0; r < 3; ++r) {
            for (int c = 0; c < 3; ++c) {
                expected.Q[slot][3 * r + c] = A[3 * r] * q[0] * A[3 * c] + A[3 * r + 1] * q[1] * A[3 * c + 1] +
                                              A[3 * r + 2] * q[2] * A[3 * c + 2];
            }
        }
    }
    TEST_ASSERT_TRUE(check_landmark_noise(before, carried_walk_block, &expected) > 0.0);
    const uint32_t n = vl_state_dim(&est);
    for (uint32_t col = 0; col < n; ++col) {
        for (uint32_t row = 0; row < col; ++row) {
            TEST_ASSERT_EQUAL_DOUBLE(est.P[(size_t)col * VL_COV_LD + row], est.P[(size_t)row * VL_COV_LD + col]);
        }
    }
}

/* Off or on, the filter is the same except at repeated images. */
void test_repeat_noise_acts_at_repeated_images_only(void)
{
    static vl_stereo_frame_t frame;
    static vl_estimator_t off;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_TRUE(cfg.repeat_anchor_noise > 0.0); /* on by default */
    vl_config_t on_cfg = cfg;
    cfg.repeat_anchor_noise = 0.0;
    const vl_imu_sample_t first = start_at(&on_cfg, 1000000);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&off, &cfg));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&off, &first));
    for (int k = 1; k <= 5; ++k) {
        const int64_t t = 1000000 + 100000 * (int64_t)k;
        const vl_imu_sample_t imu = vl_test_imu_at(t, 2.0, 0.05);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &imu));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&off, &imu));
        if (k != 5) { /* frame 5 repeats frame 4 */
            make_frame(&cfg, &frame, t, 8, 0);
            for (uint32_t i = 0; i < frame.count; ++i) {
                frame.obs[i].u_left -= 0.5 * k;
                frame.obs[i].u_right -= 0.5 * k;
            }
        }
        frame.utime = t;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&off, &frame));
        const uint32_t n = vl_state_dim(&est);
        int same = n == vl_state_dim(&off) && memcmp(est.p, off.p, sizeof(est.p)) == 0;
        for (uint32_t col = 0; col < n && same; ++col) { /* the state's columns: the rest of P is scratch */
            same = memcmp(&est.P[(size_t)col * VL_COV_LD], &off.P[(size_t)col * VL_COV_LD], n * sizeof(double)) == 0;
        }
        TEST_ASSERT_EQUAL_INT(k != 5, same);
    }
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->frames_repeated);
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&off)->frames_repeated);
}

/* ------------------------------------------------------------ prediction */

void test_propagate_follows_exponential_map(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.estimate_input_offsets = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    const double u[6] = {5.0, 0.2, -0.1, 0.01, -0.02, 0.3};
    vl_imu_sample_t s;
    s.utime = 0;
    memcpy(s.linear_velocity, u, sizeof(s.linear_velocity));
    memcpy(s.angular_velocity, u + 3, sizeof(s.angular_velocity));
    for (int k = 0; k <= 20; ++k) {
        s.utime = (int64_t)k * 100000;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    }
    /* constant velocity for 2 s is one exponential */
    double xi[6], R[9], p[3];
    for (int i = 0; i < 6; ++i) {
        xi[i] = 2.0 * u[i];
    }
    vl_se3_exp(xi, R, p);
    vl_pose_t pose;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    for (int i = 0; i < 3; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-9, p[i], pose.position[i]);
    }
    for (int i = 0; i < 9; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, R[i], pose.rotation[i]);
    }
    /* covariance grows and stays symmetric */
    TEST_ASSERT_TRUE(pose.covariance[0] > 0.0);
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            TEST_ASSERT_EQUAL_DOUBLE(pose.covariance[6 * i + j], pose.covariance[6 * j + i]);
        }
    }
}

/* Position x after samples of vx at 0 and 100 ms, with a frame at frame_ms (0: none). */
static double x_after_two_samples(int interpolate, double vx0, double vx1, int64_t frame_ms)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.estimate_input_offsets = 0;
    cfg.mode = VL_MODE_IMU_ONLY;
    cfg.interpolate_velocities = interpolate;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = vl_test_imu_at(0, vx0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    if (frame_ms > 0) {
        static vl_stereo_frame_t f;
        make_frame(&cfg, &f, frame_ms * 1000, 0, 0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &f));
    }
    s = vl_test_imu_at(100000, vx1, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_pose_t pose;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    return pose.position[0];
}

void test_propagate_integrates_the_line_between_instantaneous_samples(void)
{
    /* 1 m/s, then 3 m/s 0.1 s later: the trapezoid moves 0.2 m, the held sample 0.1 m. */
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.2, x_after_two_samples(1, 1.0, 3.0, 0));
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.1, x_after_two_samples(0, 1.0, 3.0, 0));
    /* A frame at 50 ms is reached with the last sample (0.05 m), and the next sample finishes the
     * interval with the line's mean over what is left (2.5 m/s for 0.05 s). */
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.175, x_after_two_samples(1, 1.0, 3.0, 50));
    TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.1, x_after_two_samples(0, 1.0, 3.0, 50));
}

/* ------------------------------------------------------------ shim: update and marginalization */

#define N_TEST (VL_CORE_DIM + 3 * 3)
/** A state dimension with a remainder of 3 rows past a multiple of 4, and room for the padding. */
#define N_ODD (N_TEST + 3)
#define LD_ODD (N_ODD + 1)

static double rand_unit(unsigned *state)
{
    *state = *state * 1103515245u + 12345u;
    return ((double)((*state >> 8) & 0xFFFFu) / 65535.0) - 0.5;
}

/* Random SPD matrix into column-major storage with leading dimension ld. */
static void random_spd(double *P, int ld, int n, unsigned seed)
{
    static double A[N_ODD * N_ODD];
    unsigned s = seed;
    for (int i = 0; i < n * n; ++i) {
        A[i] = rand_unit(&s);
    }
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            double acc = (i == j) ? 0.5 : 0.0;
            for (int k = 0; k < n; ++k) {
                acc += A[i * n + k] * A[j * n + k];
            }
            P[(size_t)j * ld + i] = acc;
        }
    }
}

/* In-place Gauss-Jordan inverse of a small dense row-major matrix. */
static void invert(double *M, int n)
{
    static double aug[12 * 24];
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < 2 * n; ++j) {
            aug[i * 2 * n + j] = (j < n) ? M[i * n + j] : (j - n == i ? 1.0 : 0.0);
        }
    }
    for (int c = 0; c < n; ++c) {
        int piv = c;
        for (int r = c + 1; r < n; ++r) {
            if (fabs(aug[r * 2 * n + c]) > fabs(aug[piv * 2 * n + c])) {
                piv = r;
            }
        }
        for (int j = 0; j < 2 * n; ++j) {
            double t = aug[c * 2 * n + j];
            aug[c * 2 * n + j] = aug[piv * 2 * n + j];
            aug[piv * 2 * n + j] = t;
        }
        const double d = aug[c * 2 * n + c];
        for (int j = 0; j < 2 * n; ++j) {
            aug[c * 2 * n + j] /= d;
        }
        for (int r = 0; r < n; ++r) {
            if (r != c) {
                const double f = aug[r * 2 * n + c];
                for (int j = 0; j < 2 * n; ++j) {
                    aug[r * 2 * n + j] -= f * aug[c * 2 * n + j];
                }
            }
        }
    }
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            M[i * n + j] = aug[i * 2 * n + n + j];
        }
    }
}

/* vl_la_update on n states stored with leading dimension ld against the dense Kalman formula; the
 * rows past n that its padding uses are zero afterwards. */
static void check_la_update_against_dense_formula(int n, int ld)
{
    enum { n_max = N_ODD, ld_max = LD_ODD, k = 3, m = 3 * k };
    static double P[ld_max * n_max], P0[n_max * n_max], PHt[ld_max * m], S[m * m], dx[ld_max];
    TEST_ASSERT_TRUE(n <= n_max && ld <= ld_max);
    for (size_t i = 0; i < sizeof(P) / sizeof(P[0]); ++i) {
        P[i] = 1e300; /* rows past n: no state's */
    }
    random_spd(P, ld, n, 7u);
    random_spd(P0, n, n, 7u);
    vl_la_obs_t obs[k];
    unsigned s = 99u;
    for (int i = 0; i < k; ++i) {
        for (int j = 0; j < 18; ++j) {
            obs[i].H_pose[j] = 10.0 * rand_unit(&s);
        }
        for (int j = 0; j < 9; ++j) {
            obs[i].H_landmark[j] = 10.0 * rand_unit(&s);
        }
        for (int j = 0; j < 3; ++j) {
            obs[i].residual[j] = 3.0 * rand_unit(&s);
            obs[i].noise_var[j] = 1.0 + (double)j;
        }
        obs[i].landmark_col = VL_CORE_DIM + 3 * ((i + 1) % 3);
    }
    /* Dense reference: H (m x n), K = P H^T S^-1, P+ = P - K H P, dx = K r. */
    static double H[m * n_max], PHt_ref[n_max * m], Sref[m * m], K[n_max * m], Pref[n_max * n_max], dxref[n_max];
    memset(H, 0, sizeof(H));
    for (int i = 0; i < k; ++i) {
        for (int r = 0; r < 3; ++r) {
            for (int j = 0; j < 6; ++j) {
                H[(3 * i + r) * n + j] = obs[i].H_pose[6 * r + j];
            }
            for (int j = 0; j < 3; ++j) {
                H[(3 * i + r) * n + obs[i].landmark_col + j] = obs[i].H_landmark[3 * r + j];
            }
        }
    }
    for (int a = 0; a < n; ++a) {
        for (int b = 0; b < m; ++b) {
            double acc = 0.0;
            for (int c = 0; c < n; ++c) {
                acc += P0[c * n + a] * H[b * n + c];
            }
            PHt_ref[a * m + b] = acc;
        }
    }
    for (int a = 0; a < m; ++a) {
        for (int b = 0; b < m; ++b) {
            double acc = (a == b) ? obs[a / 3].noise_var[a % 3] : 0.0;
            for (int c = 0; c < n; ++c) {
                acc += H[a * n + c] * PHt_ref[c * m + b];
            }
            Sref[a * m + b] = acc;
        }
    }
    invert(Sref, m);
    for (int a = 0; a < n; ++a) {
        for (int b = 0; b < m; ++b) {
            double acc = 0.0;
            for (int c = 0; c < m; ++c) {
                acc += PHt_ref[a * m + c] * Sref[c * m + b];
            }
            K[a * m + b] = acc;
        }
    }
    for (int a = 0; a < n; ++a) {
        double acc = 0.0;
        for (int b = 0; b < m; ++b) {
            acc += K[a * m + b] * obs[b / 3].residual[b % 3];
        }
        dxref[a] = acc;
        for (int b = 0; b < n; ++b) {
            double kh = 0.0;
            for (int c = 0; c < m; ++c) {
                kh += K[a * m + c] * PHt_ref[b * m + c];
            }
            Pref[b * n + a] = P0[b * n + a] - kh;
        }
    }

    double nis_ref = 0.0; /* r^T S^-1 r, Sref holding S^-1 now */
    for (int a = 0; a < m; ++a) {
        for (int b = 0; b < m; ++b) {
            nis_ref += obs[a / 3].residual[a % 3] * Sref[a * m + b] * obs[b / 3].residual[b % 3];
        }
    }

    vl_la_workspace_t ws = {PHt, S, dx, NULL, NULL};
    double nis = -1.0;
    TEST_ASSERT_EQUAL_INT(0, vl_la_update(P, ld, n, obs, k, &ws, &nis));
    TEST_ASSERT_DOUBLE_WITHIN(1e-9 * nis_ref, nis_ref, nis);
    const int padded = (n + 3) / 4 * 4 < ld ? (n + 3) / 4 * 4 : ld;
    for (int a = 0; a < n; ++a) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-9, dxref[a], dx[a]);
        for (int b = 0; b < n; ++b) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, Pref[b * n + a], P[b * ld + a]);
            TEST_ASSERT_EQUAL_DOUBLE(P[b * ld + a], P[a * ld + b]); /* exactly symmetric */
        }
        for (int r = n; r < ld; ++r) {
            TEST_ASSERT_EQUAL_DOUBLE(r < padded ? 0.0 : 1e300, P[a * ld + r]);
        }
    }
}

void test_la_update_equals_dense_kalman_formula(void)
{
    check_la_update_against_dense_formula(N_TEST, N_TEST); /* a multiple of 4 */
    check_la_update_against_dense_formula(N_ODD, N_ODD);   /* no room to pad */
    check_la_update_against_dense_formula(N_ODD, LD_ODD);  /* padded by one zero row */
}

void test_la_update_refuses_indefinite_innovation_covariance(void)
{
    enum { n = N_TEST };
    static double P[n * n], P0[n * n], PHt[n * 3], S[9], dx[n];
    random_spd(P, n, n, 3u);
    memcpy(P0, P, sizeof(P));
    vl_la_obs_t obs;
    memset(&obs, 0, sizeof(obs));
    obs.H_landmark[0] = obs.H_landmark[4] = obs.H_landmark[8] = 1.0;
    obs.noise_var[0] = obs.noise_var[1] = obs.noise_var[2] = -1e6;
    obs.landmark_col = VL_CORE_DIM;
    vl_la_workspace_t ws = {PHt, S, dx, NULL, NULL};
    TEST_ASSERT_EQUAL_INT(-1, vl_la_update(P, n, n, &obs, 1, &ws, NULL));
    TEST_ASSERT_EQUAL_MEMORY(P0, P, sizeof(P));
}

/* Largest |a - b| over an n x n block of two matrices of leading dimension ld, and largest |a|. */
static void max_difference(const double *a, const double *b, int ld, int n, double *diff, double *scale)
{
    *diff = *scale = 0.0;
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
            *diff = fmax(*diff, fabs(a[j * ld + i] - b[j * ld + i]));
            *scale = fmax(*scale, fabs(a[j * ld + i]));
        }
    }
}

/* Two updates with the landmark block's downdate left pending (vl_la_update_core, the second
 * against the first's pending rows), then one downdate of both, against two full updates in
 * turn: the same corrections and covariance to rounding. In between, the core's rows are current
 * and an observation's innovation covariance read with the pending rows is the updated one. */
void test_la_pending_downdate_equals_the_updates_in_turn(void)
{
    enum { n = VL_CORE_DIM + 3 * 40, ld = n + 5, k1 = 12, k2 = 7, m = 3 * (k1 + k2) };
    static double P_full[ld * n], P_lazy[ld * n], G[n * VL_RANDOM_FACTOR_RANK];
    static double PHt_full[ld * m], S_full[m * m], dx_full[ld], PHt[ld * m], S[m * m], dx[ld];
    static vl_obs_row_t obs1[k1], obs2[k2];
    unsigned state = 11u;
    vl_random_covariance(P_full, ld, n, G, &state);
    memcpy(P_lazy, P_full, sizeof(P_full));
    vl_random_observations(obs1, n, k1, &state);
    vl_random_observations(obs2, n, k2, &state);
    for (int i = 0; i < k2; i += 2) { /* half on the first update's landmarks, half on others */
        obs2[i].landmark_col += 3 * 20;
    }
    const vl_la_workspace_t full = {PHt_full, S_full, dx_full, NULL, NULL};
    const vl_la_workspace_t lazy = {PHt, S, dx, NULL, NULL};
    double diff, scale;

    TEST_ASSERT_EQUAL_INT(0, vl_la_update(P_full, ld, n, obs1, k1, &full, NULL));
    TEST_ASSERT_EQUAL_INT(0, vl_la_update_core(P_lazy, ld, n, obs1, k1, &lazy, 0, NULL));
    for (int i = 0; i < n; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, dx_full[i], dx[i]);
    }
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
            if (i < VL_CORE_DIM || j < VL_CORE_DIM) { /* the core's rows and columns are current */
                TEST_ASSERT_DOUBLE_WITHIN(1e-12 * 64.0, P_full[j * ld + i], P_lazy[j * ld + i]);
            }
        }
    }
    const vl_la_pending_t pending = {PHt, vl_la_padded_rows(n, ld), 3 * k1};
    for (int i = 0; i < k2; ++i) {
        double Sa[9], Sb[9];
        vl_la_obs_covariance(P_lazy, ld, &obs2[i], &pending, Sa);
        vl_la_obs_covariance(P_full, ld, &obs2[i], NULL, Sb);
        for (int q = 0; q < 9; ++q) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-9 * fabs(Sb[q]) + 1e-12, Sb[q], Sa[q]);
        }
    }
    max_difference(P_full, P_lazy, ld, n, &diff, &scale);
    TEST_ASSERT_TRUE(diff > 1e-3 * scale); /* the landmark block still owes the downdate */

    TEST_ASSERT_EQUAL_INT(0, vl_la_update(P_full, ld, n, obs2, k2, &full, NULL));
    TEST_ASSERT_EQUAL_INT(0, vl_la_update_core(P_lazy, ld, n, obs2, k2, &lazy, 3 * k1, NULL));
    for (int i = 0; i < n; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-12, dx_full[i], dx[i]);
    }
    vl_la_downdate_landmarks(P_lazy, ld, n, &lazy, 3 * (k1 + k2));
    max_difference(P_full, P_lazy, ld, n, &diff, &scale);
    TEST_ASSERT_TRUE(diff <= 1e-12 * scale);
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < j; ++i) {
            TEST_ASSERT_EQUAL_DOUBLE(P_lazy[j * ld + i], P_lazy[i * ld + j]); /* exactly symmetric */
        }
    }
}

void test_la_move_block_leaves_the_exact_marginal(void)
{
    enum { n = N_TEST };
    static double P[n * n], P0[n * n];
    random_spd(P, n, n, 11u);
    memcpy(P0, P, sizeof(P));
    /* Drop landmark 0: landmark 2 moves into its place, landmark 1 stays. */
    vl_la_move_block(P, n, n, VL_CORE_DIM, VL_CORE_DIM + 6);
    int map[N_TEST - 3];
    for (int i = 0; i < VL_CORE_DIM; ++i) {
        map[i] = i;
    }
    for (int i = 0; i < 3; ++i) {
        map[VL_CORE_DIM + i] = VL_CORE_DIM + 6 + i;
        map[VL_CORE_DIM + 3 + i] = VL_CORE_DIM + 3 + i;
    }
    for (int a = 0; a < n - 3; ++a) {
        for (int b = 0; b < n - 3; ++b) {
            TEST_ASSERT_EQUAL_DOUBLE(P0[map[b] * n + map[a]], P[b * n + a]);
        }
    }
}

/* ------------------------------------------------------------ window and map */

typedef struct {
    vl_landmark_t got[VL_MAX_LANDMARKS];
    size_t count;
} sink_t;

static void collect(void *user, const vl_landmark_t *lm)
{
    sink_t *s = (sink_t *)user;
    if (s->count < VL_MAX_LANDMARKS) {
        s->got[s->count] = *lm;
    }
    s->count++;
}

void test_flush_hands_every_landmark_to_the_sink_with_its_marginal(void)
{
    static vl_stereo_frame_t frame;
    static sink_t sink;
    static vl_landmark_t before[VL_MAX_LANDMARKS];
    memset(&sink, 0, sizeof(sink));
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.landmark_sink = collect;
    cfg.landmark_sink_user = &sink;
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, 12, 100);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    size_t count = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&est, before, VL_MAX_LANDMARKS, &count));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(12), (uint64_t)(count));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_flush_landmarks(&est));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(12), (uint64_t)(sink.count));
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT32(VL_CORE_DIM, vl_state_dim(&est));
    for (size_t i = 0; i < count; ++i) {
        int found = 0;
        for (size_t j = 0; j < sink.count; ++j) {
            if (sink.got[j].id == before[i].id) {
                found = 1;
                TEST_ASSERT_EQUAL_MEMORY(before[i].position, sink.got[j].position, sizeof(before[i].position));
                TEST_ASSERT_EQUAL_MEMORY(before[i].covariance, sink.got[j].covariance, sizeof(before[i].covariance));
            }
        }
        TEST_ASSERT_TRUE(found);
    }
    /* a landmark seen from the identity pose lands where it was placed */
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, 8.0, before[0].position[0] + 0.0 * before[0].id);
}

void test_window_never_exceeds_its_limit_and_keeps_observed_landmarks(void)
{
    static vl_stereo_frame_t frame;
    static sink_t sink;
    memset(&sink, 0, sizeof(sink));
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_landmarks = 5;
    cfg.landmark_sink = collect;
    cfg.landmark_sink_user = &sink;
    vl_imu_sample_t s = start_at(&cfg, 0);
    for (int k = 0; k < 5; ++k) {
        s.utime = (int64_t)k * 100000;
        if (k > 0) {
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        }
        make_frame(&cfg, &frame, s.utime, 9, 0); /* the same 9 tracks every frame */
        TEST_ASSERT_TRUE(vl_test_update(&est, &frame) >= 0);
        TEST_ASSERT_LESS_OR_EQUAL_UINT32(5, vl_window_size(&est));
    }
    /* All five admitted landmarks are observed every frame: none may be evicted. */
    TEST_ASSERT_EQUAL_UINT32(5, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->landmarks_evicted);
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(0), (uint64_t)(sink.count));
    TEST_ASSERT_TRUE(vl_get_counters(&est)->landmarks_deferred > 0);
    /* Tracks end: the window empties into the map, nothing is lost. */
    s.utime = 600000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    make_frame(&cfg, &frame, s.utime, 0, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(5), (uint64_t)(sink.count));
    TEST_ASSERT_EQUAL_UINT64(vl_get_counters(&est)->landmarks_initialized,
                             vl_get_counters(&est)->landmarks_marginalized);
}

void test_a_sparse_frame_admits_its_new_tracks_at_first_sight(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    TEST_ASSERT_EQUAL_UINT32(2, cfg.min_track_length);
    const uint32_t below = cfg.first_sight_below;
    /* Fewer observations than first_sight_below: every new track becomes a landmark now. */
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, below - 1u, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(below - 1u, vl_window_size(&est));
    /* As many: the tracks wait for their second frame (min_track_length). */
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, below, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
    frame.utime = 1100000;
    frame.obs[0].u_left += 0.25; /* not a repeated image */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(below, vl_window_size(&est));
    /* 0: never at first sight. */
    cfg.first_sight_below = 0;
    start_at(&cfg, 1000000);
    make_frame(&cfg, &frame, 1000000, 3, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
}

void test_window_admits_the_largest_disparity_first(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_landmarks = 1;
    start_at(&cfg, 0);
    frame.utime = 0;
    frame.count = 3;
    const double far[3] = {40.0, 1.0, 0.0}, near[3] = {6.0, 1.0, 0.0}, mid[3] = {15.0, 1.0, 0.0};
    vl_test_observe(&cfg.calibration, far, 1, &frame.obs[0]);
    vl_test_observe(&cfg.calibration, near, 2, &frame.obs[1]);
    vl_test_observe(&cfg.calibration, mid, 3, &frame.obs[2]);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    vl_landmark_t lm;
    size_t count = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&est, &lm, 1, &count));
    TEST_ASSERT_EQUAL_INT32(2, lm.id);
}

void test_get_landmarks_reports_capacity_shortfall(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    start_at(&cfg, 0);
    make_frame(&cfg, &frame, 0, 4, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    vl_landmark_t out[2];
    size_t count = 0;
    TEST_ASSERT_EQUAL_INT(VL_ERR_CAPACITY, vl_get_landmarks(&est, out, 2, &count));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(4), (uint64_t)(count));
}

void test_update_uses_at_most_max_update_observations(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_observations = 5;
    vl_imu_sample_t s = start_at(&cfg, 0);
    make_frame(&cfg, &frame, 0, 12, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    s.utime = 100000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    make_frame(&cfg, &frame, 100000, 12, 0); /* the same 12 tracks, seen again without motion */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(5, c->observations_used);
    TEST_ASSERT_EQUAL_UINT64(7, c->observations_deferred);
    TEST_ASSERT_EQUAL_UINT32(12, vl_window_size(&est)); /* deferred, not dropped */
}

/* Two frames of the same n tracks at rest: the second updates with the window full of them. */
static const vl_counters_t *update_window_of(vl_config_t *cfg, uint32_t n)
{
    static vl_stereo_frame_t frame;
    vl_imu_sample_t s = start_at(cfg, 0);
    make_frame(cfg, &frame, 0, n, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(n, vl_window_size(&est));
    s.utime = 100000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    make_frame(cfg, &frame, 100000, n, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    return vl_get_counters(&est);
}

/* The largest observation count whose joint update on n states fits the budget (flops). */
static uint32_t observations_within(uint32_t n, uint64_t budget)
{
    uint32_t k = 1;
    while (vl_work_joint_update(n, k + 1u) <= budget) {
        ++k;
    }
    return k;
}

void test_update_work_bound_uses_fewer_observations_in_a_larger_window(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_observations = 0;
    const uint64_t budget = vl_work_joint_update(VL_CORE_DIM + 3u * 40u, 10u);
    cfg.max_update_work = (double)budget * 1e-6;

    const vl_counters_t *c = update_window_of(&cfg, 40);
    TEST_ASSERT_EQUAL_UINT64(10, c->observations_used);
    TEST_ASSERT_EQUAL_UINT64(30, c->observations_deferred);
    vl_work_t w;
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT32(30, w.rows);
    TEST_ASSERT_EQUAL_UINT32(40, vl_window_size(&est)); /* deferred, not dropped */

    /* The same budget in a smaller window buys more observations. */
    const uint32_t expected = observations_within(VL_CORE_DIM + 3u * 20u, budget);
    TEST_ASSERT_GREATER_THAN_UINT32(10, expected);
    c = update_window_of(&cfg, 20);
    TEST_ASSERT_EQUAL_UINT64(expected, c->observations_used);

    /* A budget too small for any observation still uses one. */
    cfg.max_update_work = 1e-9;
    c = update_window_of(&cfg, 20);
    TEST_ASSERT_EQUAL_UINT64(1, c->observations_used);
    TEST_ASSERT_EQUAL_UINT64(19, c->observations_deferred);
}

/* Four frames of the same 12 tracks at rest under a 5-observation bound; each landmark's update count. */
static void updates_under_bound(int rotate, uint32_t updates[12])
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_observations = 5;
    cfg.rotate_deferred = rotate;
    vl_imu_sample_t s = start_at(&cfg, 0);
    for (int f = 0; f < 4; ++f) {
        s.utime = 100000 * (int64_t)f;
        if (f > 0) {
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        }
        make_frame(&cfg, &frame, s.utime, 12, 0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    }
    TEST_ASSERT_EQUAL_UINT32(12, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT64(15, vl_get_counters(&est)->observations_used);
    for (uint32_t i = 0; i < 12; ++i) {
        updates[i] = est.slots[i].updates;
    }
}

void test_rotated_deferrals_reach_every_landmark_in_turn(void)
{
    uint32_t updates[12];
    updates_under_bound(1, updates);
    for (uint32_t i = 0; i < 12; ++i) { /* 15 uses over 12 landmarks: each once or twice */
        TEST_ASSERT_TRUE(updates[i] == 1 || updates[i] == 2);
    }
    /* The evenly spread subset picks the same rows every frame: some landmarks never serve. */
    updates_under_bound(0, updates);
    uint32_t never = 0;
    for (uint32_t i = 0; i < 12; ++i) {
        never += updates[i] == 0;
    }
    TEST_ASSERT_GREATER_THAN_UINT32(0, never);
}

/* Frame f at rest sees points 2f .. 2f + 11 (each its index as id): each frame ends two tracks
 * and starts two. The IMU sample at the frame's time comes first. */
static void tracks_moving_on(const vl_config_t *cfg, vl_estimator_t *e, vl_stereo_frame_t *frame, int f)
{
    if (f > 0) {
        const vl_imu_sample_t s = vl_test_imu_at(100000 * (int64_t)f, 0.0, 0.0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(e, &s));
    }
    frame->utime = 100000 * (int64_t)f;
    frame->count = 12;
    for (uint32_t i = 0; i < frame->count; ++i) {
        double pw[3];
        const uint32_t point = 2u * (uint32_t)f + i;
        vl_test_point_ahead(point, pw);
        vl_test_observe(&cfg->calibration, pw, (int32_t)point, &frame->obs[i]);
    }
}

/* vl_update leaves the pose final: the landmark block's downdate and the window's upkeep after
 * it (vl_update_deferred) move neither the pose nor its covariance, and what is read of the
 * landmarks in between is what they hold afterwards. */
void test_the_pose_is_final_at_vl_update_and_the_upkeep_follows_it(void)
{
    static vl_stereo_frame_t frame;
    static vl_landmark_t during[VL_MAX_LANDMARKS], after[VL_MAX_LANDMARKS];
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_work = 0.0; /* nothing held back: vl_update_deferred does the upkeep alone */
    (void)start_at(&cfg, 0);
    const vl_counters_t *c = vl_get_counters(&est);
    uint32_t compared = 0;
    for (int f = 0; f < 10; ++f) {
        tracks_moving_on(&cfg, &est, &frame, f);
        const uint64_t admitted = c->landmarks_initialized, marginalized = c->landmarks_marginalized;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
        TEST_ASSERT_TRUE(vl_deferred_due(&est));
        TEST_ASSERT_EQUAL_UINT64(admitted, c->landmarks_initialized); /* the upkeep waits */
        TEST_ASSERT_EQUAL_UINT64(marginalized, c->landmarks_marginalized);
        vl_pose_t a, b;
        memset(&a, 0, sizeof(a));
        memset(&b, 0, sizeof(b));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &a));
        size_t n_during = 0, n_after = 0;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&est, during, VL_MAX_LANDMARKS, &n_during));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
        TEST_ASSERT_FALSE(vl_deferred_due(&est));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &b));
        TEST_ASSERT_EQUAL_MEMORY(&a, &b, sizeof(a));
        TEST_ASSERT_TRUE(c->landmarks_initialized > admitted);
        TEST_ASSERT_TRUE(f < 2 || c->landmarks_marginalized > marginalized);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&est, after, VL_MAX_LANDMARKS, &n_after));
        for (size_t i = 0; i < n_during; ++i) {
            for (size_t j = 0; j < n_after; ++j) {
                if (after[j].id != during[i].id) {
                    continue;
                }
                TEST_ASSERT_EQUAL_MEMORY(during[i].position, after[j].position, sizeof(after[j].position));
                for (int q = 0; q < 9; ++q) {
                    TEST_ASSERT_DOUBLE_WITHIN(1e-12 * fabs(after[j].covariance[0]), after[j].covariance[q],
                                              during[i].covariance[q]);
                }
                compared++;
            }
        }
    }
    TEST_ASSERT_TRUE(compared > 50);
}

/* A caller that never calls vl_update_deferred gets the same estimate: the next input does the
 * frame's work after the pose first, in the same order (the held inliers are off here, as they
 * would be dropped). */
void test_the_next_input_does_the_upkeep_vl_update_deferred_was_not_called_for(void)
{
    static vl_estimator_t other;
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.apply_deferred = 0;
    cfg.max_update_observations = 8; /* some inliers held back, and dropped alike */
    (void)start_at(&cfg, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&other, &cfg));
    const vl_imu_sample_t s0 = vl_test_imu_at(0, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&other, &s0));
    for (int f = 0; f < 10; ++f) {
        tracks_moving_on(&cfg, &est, &frame, f);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
        tracks_moving_on(&cfg, &other, &frame, f);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&other, &frame));
    }
    const vl_imu_sample_t s = vl_test_imu_at(1000000, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&other, &s));
    TEST_ASSERT_FALSE(vl_deferred_due(&other));
    TEST_ASSERT_EQUAL_UINT32(vl_state_dim(&est), vl_state_dim(&other));
    TEST_ASSERT_TRUE(vl_get_counters(&est)->observations_deferred_dropped > 0);
    TEST_ASSERT_EQUAL_MEMORY(vl_get_counters(&est), vl_get_counters(&other), sizeof(vl_counters_t));
    TEST_ASSERT_EQUAL_MEMORY(est.R, other.R, sizeof(est.R));
    TEST_ASSERT_EQUAL_MEMORY(est.p, other.p, sizeof(est.p));
    TEST_ASSERT_EQUAL_MEMORY(est.landmark_state, other.landmark_state, sizeof(double) * 3u * est.num_landmarks);
    const uint32_t n = vl_state_dim(&est);
    for (uint32_t j = 0; j < n; ++j) {
        TEST_ASSERT_EQUAL_MEMORY(&est.P[(size_t)j * VL_COV_LD], &other.P[(size_t)j * VL_COV_LD], sizeof(double) * n);
    }
}

/* Two frames of the same 12 tracks at rest under a 5-observation bound, the noise fixed; the
 * second frame's deferred observations applied (vl_update_deferred) when apply is set. */
static void twelve_tracks_under_bound(vl_config_t *cfg, int apply)
{
    vl_test_kitti_config(cfg);
    cfg->min_track_length = 1;
    cfg->adaptive_noise = 0; /* the noise in use must not move between the two updates */
    cfg->max_update_work = 0.0;
    cfg->max_update_observations = 5;
    (void)update_window_of(cfg, 12);
    if (apply) {
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    }
}

void test_deferred_observations_are_applied_after_the_pose(void)
{
    vl_config_t cfg;
    twelve_tracks_under_bound(&cfg, 0);
    TEST_ASSERT_EQUAL_UINT32(7, vl_deferred_pending(&est));
    vl_pose_t before, after;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &before));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &after));
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(12, c->observations_used);
    TEST_ASSERT_EQUAL_UINT64(7, c->observations_deferred);
    TEST_ASSERT_EQUAL_UINT64(7, c->observations_deferred_used);
    TEST_ASSERT_EQUAL_UINT64(0, c->observations_deferred_dropped);
    TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(&est));
    vl_work_t w;
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT32(21, w.rows);
    TEST_ASSERT_EQUAL_UINT32(vl_state_dim(&est), w.state_dim);
    TEST_ASSERT_EQUAL_UINT64(w.update, w.flops);
    TEST_ASSERT_GREATER_THAN_UINT64(vl_work_joint_update(vl_state_dim(&est), 7), w.flops - 1u);
    /* The seven more observations narrow the position (3 x 3 block of rho, row-major 6 x 6). */
    for (int i = 0; i < 3; ++i) {
        TEST_ASSERT_TRUE(after.covariance[7 * i] < before.covariance[7 * i]);
    }
    /* Nothing is left: a second call does nothing and leaves the work as it was. */
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    TEST_ASSERT_EQUAL_UINT64(7, vl_get_counters(&est)->observations_deferred_used);
    vl_work_t again;
    vl_get_work(&est, &again);
    TEST_ASSERT_EQUAL_UINT64(w.flops, again.flops);
}

void test_deferred_update_equals_the_unbounded_joint_update(void)
{
    /* At rest on exact pixels the correction is next to zero (1e-7 m), so the deferred rows are
     * linearized where the frame's were, and two sequential updates must leave the covariance of
     * one joint update, to the digits that correction moves (rows left out would move the
     * landmarks' variances by their whole size). */
    static double P_deferred[VL_COV_LD * VL_COV_LD];
    vl_config_t cfg;
    twelve_tracks_under_bound(&cfg, 1);
    const uint32_t n = vl_state_dim(&est);
    memcpy(P_deferred, est.P, sizeof(P_deferred));
    cfg.max_update_observations = 0;
    (void)update_window_of(&cfg, 12);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est)); /* its landmark block's downdate */
    TEST_ASSERT_EQUAL_UINT64(12, vl_get_counters(&est)->observations_used);
    TEST_ASSERT_EQUAL_UINT32(n, vl_state_dim(&est));
    double scale = 0.0, diff = 0.0;
    for (uint32_t j = 0; j < n; ++j) {
        for (uint32_t i = 0; i < n; ++i) {
            const double a = est.P[(size_t)j * VL_COV_LD + i], b = P_deferred[(size_t)j * VL_COV_LD + i];
            scale = fmax(scale, fabs(a));
            diff = fmax(diff, fabs(a - b));
        }
    }
    TEST_ASSERT_TRUE(scale > 0.0);
    TEST_ASSERT_TRUE_MESSAGE(diff <= 1e-6 * scale, "sequential updates differ from the joint one");
}

void test_deferred_observations_are_dropped_by_the_next_input_a_reset_or_when_off(void)
{
    vl_config_t cfg;
    twelve_tracks_under_bound(&cfg, 0);
    vl_imu_sample_t s = vl_test_imu_at(200000, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(&est));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    TEST_ASSERT_EQUAL_UINT64(0, vl_get_counters(&est)->observations_deferred_used);
    TEST_ASSERT_EQUAL_UINT64(7, vl_get_counters(&est)->observations_deferred_dropped); /* counted, not lost */
    TEST_ASSERT_EQUAL_UINT64(5, vl_get_counters(&est)->observations_used);

    /* A reset between the pose and the deferred update drops them as well, and says so. */
    twelve_tracks_under_bound(&cfg, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_reset(&est));
    TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(&est));
    TEST_ASSERT_EQUAL_UINT64(7, vl_get_counters(&est)->observations_deferred_dropped);

    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_work = 0.0;
    cfg.max_update_observations = 5;
    cfg.apply_deferred = 0;
    (void)update_window_of(&cfg, 12);
    TEST_ASSERT_EQUAL_UINT64(7, vl_get_counters(&est)->observations_deferred);
    TEST_ASSERT_EQUAL_UINT64(7, vl_get_counters(&est)->observations_deferred_dropped);
    TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(&est));
    TEST_ASSERT_EQUAL_INT(VL_ERR_NULL, vl_update_deferred(NULL));
    TEST_ASSERT_EQUAL_UINT32(0, vl_deferred_pending(NULL));
}

void test_deferred_work_bound_applies_at_least_one(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_update_work = 0.0;
    cfg.max_update_observations = 5;
    const uint32_t n = VL_CORE_DIM + 3u * 12u;
    cfg.max_deferred_work = (double)vl_work_joint_update(n, 3u) * 1e-6;
    (void)update_window_of(&cfg, 12);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    TEST_ASSERT_EQUAL_UINT64(3, vl_get_counters(&est)->observations_deferred_used);
    TEST_ASSERT_EQUAL_UINT64(4, vl_get_counters(&est)->observations_deferred_dropped); /* past the bound */
    cfg.max_deferred_work = 1e-9;
    (void)update_window_of(&cfg, 12);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->observations_deferred_used);
    TEST_ASSERT_EQUAL_UINT64(6, vl_get_counters(&est)->observations_deferred_dropped);
}

void test_admissions_per_frame_are_bounded_and_the_rest_wait(void)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    cfg.max_admissions = 5;
    vl_imu_sample_t s = start_at(&cfg, 0);
    const uint32_t expected[3] = {5, 10, 12};
    for (int f = 0; f < 3; ++f) {
        s.utime = 100000 * (int64_t)f;
        if (f > 0) {
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        }
        make_frame(&cfg, &frame, s.utime, 12, 0); /* the same 12 tracks, at rest */
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
        TEST_ASSERT_EQUAL_UINT32(expected[f], vl_window_size(&est));
    }
    const vl_counters_t *c = vl_get_counters(&est);
    TEST_ASSERT_EQUAL_UINT64(12, c->landmarks_initialized);
    TEST_ASSERT_EQUAL_UINT64(7 + 2, c->landmarks_deferred);
}

/*
 * A sparse frame whose two observations disagree: one landmark stays where the
 * vehicle at rest saw it, the other jumps 25 px sideways (a moving object). No
 * single-observation hypothesis explains both, so RANSAC has no consensus and the
 * gate's verdict against the prediction decides: the still landmark is used, the
 * jump is not, and the pose stays at rest. Trusting the first hypothesis drawn
 * instead moves the vehicle 0.15 m toward the jump whenever the jump is drawn
 * first, so the jump comes at several frame indices (they seed the draws).
 */
/*
 * Two landmarks ahead of a vehicle at rest, admitted at the first frame; frames 1 to
 * last follow, and in the last one the second landmark's pixels move by (du, dv).
 * *before is the pose before that frame.
 */
static void two_landmarks_then_a_jump(int64_t last, double du, double dv, vl_pose_t *before)
{
    static vl_stereo_frame_t frame;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.min_track_length = 1;
    vl_imu_sample_t s = start_at(&cfg, 0);
    make_frame(&cfg, &frame, 0, 2, 0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(2, vl_window_size(&est));
    for (int64_t step = 1; step <= last; ++step) {
        s.utime = 100000 * step;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        make_frame(&cfg, &frame, s.utime, 2, 0);
        if (step == last) {
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, before));
            frame.obs[1].u_left += du;
            frame.obs[1].u_right += du;
            frame.obs[1].v_left += dv;
            frame.obs[1].v_right += dv;
        }
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    }
}

void test_sparse_frame_without_consensus_keeps_the_gate_verdict(void)
{
    for (int64_t last = 1; last <= 8; ++last) { /* the frame index seeds the hypotheses */
        vl_pose_t before, pose;
        two_landmarks_then_a_jump(last, 25.0, 0.0, &before);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
        const double moved = sqrt(pose.position[0] * pose.position[0] + pose.position[1] * pose.position[1] +
                                  pose.position[2] * pose.position[2]);
        printf("jump at frame %d: pose moved %.4f m, %llu observations gated\n", (int)last, moved,
               (unsigned long long)vl_get_counters(&est)->observations_gated);
        TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->observations_gated);
        TEST_ASSERT_TRUE(moved < 0.01);
    }
}

/*
 * A frame of two rows has no majority to outvote an outlier: of its six pixel
 * variance samples the median is the outlier's smallest. A 60 px mismatch would
 * multiply the pixel variance by several at once; capped at 100 variances in use,
 * a sample moves it by at most w x 100 / 0.455 (w = 1 - exp(-2 / 1000) for two rows):
 * 44%, 20% in standard deviation.
 */
void test_an_outlier_in_a_sparse_frame_moves_the_pixel_noise_a_bounded_step(void)
{
    vl_pose_t before, after;
    two_landmarks_then_a_jump(3, 60.0, 60.0, &before);
    TEST_ASSERT_EQUAL_UINT64(1, vl_get_counters(&est)->observations_gated);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &after));
    const double ratio = after.pixel_noise / before.pixel_noise;
    printf("pixel noise %.4f px before the outlier, %.4f px after (x%.4f)\n", before.pixel_noise, after.pixel_noise,
           ratio);
    TEST_ASSERT_TRUE(ratio > 1.15); /* the outlier counts... */
    TEST_ASSERT_TRUE(ratio < 1.21); /* ...as a bounded step */
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_init_rejects_null_and_missing_calibration);
    RUN_TEST(test_init_rejects_misaligned_estimator);
    RUN_TEST(test_config_check_rejects_out_of_range_values);
    RUN_TEST(test_propagate_rejects_nan_and_counts_it);
    RUN_TEST(test_propagate_rejects_non_increasing_time);
    RUN_TEST(test_update_before_first_imu_is_not_ready);
    RUN_TEST(test_update_rejects_frame_out_of_time_order);
    RUN_TEST(test_update_truncates_oversized_frame_and_counts_it);
    RUN_TEST(test_update_counts_invalid_observations);
    RUN_TEST(test_propagate_follows_exponential_map);
    RUN_TEST(test_propagate_integrates_the_line_between_instantaneous_samples);
    RUN_TEST(test_la_update_equals_dense_kalman_formula);
    RUN_TEST(test_la_update_refuses_indefinite_innovation_covariance);
    RUN_TEST(test_la_pending_downdate_equals_the_updates_in_turn);
    RUN_TEST(test_la_move_block_leaves_the_exact_marginal);
    RUN_TEST(test_flush_hands_every_landmark_to_the_sink_with_its_marginal);
    RUN_TEST(test_window_never_exceeds_its_limit_and_keeps_observed_landmarks);
    RUN_TEST(test_a_sparse_frame_admits_its_new_tracks_at_first_sight);
    RUN_TEST(test_window_admits_the_largest_disparity_first);
    RUN_TEST(test_get_landmarks_reports_capacity_shortfall);
    RUN_TEST(test_update_uses_at_most_max_update_observations);
    RUN_TEST(test_update_work_bound_uses_fewer_observations_in_a_larger_window);
    RUN_TEST(test_rotated_deferrals_reach_every_landmark_in_turn);
    RUN_TEST(test_deferred_observations_are_applied_after_the_pose);
    RUN_TEST(test_deferred_update_equals_the_unbounded_joint_update);
    RUN_TEST(test_deferred_observations_are_dropped_by_the_next_input_a_reset_or_when_off);
    RUN_TEST(test_deferred_work_bound_applies_at_least_one);
    RUN_TEST(test_the_pose_is_final_at_vl_update_and_the_upkeep_follows_it);
    RUN_TEST(test_the_next_input_does_the_upkeep_vl_update_deferred_was_not_called_for);
    RUN_TEST(test_admissions_per_frame_are_bounded_and_the_rest_wait);
    RUN_TEST(test_update_counts_a_repeated_image_and_nothing_else);
    RUN_TEST(test_repeat_noise_moves_the_observed_landmarks_together_and_nothing_else);
    RUN_TEST(test_repeat_noise_acts_at_repeated_images_only);
    RUN_TEST(test_carried_walk_widens_the_carried_landmarks_alone);
    RUN_TEST(test_sparse_frame_without_consensus_keeps_the_gate_verdict);
    RUN_TEST(test_an_outlier_in_a_sparse_frame_moves_the_pixel_noise_a_bounded_step);
    return UNITY_END();
}
