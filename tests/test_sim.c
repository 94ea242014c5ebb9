/* Tests of the synthetic scenario generator (tools/sim/vl_sim.c). */
#include <math.h>
#include <string.h>

#include "unity.h"
#include "vl_sim.h"

/* Static: a simulator is about 0.8 MB. */
static vl_sim_t g_a;
static vl_sim_t g_b;
static vl_stereo_frame_t g_fa;
static vl_stereo_frame_t g_fb;

#define MAX_IDS 20000
static unsigned char g_id_state[MAX_IDS]; /* 0 unseen, 1 seen in the previous frame, 2 ended */

void setUp(void) {}
void tearDown(void) {}

/** Projects world point x from the true pose into [u_left, v, u_right]. */
static void reproject(const vl_calibration_t *cal, const double R[9], const double p[3], const double x[3],
                      double px[3])
{
    const double *T = cal->cam_T_imu;
    const double d[3] = {x[0] - p[0], x[1] - p[1], x[2] - p[2]};
    double b[3], c[3];
    int i;
    for (i = 0; i < 3; ++i) {
        b[i] = R[i] * d[0] + R[3 + i] * d[1] + R[6 + i] * d[2];
    }
    for (i = 0; i < 3; ++i) {
        c[i] = T[4 * i] * b[0] + T[4 * i + 1] * b[1] + T[4 * i + 2] * b[2] + T[4 * i + 3];
    }
    px[0] = cal->fx * c[0] / c[2] + cal->cx;
    px[1] = cal->fy * c[1] / c[2] + cal->cy;
    px[2] = cal->fx * (c[0] - cal->baseline) / c[2] + cal->cx;
}

static void test_vl_sim_init_rejects_bad_config(void)
{
    vl_sim_config_t cfg;
    vl_sim_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(NULL, &cfg));
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, NULL));
    cfg.pixel_noise = -1.0;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    cfg.max_observations = VL_MAX_FRAME_FEATURES + 1;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    cfg.dt_min = NAN;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
}

static void test_vl_sim_step_same_seed_gives_identical_output(void)
{
    vl_sim_config_t cfg;
    vl_imu_sample_t ia, ib;
    double Ra[9], pa[3], Rb[9], pb[3];
    int steps = 0;
    vl_sim_config_default(&cfg);
    cfg.seed = 12345;
    cfg.noise_seed = 7;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_b, &cfg));
    while (vl_sim_step(&g_a, &ia, &g_fa, Ra, pa) == 0) {
        TEST_ASSERT_EQUAL_INT(0, vl_sim_step(&g_b, &ib, &g_fb, Rb, pb));
        TEST_ASSERT_EQUAL_MEMORY(&ia, &ib, sizeof(ia));
        TEST_ASSERT_EQUAL_MEMORY(Ra, Rb, sizeof(Ra));
        TEST_ASSERT_EQUAL_MEMORY(pa, pb, sizeof(pa));
        TEST_ASSERT_EQUAL_UINT32(g_fa.count, g_fb.count);
        TEST_ASSERT_EQUAL_INT64(g_fa.utime, g_fb.utime);
        TEST_ASSERT_EQUAL_MEMORY(g_fa.obs, g_fb.obs, g_fa.count * sizeof(g_fa.obs[0]));
        ++steps;
    }
    TEST_ASSERT_EQUAL_INT(300, steps);
    TEST_ASSERT_EQUAL_INT(1, vl_sim_step(&g_b, &ib, &g_fb, Rb, pb));
}

static void test_vl_sim_step_noise_seed_changes_noise_only(void)
{
    vl_sim_config_t cfg;
    vl_imu_sample_t ia, ib;
    double Ra[9], pa[3], Rb[9], pb[3];
    int k, differing = 0;
    uint32_t i;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 120;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    cfg.noise_seed = 99;
    cfg.pixel_noise = 3.0;
    cfg.linear_noise = 0.0;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_b, &cfg));
    for (k = 0; k < 120; ++k) {
        TEST_ASSERT_EQUAL_INT(0, vl_sim_step(&g_a, &ia, &g_fa, Ra, pa));
        TEST_ASSERT_EQUAL_INT(0, vl_sim_step(&g_b, &ib, &g_fb, Rb, pb));
        TEST_ASSERT_EQUAL_MEMORY(Ra, Rb, sizeof(Ra));
        TEST_ASSERT_EQUAL_MEMORY(pa, pb, sizeof(pa));
        TEST_ASSERT_EQUAL_INT64(ia.utime, ib.utime);
        TEST_ASSERT_EQUAL_UINT32(g_fa.count, g_fb.count);
        for (i = 0; i < g_fa.count; ++i) {
            TEST_ASSERT_EQUAL_INT32(g_fa.obs[i].id, g_fb.obs[i].id);
            differing += g_fa.obs[i].u_left != g_fb.obs[i].u_left;
        }
    }
    TEST_ASSERT_TRUE(differing > 1000);
}

static void test_vl_sim_step_observations_inside_image_and_reproject(void)
{
    vl_sim_config_t cfg;
    vl_calibration_t cal;
    double R[9], p[3], x[3], px[3];
    double sum2[4] = {0, 0, 0, 0};
    long n = 0;
    uint32_t i;
    int j;
    vl_sim_config_default(&cfg);
    cfg.pixel_noise = 1.5;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    vl_sim_calibration(&g_a, &cal);
    TEST_ASSERT_EQUAL_DOUBLE(707.0912, cal.fx);
    TEST_ASSERT_EQUAL_DOUBLE(0.5371506, cal.baseline);
    while (vl_sim_step(&g_a, NULL, &g_fa, R, p) == 0) {
        for (i = 0; i < g_fa.count; ++i) {
            const vl_stereo_obs_t *o = &g_fa.obs[i];
            const double meas[4] = {o->u_left, o->v_left, o->u_right, o->v_right};
            double r[4];
            TEST_ASSERT_TRUE(o->u_left >= 0.0 && o->u_left <= cfg.image_width - 1.0);
            TEST_ASSERT_TRUE(o->u_right >= 0.0 && o->u_right <= cfg.image_width - 1.0);
            TEST_ASSERT_TRUE(o->v_left >= 0.0 && o->v_left <= cfg.image_height - 1.0);
            TEST_ASSERT_TRUE(o->v_right >= 0.0 && o->v_right <= cfg.image_height - 1.0);
            TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, o->id, x));
            reproject(&cal, R, p, x, px);
            r[0] = meas[0] - px[0];
            r[1] = meas[1] - px[1];
            r[2] = meas[2] - px[2];
            r[3] = meas[3] - px[1];
            for (j = 0; j < 4; ++j) {
                TEST_ASSERT_TRUE(fabs(r[j]) < 6.0 * cfg.pixel_noise);
                sum2[j] += r[j] * r[j];
            }
            ++n;
        }
    }
    TEST_ASSERT_TRUE(n > 10000);
    for (j = 0; j < 4; ++j) {
        TEST_ASSERT_DOUBLE_WITHIN(0.05 * cfg.pixel_noise, cfg.pixel_noise, sqrt(sum2[j] / (double)n));
    }
}

static void test_vl_sim_step_ids_never_reappear_after_track_ends(void)
{
    vl_sim_config_t cfg;
    uint32_t i;
    int32_t id;
    long tracks_done = 0;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 600;
    cfg.seed = 3;
    memset(g_id_state, 0, sizeof(g_id_state));
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    while (vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0) {
        for (i = 0; i < g_fa.count; ++i) {
            id = g_fa.obs[i].id;
            TEST_ASSERT_TRUE(id >= 0 && id < MAX_IDS);
            if (i > 0) {
                TEST_ASSERT_TRUE(g_fa.obs[i - 1].id < id); /* ascending, so unique */
            }
            TEST_ASSERT_NOT_EQUAL(2, g_id_state[id]);
            g_id_state[id] = 3; /* seen now */
        }
        /* Tracks seen before but not now have ended. */
        for (id = 0; id < vl_sim_tracks_issued(&g_a); ++id) {
            if (g_id_state[id] == 1) {
                g_id_state[id] = 2;
            } else if (g_id_state[id] == 3) {
                g_id_state[id] = 1;
            }
        }
    }
    for (id = 0; id < vl_sim_tracks_issued(&g_a); ++id) {
        TEST_ASSERT_NOT_EQUAL(0, g_id_state[id]); /* every issued id was observed */
        tracks_done += g_id_state[id] == 2;
    }
    TEST_ASSERT_TRUE(tracks_done > 1000);
}

static void test_vl_sim_step_frames_never_exceed_cap(void)
{
    vl_sim_config_t cfg;
    int full = 0;
    vl_sim_config_default(&cfg);
    cfg.points_per_meter = 20.0;
    cfg.num_steps = 200;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    while (vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0) {
        TEST_ASSERT_TRUE(g_fa.count <= VL_MAX_FRAME_FEATURES);
        full += g_fa.count == VL_MAX_FRAME_FEATURES;
    }
    TEST_ASSERT_TRUE(full > 0);

    cfg.max_observations = 10;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    while (vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0) {
        TEST_ASSERT_TRUE(g_fa.count <= 10);
    }
}

static void test_vl_sim_step_truth_integrates_true_velocities(void)
{
    vl_sim_config_t cfg;
    vl_imu_sample_t imu, prev_true;
    double R[9], p[3], Ri[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, pi[3] = {0, 0, 0};
    double u[6];
    int k, j;
    vl_sim_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    for (k = 0; vl_sim_step(&g_a, &imu, NULL, R, p) == 0; ++k) {
        const vl_imu_sample_t *t = vl_sim_true_imu(&g_a);
        if (k > 0) {
            const double tau = (double)(t->utime - prev_true.utime) * 1e-6;
            TEST_ASSERT_TRUE(tau >= 0.099 - 1e-9 && tau <= 0.109 + 1e-9);
            memcpy(u, prev_true.linear_velocity, sizeof(prev_true.linear_velocity));
            memcpy(u + 3, prev_true.angular_velocity, sizeof(prev_true.angular_velocity));
            vl_sim_integrate(Ri, pi, u, tau);
        } else {
            TEST_ASSERT_EQUAL_INT64(cfg.start_utime, t->utime);
        }
        for (j = 0; j < 9; ++j) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-12, Ri[j], R[j]);
        }
        for (j = 0; j < 3; ++j) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, pi[j], p[j]);
        }
        TEST_ASSERT_EQUAL_INT64(t->utime, imu.utime);
        prev_true = *t;
    }
    TEST_ASSERT_TRUE(vl_sim_distance(&g_a) > 200.0); /* about 8 m/s for 30 s */
}

static void test_vl_sim_step_zero_noise_gives_exact_measurements(void)
{
    vl_sim_config_t cfg;
    vl_calibration_t cal;
    vl_imu_sample_t imu;
    double R[9], p[3], x[3], px[3];
    uint32_t i;
    int j;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 50;
    cfg.pixel_noise = 0.0;
    cfg.linear_noise = 0.0;
    cfg.angular_noise = 0.0;
    cfg.linear_offset[0] = 0.25;
    cfg.angular_offset[2] = -0.01;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    vl_sim_calibration(&g_a, &cal);
    while (vl_sim_step(&g_a, &imu, &g_fa, R, p) == 0) {
        const vl_imu_sample_t *t = vl_sim_true_imu(&g_a);
        for (j = 0; j < 3; ++j) {
            TEST_ASSERT_EQUAL_DOUBLE(t->linear_velocity[j] + cfg.linear_offset[j], imu.linear_velocity[j]);
            TEST_ASSERT_EQUAL_DOUBLE(t->angular_velocity[j] + cfg.angular_offset[j], imu.angular_velocity[j]);
        }
        TEST_ASSERT_TRUE(g_fa.count > 0);
        for (i = 0; i < g_fa.count; ++i) {
            TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, g_fa.obs[i].id, x));
            reproject(&cal, R, p, x, px);
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, px[0], g_fa.obs[i].u_left);
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, px[1], g_fa.obs[i].v_left);
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, px[2], g_fa.obs[i].u_right);
            TEST_ASSERT_DOUBLE_WITHIN(1e-9, px[1], g_fa.obs[i].v_right);
            TEST_ASSERT_TRUE(g_fa.obs[i].u_left > g_fa.obs[i].u_right);
        }
    }
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_landmark(&g_a, -1, x));
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_landmark(&g_a, vl_sim_tracks_issued(&g_a), x));
}

static void test_vl_sim_step_observation_statistics_like_real_data(void)
{
    vl_sim_config_t cfg;
    long obs = 0;
    int steps = 0;
    vl_sim_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    while (vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0) {
        obs += g_fa.count;
        ++steps;
    }
    /* Mean observations per frame and mean track length in the real data's range. */
    TEST_ASSERT_TRUE((double)obs / steps > 50.0 && (double)obs / steps < 130.0);
    TEST_ASSERT_TRUE((double)obs / vl_sim_tracks_issued(&g_a) > 12.0);
    TEST_ASSERT_TRUE((double)obs / vl_sim_tracks_issued(&g_a) < 25.0);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_vl_sim_init_rejects_bad_config);
    RUN_TEST(test_vl_sim_step_same_seed_gives_identical_output);
    RUN_TEST(test_vl_sim_step_noise_seed_changes_noise_only);
    RUN_TEST(test_vl_sim_step_observations_inside_image_and_reproject);
    RUN_TEST(test_vl_sim_step_ids_never_reappear_after_track_ends);
    RUN_TEST(test_vl_sim_step_frames_never_exceed_cap);
    RUN_TEST(test_vl_sim_step_truth_integrates_true_velocities);
    RUN_TEST(test_vl_sim_step_zero_noise_gives_exact_measurements);
    RUN_TEST(test_vl_sim_step_observation_statistics_like_real_data);
    return UNITY_END();
}
