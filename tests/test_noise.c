/* Unit tests of the noise adaptation: the angular offsets reopened, the pixel estimate's floor. */
#include <math.h>
#include <string.h>

#include "unity.h"
#include "vl_test_util.h"
#include "vislam/vislam.h"
#include "vl_estimator_internal.h"
#include "vl_noise.h"

static vl_estimator_t est;
static double before[VL_LD * VL_LD];

#define NUM_POINTS 20u
#define STEPS 40

/* vl_init, then STEPS steps of a vehicle standing before fixed points: the frames hold the pose
 * still, so the offsets are learned and correlated with the pose and the landmarks. */
static void stand(const vl_config_t *cfg)
{
    static vl_stereo_frame_t frame;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, cfg));
    for (int k = 0; k < STEPS; ++k) {
        const int64_t t = VL_TEST_T0_US + k * VL_TEST_STEP_US;
        const vl_imu_sample_t s = vl_test_imu_at(t, 0.0, 0.0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
        vl_test_frame_ahead(&cfg->calibration, &frame, t, NUM_POINTS, 0);
        TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    }
    TEST_ASSERT_TRUE(vl_state_dim(&est) > VL_CORE_DIM); /* landmarks in the state */
}

static void keep_P(void)
{
    memcpy(before, est.P, sizeof(before));
}

static int is_angular_offset(uint32_t i)
{
    return i >= VL_IDX_OFFSET_ANG && i < VL_IDX_OFFSET_ANG + 3u;
}

static double P_before(uint32_t i, uint32_t j)
{
    return before[(size_t)j * VL_LD + i];
}

static void assert_P_unchanged(void)
{
    TEST_ASSERT_EQUAL_MEMORY(before, est.P, sizeof(before));
}

/* The angular variance rising 4x past where it was last reopened scales each angular offset's
 * variance by 4 (under its prior), keeps every correlation, and leaves the rest of P alone. */
void test_angular_offsets_reopen_as_the_angular_noise_rises(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    stand(&cfg);
    const double configured = cfg.angular_velocity_noise * cfg.angular_velocity_noise;
    TEST_ASSERT_EQUAL_DOUBLE(VL_NOISE_REOPEN_RATIO * configured, est.angular_velocity_var_reopened);
    keep_P();
    est.angular_velocity_var = 4.0 * VL_NOISE_REOPEN_RATIO * configured;
    vl_noise_reopen_angular_offset(&est);
    TEST_ASSERT_EQUAL_DOUBLE(est.angular_velocity_var, est.angular_velocity_var_reopened);

    const uint32_t n = vl_state_dim(&est);
    const double prior = cfg.angular_offset_prior * cfg.angular_offset_prior;
    for (uint32_t i = VL_IDX_OFFSET_ANG; i < VL_IDX_OFFSET_ANG + 3u; ++i) {
        TEST_ASSERT_TRUE(4.0 * P_before(i, i) < prior); /* the cap is not what this test sees */
        TEST_ASSERT_DOUBLE_WITHIN(1e-12 * P_before(i, i), 4.0 * P_before(i, i), vl_P_value(&est, i, i));
    }
    double largest_correlation = 0.0;
    for (uint32_t i = 0; i < n; ++i) {
        for (uint32_t j = 0; j < n; ++j) {
            const double now = vl_P_value(&est, i, j);
            if (!is_angular_offset(i) && !is_angular_offset(j)) {
                TEST_ASSERT_TRUE(P_before(i, j) == now); /* pose, linear offsets, landmarks: bit for bit */
                continue;
            }
            const double was = P_before(i, j) / sqrt(P_before(i, i) * P_before(j, j));
            const double is = now / sqrt(vl_P_value(&est, i, i) * vl_P_value(&est, j, j));
            TEST_ASSERT_DOUBLE_WITHIN(1e-12, was, is);
            if (i != j) {
                largest_correlation = fmax(largest_correlation, fabs(was));
            }
        }
    }
    TEST_ASSERT_TRUE(largest_correlation > 0.1); /* there were correlations to keep */

    keep_P(); /* no further rise, nothing more */
    vl_noise_reopen_angular_offset(&est);
    assert_P_unchanged();
}

/* Under VL_NOISE_REOPEN_RATIO x the configured variance (the adaptation's own spread), or after a
 * fall, the offsets keep what they learned. */
void test_angular_offsets_stay_while_the_noise_is_near_its_prior(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    stand(&cfg);
    const double configured = cfg.angular_velocity_noise * cfg.angular_velocity_noise;
    keep_P();
    est.angular_velocity_var = 0.99 * VL_NOISE_REOPEN_RATIO * configured;
    vl_noise_reopen_angular_offset(&est);
    assert_P_unchanged();
    est.angular_velocity_var = 0.1 * configured;
    vl_noise_reopen_angular_offset(&est);
    assert_P_unchanged();
    TEST_ASSERT_EQUAL_DOUBLE(VL_NOISE_REOPEN_RATIO * configured, est.angular_velocity_var_reopened);
}

/* A rise of 10,000x gives back no more than the offsets' prior. */
void test_reopening_stops_at_the_offsets_prior(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    stand(&cfg);
    est.angular_velocity_var = 1e4 * est.angular_velocity_var_reopened;
    vl_noise_reopen_angular_offset(&est);
    const double prior = cfg.angular_offset_prior * cfg.angular_offset_prior;
    for (uint32_t i = VL_IDX_OFFSET_ANG; i < VL_IDX_OFFSET_ANG + 3u; ++i) {
        TEST_ASSERT_DOUBLE_WITHIN(1e-12 * prior, prior, vl_P_value(&est, i, i));
    }
}

/* Without offset states there is nothing to reopen, and their covariance stays zero. */
void test_no_reopening_without_offset_states(void)
{
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    cfg.estimate_input_offsets = 0;
    stand(&cfg);
    keep_P();
    est.angular_velocity_var = 100.0 * est.angular_velocity_var_reopened;
    vl_noise_reopen_angular_offset(&est);
    assert_P_unchanged();
}

/*
 * A dense frame whose rows were all rejected and kept less than the fit's spread (residual zero,
 * the pose uncertain) has a median pixel sample under zero: it is floored at a hundredth of the
 * variance in use, as the cap mirrors, so the average steps toward that, never under zero (which
 * the clamp turned into the noise 100x under the configured).
 */
void test_a_pixel_sample_under_zero_is_floored(void)
{
    enum { ROWS = 20 };
    static vl_la_obs_t rows[ROWS];
    vl_config_t cfg;
    vl_test_kitti_config(&cfg);
    stand(&cfg);
    memset(rows, 0, sizeof(rows));
    for (int i = 0; i < ROWS; ++i) {
        for (int r = 0; r < 3; ++r) {
            rows[i].H_pose[6 * r + r] = 1e4; /* px per m: (H P H^T)_rr far over the pixel variance */
            rows[i].noise_var[r] = est.pixel_var;
        }
        rows[i].landmark_col = VL_CORE_DIM;
    }
    memset(est.work_dx, 0, sizeof(est.work_dx));
    const double var = est.pixel_var;
    TEST_ASSERT_TRUE(1e8 * vl_P_value(&est, 0, 0) > 1e3 * var); /* each sample e^2 - fit is under zero */
    vl_noise_adapt_pixel(&est, rows, 0, 0, ROWS, ROWS);
    /* one frame's step toward var / 100: at most its weight (20 observations of 1,000 or 100) */
    const double w = 1.0 - exp(-(double)ROWS / 100.0);
    TEST_ASSERT_TRUE(est.pixel_var < var);
    TEST_ASSERT_TRUE(est.pixel_var >= (1.0 - w) * var + w * var / 100.0 - 1e-12);
}

void setUp(void)
{
}

void tearDown(void)
{
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_angular_offsets_reopen_as_the_angular_noise_rises);
    RUN_TEST(test_angular_offsets_stay_while_the_noise_is_near_its_prior);
    RUN_TEST(test_reopening_stops_at_the_offsets_prior);
    RUN_TEST(test_no_reopening_without_offset_states);
    RUN_TEST(test_a_pixel_sample_under_zero_is_floored);
    return UNITY_END();
}
