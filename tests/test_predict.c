/*
 * The deferred prediction (vl_predict.c): K steps accumulated in core
 * coordinates and applied to P once give the step-by-step propagation
 * P <- Phi P Phi^T + G Q G^T + E W E^T (written out densely here), and P's
 * core block is current after every step.
 */
#include <math.h>
#include <signal.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "unity.h"
#include "vl_estimator_internal.h"
#include "vl_predict.h"
#include "vl_se3.h"
#include "vl_test_util.h"
#include "vl_window.h"
#include "vislam/vislam.h"

#define LANDMARKS 6
#define N (VL_CORE_DIM + 3 * LANDMARKS)

static vl_estimator_t est;
static vl_estimator_t settled; /* a copy of est, settled, to compare readers against */
static vl_stereo_frame_t frame;
static uint64_t rng = 0x9e3779b97f4a7c15ull;

void setUp(void)
{
}

void tearDown(void)
{
}

/* Uniform in [-1, 1) (xorshift64*): the same sequence on every host. */
static double uniform(void)
{
    rng ^= rng >> 12;
    rng ^= rng << 25;
    rng ^= rng >> 27;
    return (double)((rng * 0x2545f4914f6cdd1dull) >> 11) / 9007199254740992.0 * 2.0 - 1.0;
}

/* C = A B for dense row-major n x n matrices. */
static void matmul_n(const double *A, const double *B, double *C, int n)
{
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            double s = 0.0;
            for (int k = 0; k < n; ++k) {
                s += A[n * i + k] * B[n * k + j];
            }
            C[n * i + j] = s;
        }
    }
}

/*
 * An initialized estimator whose window holds LANDMARKS random points and whose
 * P (n x n, also returned row-major in Pref) is a random SPD matrix; with the
 * offsets (states 6..11) or the sensor position (12..14) not estimated their rows
 * and columns are zero, as the estimator keeps them.
 */
static void random_state(vl_mode_t mode, int offsets, int sensor, double *Pref)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_test_kitti_calibration(&cfg.calibration, 1);
    cfg.mode = mode;
    cfg.estimate_input_offsets = offsets;
    cfg.velocity_sensor_std_x = sensor ? 1.0 : 0.0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    est.num_landmarks = LANDMARKS;
    for (int i = 0; i < 3 * LANDMARKS; ++i) {
        est.landmark_state[i] = 20.0 * uniform();
    }
    double A[N * N];
    for (int i = 0; i < N * N; ++i) {
        A[i] = uniform();
    }
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < N; ++j) {
            double s = (i == j) ? 0.5 : 0.0;
            for (int k = 0; k < N; ++k) {
                s += A[N * i + k] * A[N * j + k];
            }
            const int offset_ij = (i >= 6 && i < 12) || (j >= 6 && j < 12);
            const int sensor_ij = (i >= 12 && i < 15) || (j >= 12 && j < 15);
            Pref[N * i + j] = ((offsets || !offset_ij) && (sensor || !sensor_ij)) ? 0.01 * s : 0.0;
            *vl_P_at(&est, (uint32_t)i, (uint32_t)j) = Pref[N * i + j];
        }
    }
}

/* B M for a map M (6 x cols, row-major) on the pose: M on the pose rows, hat(l_s) times its
 * rotation rows on landmark s's (zero when mapping), zero on the parameters'. N x cols. */
static void lift(vl_mode_t mode, const double *M, int cols, double *out)
{
    memset(out, 0, sizeof(double) * N * (size_t)cols);
    memcpy(out, M, sizeof(double) * 6 * (size_t)cols);
    for (int s = 0; s < LANDMARKS && mode != VL_MODE_MAPPING; ++s) {
        const double *l = &est.landmark_state[3 * s];
        double L[9];
        vl_skew(l, L);
        for (int r = 0; r < 3; ++r) {
            for (int j = 0; j < cols; ++j) {
                double v = 0.0;
                for (int k = 0; k < 3; ++k) {
                    v += L[3 * r + k] * M[cols * (3 + k) + j];
                }
                out[cols * (VL_CORE_DIM + 3 * s + r) + j] = v;
            }
        }
    }
}

/*
 * One step, densely: G = B Gp, Phi = I + B Gt E^T (parameters) with the offsets' rows scaled by a,
 * P <- Phi P Phi^T + G Q G^T + (1 - a^2) P_bb + E W E^T (P_bb the offsets' block before the step,
 * W on the offsets).
 */
static void dense_step(vl_mode_t mode, const double Gp[36], const double *Gt, const double q[6], const double *w,
                       double a, double *P)
{
    static double G[N * 6], Gtn[N * VL_PARAM_DIM], Phi[N * N], T[N * N], PhiT[N * N];
    double Pbb[36];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            Pbb[6 * i + j] = P[N * (6 + i) + 6 + j];
        }
    }
    lift(mode, Gp, 6, G);
    if (Gt != NULL) {
        lift(mode, Gt, VL_PARAM_DIM, Gtn);
    }
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < N; ++j) {
            Phi[N * i + j] = (i == j) ? 1.0 : 0.0;
            if (Gt != NULL && j >= 6 && j < VL_CORE_DIM) {
                Phi[N * i + j] += Gtn[VL_PARAM_DIM * i + (j - 6)];
            }
            if (Gt != NULL && i >= 6 && i < 12) {
                Phi[N * i + j] *= a;
            }
        }
    }
    matmul_n(Phi, P, T, N);
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < N; ++j) {
            PhiT[N * i + j] = Phi[N * j + i];
        }
    }
    matmul_n(T, PhiT, P, N);
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < N; ++j) {
            for (int k = 0; k < 6; ++k) {
                P[N * i + j] += G[6 * i + k] * q[k] * G[6 * j + k];
            }
        }
    }
    for (int i = 0; i < 6 && Gt != NULL; ++i) {
        for (int j = 0; j < 6; ++j) {
            P[N * (6 + i) + 6 + j] += (1.0 - a * a) * Pbb[6 * i + j];
        }
    }
    for (int k = 0; k < 6 && w != NULL; ++k) {
        P[N * (6 + k) + 6 + k] += w[k];
    }
}

/* Largest |P(i, j) - Pref(i, j)| over the first `dim` rows and columns, relative to max |Pref|. */
static double relative_error(const double *Pref, int dim)
{
    double err = 0.0, scale = 0.0;
    for (int i = 0; i < dim; ++i) {
        for (int j = 0; j < dim; ++j) {
            const double ref = Pref[N * i + j];
            err = fmax(err, fabs(est.P[(size_t)j * VL_LD + i] - ref));
            scale = fmax(scale, fabs(ref));
        }
    }
    return err / scale;
}

static void check_deferred_matches_sequential(vl_mode_t mode, int offsets, int sensor, int steps, double a)
{
    static double Pref[N * N];
    random_state(mode, offsets, sensor, Pref);
    for (int k = 0; k < steps; ++k) {
        double Gp[36], Gt[6 * VL_PARAM_DIM] = {0}, q[6], w[6];
        for (int i = 0; i < 36; ++i) {
            Gp[i] = 0.3 * uniform();
        }
        for (int i = 0; i < 6; ++i) {
            for (int j = 0; j < VL_PARAM_DIM; ++j) {
                const int on = j < 6 ? offsets : sensor;
                Gt[VL_PARAM_DIM * i + j] = on ? (j < 6 ? Gp[6 * i + j] : 0.3 * uniform()) : 0.0;
            }
            q[i] = 0.01 * (1.5 + uniform());
            w[i] = 0.001 * (1.5 + uniform());
        }
        const double *coupled = (offsets || sensor) ? Gt : NULL;
        dense_step(mode, Gp, coupled, q, offsets ? w : NULL, a, Pref);
        vl_predict_defer(&est, Gp, coupled, q, offsets ? w : NULL, a);
        TEST_ASSERT_EQUAL_UINT32((uint32_t)k + 1u, est.deferred.steps);
        /* The core block (what vl_get_pose reads) is current between updates. */
        TEST_ASSERT_TRUE(relative_error(Pref, VL_CORE_DIM) < 1e-12);
        /* So is what vl_get_landmarks reports, computed from the accumulators. */
        for (uint32_t s = 0; s < LANDMARKS; ++s) {
            double B[36];
            vl_predict_landmark_block(&est, s, B);
            const uint32_t c = vl_landmark_col(s);
            const uint32_t idx[6] = {3, 4, 5, c, c + 1, c + 2};
            for (int i = 0; i < 6; ++i) {
                for (int j = 0; j < 6; ++j) {
                    const double ref = Pref[N * idx[i] + idx[j]];
                    TEST_ASSERT_DOUBLE_WITHIN(1e-10 * (1.0 + fabs(ref)), ref, B[6 * i + j]);
                }
            }
        }
    }
    double core[VL_CORE_DIM * VL_CORE_DIM];
    for (int j = 0; j < VL_CORE_DIM; ++j) {
        memcpy(&core[VL_CORE_DIM * j], &est.P[(size_t)j * VL_LD], sizeof(double) * VL_CORE_DIM);
    }
    vl_predict_settle(&est);
    TEST_ASSERT_EQUAL_UINT32(0, est.deferred.steps);
    const double err = relative_error(Pref, N);
    TEST_ASSERT_TRUE_MESSAGE(err < 1e-10, "the settled P differs from the sequential propagation");
    for (int j = 0; j < VL_CORE_DIM; ++j) {
        TEST_ASSERT_EQUAL_MEMORY(&core[VL_CORE_DIM * j], &est.P[(size_t)j * VL_LD], sizeof(double) * VL_CORE_DIM);
    }
    for (int i = 0; i < N; ++i) {
        for (int j = 0; j < i; ++j) {
            TEST_ASSERT_EQUAL_DOUBLE(est.P[(size_t)j * VL_LD + i], est.P[(size_t)i * VL_LD + j]);
        }
    }
}

void test_slam_with_offsets(void)
{
    check_deferred_matches_sequential(VL_MODE_SLAM, 1, 0, 1, 1.0);
    check_deferred_matches_sequential(VL_MODE_SLAM, 1, 0, 2, 1.0);
    check_deferred_matches_sequential(VL_MODE_SLAM, 1, 0, 7, 1.0);
}

void test_slam_without_offsets(void)
{
    check_deferred_matches_sequential(VL_MODE_SLAM, 0, 0, 1, 1.0);
    check_deferred_matches_sequential(VL_MODE_SLAM, 0, 0, 2, 1.0);
    check_deferred_matches_sequential(VL_MODE_SLAM, 0, 0, 7, 1.0);
}

void test_slam_with_the_sensor_position(void)
{
    for (int offsets = 0; offsets <= 1; ++offsets) {
        check_deferred_matches_sequential(VL_MODE_SLAM, offsets, 1, 1, 1.0);
        check_deferred_matches_sequential(VL_MODE_SLAM, offsets, 1, 2, 1.0);
        check_deferred_matches_sequential(VL_MODE_SLAM, offsets, 1, 7, 1.0);
    }
}

/* The offsets' correlations fading (offset_correlation_time): D P D plus their block refilled. */
void test_slam_with_the_offsets_decaying(void)
{
    for (int sensor = 0; sensor <= 1; ++sensor) {
        check_deferred_matches_sequential(VL_MODE_SLAM, 1, sensor, 1, 0.7);
        check_deferred_matches_sequential(VL_MODE_SLAM, 1, sensor, 2, 0.7);
        check_deferred_matches_sequential(VL_MODE_SLAM, 1, sensor, 7, 0.9);
    }
}

void test_mapping_with_and_without_offsets(void)
{
    for (int offsets = 0; offsets <= 1; ++offsets) {
        check_deferred_matches_sequential(VL_MODE_MAPPING, offsets, offsets, 1, offsets ? 0.8 : 1.0);
        check_deferred_matches_sequential(VL_MODE_MAPPING, offsets, offsets, 2, 1.0);
        check_deferred_matches_sequential(VL_MODE_MAPPING, offsets, offsets, 7, offsets ? 0.8 : 1.0);
    }
}

/*
 * Through the API: IMU samples leave the steps pending and the pose current; a
 * frame settles them; vl_get_landmarks between the two reports what a settled
 * P holds.
 */
void test_samples_defer_and_a_frame_settles(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_test_kitti_calibration(&cfg.calibration, 1);
    cfg.min_track_length = 1;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = vl_test_imu_at(1000000, 1.0, 0.1);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    frame.utime = s.utime;
    frame.count = 20;
    for (uint32_t i = 0; i < frame.count; ++i) {
        double pw[3];
        vl_test_point_ahead(i, pw);
        vl_test_observe(&cfg.calibration, pw, (int32_t)i, &frame.obs[i]);
    }
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(20, vl_window_size(&est));
    TEST_ASSERT_EQUAL_UINT32(0, est.deferred.steps);
    for (int k = 0; k < 5; ++k) {
        s.utime += 10000;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    }
    TEST_ASSERT_EQUAL_UINT32(5, est.deferred.steps);

    memcpy(&settled, &est, sizeof(est));
    vl_predict_settle(&settled);
    vl_pose_t pose, pose_settled;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&settled, &pose_settled));
    TEST_ASSERT_EQUAL_MEMORY(pose_settled.covariance, pose.covariance, sizeof(pose.covariance));
    vl_landmark_t lm[20], lm_settled[20];
    size_t count = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&est, lm, 20, &count));
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_landmarks(&settled, lm_settled, 20, &count));
    for (int i = 0; i < 20; ++i) {
        VL_TEST_ASSERT_CLOSE(lm_settled[i].covariance, lm[i].covariance, 9, 1e-12);
    }

    /* A frame applies the steps before it reads P. */
    frame.utime = s.utime + 5000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(0, est.deferred.steps);
    /* A refused frame leaves them pending; vl_flush_landmarks applies them too. */
    s.utime += 10000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    frame.utime = s.utime - 1;
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(1, est.deferred.steps);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_flush_landmarks(&est));
    TEST_ASSERT_EQUAL_UINT32(0, est.deferred.steps);
    TEST_ASSERT_EQUAL_UINT32(0, vl_window_size(&est));
}

/*
 * A reader of P beyond the core block with steps pending (here marginalization,
 * called without the entry point that settles first) stops at vl_P's assert in
 * the checked core the tests link.
 */
void test_a_stale_read_stops_at_the_assert(void)
{
    static double Pref[N * N];
    random_state(VL_MODE_SLAM, 1, 0, Pref);
    const double Gp[36] = {0.1}, q[6] = {0.01, 0.01, 0.01, 0.01, 0.01, 0.01};
    vl_predict_defer(&est, Gp, NULL, q, NULL, 1.0);
    fflush(stdout);
    const pid_t child = fork();
    TEST_ASSERT_TRUE(child >= 0);
    if (child == 0) {
        (void)freopen("/dev/null", "w", stderr); /* the assert's message */
        vl_window_marginalize(&est, 0);
        _exit(0);
    }
    int status = 0;
    TEST_ASSERT_EQUAL_INT(child, waitpid(child, &status, 0));
    TEST_ASSERT_TRUE_MESSAGE(WIFSIGNALED(status) && WTERMSIG(status) == SIGABRT, "a stale read went unnoticed");
    vl_predict_settle(&est);
    vl_window_marginalize(&est, 0); /* settled: allowed */
    TEST_ASSERT_EQUAL_UINT32(LANDMARKS - 1, vl_window_size(&est));
}

/*
 * A velocity sensor away from the body origin (velocity_sensor_*): spinning in place at
 * 1 rad/s about z, a sensor at p = (1, 0.5, 0) m sees w x p; with p configured the body
 * origin stays put and the pose reports its velocity as zero; without it, it circles.
 */
void test_a_velocity_sensor_lever_arm_is_taken_out(void)
{
    const double p[3] = {1.0, 0.5, 0.0}, wz = 1.0;
    const double seen[3] = {-wz * p[1], wz * p[0], 0.0}; /* w x p */
    double end[2][3];
    for (int lever = 0; lever < 2; ++lever) {
        vl_config_t cfg;
        vl_test_kitti_config(&cfg);
        cfg.mode = VL_MODE_IMU_ONLY;
        cfg.velocity_sensor_x = lever ? p[0] : 0.0;
        cfg.velocity_sensor_y = lever ? p[1] : 0.0;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
        for (int k = 0; k <= 20; ++k) {
            vl_imu_sample_t s = vl_test_imu_at(VL_TEST_T0_US + k * VL_TEST_STEP_US, 0.0, wz);
            memcpy(s.linear_velocity, seen, sizeof(seen));
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        }
        vl_pose_t pose;
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
        memcpy(end[lever], pose.position, sizeof(end[lever]));
        if (lever) {
            for (int i = 0; i < 3; ++i) {
                TEST_ASSERT_DOUBLE_WITHIN(1e-12, 0.0, pose.linear_velocity[i]);
            }
        }
    }
    TEST_ASSERT_TRUE(vl_norm3(end[1]) < 1e-9); /* 2 s of spinning: the origin has not moved */
    TEST_ASSERT_TRUE(vl_norm3(end[0]) > 0.5);  /* taken as the origin's velocity, it circles */
}

/*
 * The lever arm's noise: one step from rest at the identity pose (G = -tau I), with the
 * sensor at p the pose covariance is tau^2 T Q T^T, T = [I hat(p); 0 I], Q = diag(sv^2 I,
 * sw^2 I): the angular noise reaches the position through the lever arm.
 */
void test_a_velocity_sensor_lever_arm_carries_the_angular_noise(void)
{
    const double p[3] = {1.5, -0.7, 0.4}, sv = 0.1, sw = 0.05, tau = 0.1;
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.mode = VL_MODE_IMU_ONLY;
    cfg.adaptive_noise = 0;
    cfg.estimate_input_offsets = 0;
    cfg.interpolate_velocities = 0;
    cfg.linear_velocity_noise = sv;
    cfg.angular_velocity_noise = sw;
    cfg.velocity_sensor_x = p[0];
    cfg.velocity_sensor_y = p[1];
    cfg.velocity_sensor_z = p[2];
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_imu_sample_t s = vl_test_imu_at(VL_TEST_T0_US, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    s.utime += (int64_t)(tau * 1e6);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_pose_t pose;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_get_pose(&est, &pose));
    double S[9], expected[36];
    vl_skew(p, S);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            double ss = 0.0; /* (hat(p) hat(p)^T)_ij */
            for (int k = 0; k < 3; ++k) {
                ss += S[3 * i + k] * S[3 * j + k];
            }
            expected[6 * i + j] = tau * tau * ((i == j ? sv * sv : 0.0) + sw * sw * ss);
            expected[6 * i + 3 + j] = expected[6 * (3 + j) + i] = tau * tau * sw * sw * S[3 * i + j];
            expected[6 * (3 + i) + 3 + j] = i == j ? tau * tau * sw * sw : 0.0;
        }
    }
    for (int i = 0; i < 36; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-15, expected[i], pose.covariance[i]);
    }
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_slam_with_offsets);
    RUN_TEST(test_slam_without_offsets);
    RUN_TEST(test_slam_with_the_sensor_position);
    RUN_TEST(test_slam_with_the_offsets_decaying);
    RUN_TEST(test_mapping_with_and_without_offsets);
    RUN_TEST(test_samples_defer_and_a_frame_settles);
    RUN_TEST(test_a_stale_read_stops_at_the_assert);
    RUN_TEST(test_a_velocity_sensor_lever_arm_is_taken_out);
    RUN_TEST(test_a_velocity_sensor_lever_arm_carries_the_angular_noise);
    return UNITY_END();
}
