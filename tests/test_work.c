/* vl_get_work: the per-stage arithmetic the core counts for its last step. */
#include <string.h>

#include "unity.h"
#include "vl_test_util.h"
#include "vislam/vislam.h"

static vl_estimator_t est;
static vl_stereo_frame_t frame;

void setUp(void)
{
}

void tearDown(void)
{
}

/* Outlier handling and noise adaptation off, no update bound: an update uses every observation. */
static void plain_config(vl_config_t *cfg)
{
    vl_test_kitti_config(cfg);
    cfg->gate_chi2 = 0.0;
    cfg->adaptive_noise = 0;
    cfg->max_update_observations = 0;
    cfg->min_track_length = 1;
}

/* The frame observing points first_point .. first_point + count - 1 (ids equal to the point's index). */
static void observe(const vl_config_t *cfg, int64_t utime, uint32_t first_point, uint32_t count)
{
    frame.utime = utime;
    frame.count = count;
    for (uint32_t i = 0; i < count; ++i) {
        double pw[3];
        vl_test_point_ahead(first_point + i, pw);
        vl_test_observe(&cfg->calibration, pw, (int32_t)(first_point + i), &frame.obs[i]);
    }
}

/* An estimator at rest whose window holds the first `landmarks` points. */
static void window_of(const vl_config_t *cfg, uint32_t landmarks)
{
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, cfg));
    vl_imu_sample_t s = vl_test_imu_at(1000000, 0.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    observe(cfg, 1000000, 0, landmarks);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_test_update(&est, &frame));
    TEST_ASSERT_EQUAL_UINT32(landmarks, vl_window_size(&est));
}

static uint64_t stage_sum(const vl_work_t *w)
{
    return w->predict + w->gate + w->ransac + w->update + w->rescue + w->window;
}

/* The update's leading terms before the pose: the whitening, the factorization and the core's
 * rows and columns of the downdate; the landmark block's downdate comes after the pose. */
static double update_leading(double n, double m)
{
    const double nl = n - VL_CORE_DIM;
    return n * m * m + m * m * m / 3.0 + (n * n - nl * nl) * m;
}

/* The update stage of a frame observing k of the window's landmarks, 0.1 s later. */
static vl_work_t update_with(const vl_config_t *cfg, uint32_t landmarks, uint32_t k)
{
    window_of(cfg, landmarks);
    observe(cfg, 1100000, 0, k);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    vl_work_t w;
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(w.flops, stage_sum(&w));
    TEST_ASSERT_EQUAL_UINT32(VL_CORE_DIM + 3u * landmarks, w.state_dim);
    TEST_ASSERT_EQUAL_UINT32(3u * k, w.rows);
    return w;
}

/* The work after the pose (vl_update_deferred) of the frame update_with applied. */
static vl_work_t work_after_the_pose(void)
{
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update_deferred(&est));
    vl_work_t w;
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(w.flops, stage_sum(&w));
    return w;
}

void test_zero_after_init_and_for_calls_that_do_nothing(void)
{
    vl_config_t cfg;
    plain_config(&cfg);
    vl_work_t w;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_init(&est, &cfg));
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);

    /* The first IMU sample only sets the clock. */
    vl_imu_sample_t s = vl_test_imu_at(1000000, 1.0, 0.0);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);

    /* A propagation did work; a refused sample right after it did none. */
    s.utime += 10000;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
    vl_get_work(&est, &w);
    TEST_ASSERT_TRUE(w.predict > 0);
    TEST_ASSERT_EQUAL_UINT64(w.predict, w.flops);
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_propagate(&est, &s));
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);

    /* A frame at the state's time with no observations: nothing to predict or update. */
    frame.utime = s.utime;
    frame.count = 0;
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);
    frame.utime = s.utime - 1;
    TEST_ASSERT_EQUAL_INT(VL_ERR_TIME_ORDER, vl_update(&est, &frame));
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);

    memset(&w, 0xff, sizeof(w));
    vl_get_work(NULL, &w);
    TEST_ASSERT_EQUAL_UINT64(0, w.flops);
}

void test_prediction_is_constant_per_sample_and_paid_once_per_frame(void)
{
    vl_config_t cfg;
    plain_config(&cfg);
    double settle[2];
    uint64_t sample_work = 0;
    const uint32_t landmarks[2] = {20, 40};
    for (int i = 0; i < 2; ++i) {
        for (int samples = 1; samples <= 3; samples += 2) {
            window_of(&cfg, landmarks[i]);
            vl_imu_sample_t s = vl_test_imu_at(1000000, 0.0, 0.0);
            for (int k = 0; k < samples; ++k) {
                s.utime += 10000;
                TEST_ASSERT_EQUAL_INT(VL_OK, vl_propagate(&est, &s));
                vl_work_t w;
                vl_get_work(&est, &w);
                /* The pose and the core block, twice (P's and the deferred noise):
                 * the same whatever the window. */
                if (sample_work == 0) {
                    sample_work = w.predict;
                }
                TEST_ASSERT_EQUAL_UINT64(sample_work, w.predict);
                TEST_ASSERT_EQUAL_UINT64(w.predict, w.flops);
                TEST_ASSERT_TRUE(w.predict < 30000u); /* O(core block^2): about 25,000 */
            }
            /* A frame at the last sample's time: no step of its own, the deferred steps applied once. */
            observe(&cfg, s.utime, 0, 0);
            TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
            vl_work_t w;
            vl_get_work(&est, &w);
            const double nl = 3.0 * landmarks[i];
            /* The landmark block's rank-6 product (6 nl^2) and O(nl) rows against the core. */
            TEST_ASSERT_TRUE((double)w.predict >= 6.0 * nl * nl);
            TEST_ASSERT_TRUE((double)w.predict <= 6.0 * nl * nl + 800.0 * nl + 10000.0);
            if (samples == 1) {
                settle[i] = (double)w.predict;
            } else {
                TEST_ASSERT_EQUAL_DOUBLE(settle[i], (double)w.predict); /* paid once, however many samples */
            }
        }
    }
    /* nl from 60 to 120: more than linear (2) with the rows' O(nl) terms, at most the ratio of the squares (4). */
    TEST_ASSERT_TRUE(settle[1] / settle[0] > 2.5 && settle[1] / settle[0] < 4.0);
}

void test_update_grows_with_rows_and_state_as_the_formula_says(void)
{
    vl_config_t cfg;
    plain_config(&cfg);
    const uint32_t cases[4][2] = {{20, 10}, {40, 10}, {40, 20}, {40, 40}}; /* landmarks, observations */
    uint64_t previous = 0;
    for (int c = 0; c < 4; ++c) {
        const vl_work_t w = update_with(&cfg, cases[c][0], cases[c][1]);
        const double n = w.state_dim, m = w.rows;
        const double lead = update_leading(n, m);
        TEST_ASSERT_TRUE(w.update > previous);
        TEST_ASSERT_TRUE((double)w.update >= lead);
        /* Besides the leading terms: P H^T (18 n m), S (about 9 m^2), the correction. */
        TEST_ASSERT_TRUE((double)w.update <= lead + 25.0 * n * m + 12.0 * m * m + 10000.0);
        TEST_ASSERT_EQUAL_UINT64(0, w.gate + w.ransac + w.rescue);
        TEST_ASSERT_TRUE(w.predict > 0 && w.window > 0);
        previous = w.update;
        /* After the pose: the landmark block's lower triangle less m rows' product, and the window's
         * upkeep (nothing was held back). */
        const vl_work_t after = work_after_the_pose();
        const double nl = n - VL_CORE_DIM;
        TEST_ASSERT_EQUAL_DOUBLE(nl * (nl + 1.0) * m, (double)after.update);
        TEST_ASSERT_EQUAL_UINT64(after.update + after.window, after.flops);
    }
}

void test_outlier_stages_count_their_work(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    vl_test_kitti_calibration(&cfg.calibration, 1);
    cfg.min_track_length = 1;
    window_of(&cfg, 40);
    observe(&cfg, 1100000, 0, 40);
    TEST_ASSERT_EQUAL_INT(VL_OK, vl_update(&est, &frame));
    vl_work_t w;
    vl_get_work(&est, &w);
    TEST_ASSERT_EQUAL_UINT64(w.flops, stage_sum(&w));
    TEST_ASSERT_TRUE(w.gate > 0);
    TEST_ASSERT_EQUAL_UINT32(cfg.ransac_hypotheses, w.hypotheses);
    TEST_ASSERT_TRUE(w.ransac > (uint64_t)cfg.ransac_hypotheses * 54u * w.state_dim);
    TEST_ASSERT_TRUE(w.update > 0);
    /* The default bound caps the update at 64 observations; all 40 agree, nothing to rescue. */
    TEST_ASSERT_EQUAL_UINT32(3u * 40u, w.rows);
    TEST_ASSERT_EQUAL_UINT64(0, w.rescue);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_zero_after_init_and_for_calls_that_do_nothing);
    RUN_TEST(test_prediction_is_constant_per_sample_and_paid_once_per_frame);
    RUN_TEST(test_update_grows_with_rows_and_state_as_the_formula_says);
    RUN_TEST(test_outlier_stages_count_their_work);
    return UNITY_END();
}
