/* Tests of the synthetic scenario generator (tools/sim/vl_sim.c). */
#include <math.h>
#include <string.h>

#include "unity.h"
#include "vl_sim.h"

/* Static: a simulator is about 1.4 MB. */
static vl_sim_t g_a;
static vl_sim_t g_b;
static vl_stereo_frame_t g_fa;
static vl_stereo_frame_t g_fb;

#define MAX_IDS 20000
static unsigned char g_id_state[MAX_IDS]; /* 0 unseen, 1 seen in the previous frame, 2 ended */

void setUp(void)
{
}
void tearDown(void)
{
}

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
    cfg.interval_velocities = 1; /* then the truth is exactly the held samples' motion */
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

/* Truth over one step from pose (R0, p0) with the velocity u held (w = 0) or the
 * trapezoid of u and u_next (w = 0.5); returns the distance to (R1, p1), m. */
static double step_error(const double R0[9], const double p0[3], const double u[6], const double u_next[6], double w,
                         double tau, const double p1[3])
{
    double R[9], p[3], m[6];
    int j;
    memcpy(R, R0, sizeof(R));
    memcpy(p, p0, sizeof(p));
    for (j = 0; j < 6; ++j) {
        m[j] = u[j] + w * (u_next[j] - u[j]);
    }
    vl_sim_integrate(R, p, m, tau);
    return sqrt((p[0] - p1[0]) * (p[0] - p1[0]) + (p[1] - p1[1]) * (p[1] - p1[1]) + (p[2] - p1[2]) * (p[2] - p1[2]));
}

static void test_vl_sim_step_samples_are_instantaneous_velocities(void)
{
    vl_sim_config_t cfg;
    vl_imu_sample_t imu, prev;
    double R[9], p[3], R0[9], p0[3], u0[6], u[6];
    double held = 0.0, trapezoid = 0.0, worst = 0.0;
    int k;
    vl_sim_config_default(&cfg);
    TEST_ASSERT_EQUAL_INT(0, cfg.interval_velocities);
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    for (k = 0; vl_sim_step(&g_a, &imu, NULL, R, p) == 0; ++k) {
        const vl_imu_sample_t *t = vl_sim_true_imu(&g_a);
        memcpy(u, t->linear_velocity, sizeof(t->linear_velocity));
        memcpy(u + 3, t->angular_velocity, sizeof(t->angular_velocity));
        if (k > 0) {
            const double tau = (double)(t->utime - prev.utime) * 1e-6;
            const double e = step_error(R0, p0, u0, u, 0.5, tau, p);
            held += step_error(R0, p0, u0, u, 0.0, tau, p);
            trapezoid += e;
            worst = e > worst ? e : worst;
        }
        prev = *t;
        memcpy(R0, R, sizeof(R));
        memcpy(p0, p, sizeof(p));
        memcpy(u0, u, sizeof(u));
    }
    /* The motion varies smoothly between samples: the trapezoid of the two samples
     * follows it to second order, the held sample only to first order. */
    TEST_ASSERT_TRUE(worst < 2e-3);
    TEST_ASSERT_TRUE(trapezoid < 0.1 * held);
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

/* A velocity sensor at p (--velocity-sensor) samples the velocity there: v + w x p, the angular
 * velocity unchanged, and the frames and the truth the same as with the sensor at the IMU. */
static void test_vl_sim_velocity_sensor_adds_the_turn_times_its_lever_arm(void)
{
    static const double lever[3] = {-1.9, 1.5, -1.0};
    vl_sim_config_t cfg;
    vl_imu_sample_t imu;
    double R[9], p[3], Rb[9], pb[3];
    int j, turning = 0;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 60;
    cfg.linear_noise = 0.0;
    cfg.angular_noise = 0.0;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_b, &cfg));
    memcpy(cfg.velocity_sensor, lever, sizeof(lever));
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    while (vl_sim_step(&g_a, &imu, &g_fa, R, p) == 0) {
        vl_imu_sample_t at_imu;
        TEST_ASSERT_EQUAL_INT(0, vl_sim_step(&g_b, &at_imu, &g_fb, Rb, pb));
        const double *w = vl_sim_true_imu(&g_a)->angular_velocity;
        const double turn[3] = {w[1] * lever[2] - w[2] * lever[1], w[2] * lever[0] - w[0] * lever[2],
                                w[0] * lever[1] - w[1] * lever[0]};
        for (j = 0; j < 3; ++j) {
            TEST_ASSERT_DOUBLE_WITHIN(1e-12, at_imu.linear_velocity[j] + turn[j], imu.linear_velocity[j]);
            TEST_ASSERT_EQUAL_DOUBLE(at_imu.angular_velocity[j], imu.angular_velocity[j]);
        }
        turning += fabs(turn[0]) + fabs(turn[1]) + fabs(turn[2]) > 1e-3;
        TEST_ASSERT_EQUAL_MEMORY(Rb, R, sizeof(R));
        TEST_ASSERT_EQUAL_MEMORY(pb, p, sizeof(p));
        TEST_ASSERT_EQUAL_UINT32(g_fb.count, g_fa.count);
        TEST_ASSERT_EQUAL_MEMORY(g_fb.obs, g_fa.obs, g_fa.count * sizeof(g_fa.obs[0]));
    }
    TEST_ASSERT_TRUE(turning > 10); /* the drive turns, so the lever arm is seen */
    cfg.velocity_sensor[1] = NAN;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
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

/* ---------- realistic conditions ---------- */

static uint64_t fnv_mix(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = (const unsigned char *)data;
    size_t i;
    for (i = 0; i < n; ++i) {
        h = (h ^ p[i]) * 0x100000001B3ull;
    }
    return h;
}

/** Hash of every output of a run (IMU, frames, truth), in step order. */
static uint64_t run_hash(const vl_sim_config_t *cfg)
{
    vl_imu_sample_t imu;
    double R[9], p[3];
    uint64_t h = 0xcbf29ce484222325ull;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, cfg));
    while (vl_sim_step(&g_a, &imu, &g_fa, R, p) == 0) {
        h = fnv_mix(h, &imu, sizeof(imu));
        h = fnv_mix(h, &g_fa.utime, sizeof(g_fa.utime));
        h = fnv_mix(h, &g_fa.count, sizeof(g_fa.count));
        h = fnv_mix(h, g_fa.obs, g_fa.count * sizeof(g_fa.obs[0]));
        h = fnv_mix(h, R, sizeof(R));
        h = fnv_mix(h, p, sizeof(p));
    }
    return h;
}

static void test_vl_sim_conditions_off_leave_outputs_bit_identical(void)
{
    vl_sim_config_t cfg;
    vl_sim_counts_t counts;
    vl_sim_config_default(&cfg);
    cfg.seed = 5;
    cfg.noise_seed = 3;
    cfg.num_steps = 400;
    cfg.interval_velocities = 1;
    /* The simulator before the realistic conditions existed (its motion held each sample until
       the next) gave this hash for this run (the build is ISO C99, so no floating-point
       contraction changes the bits; data/sample.lcmlog relies on the same). Off must stay
       exactly that. */
    TEST_ASSERT_EQUAL_HEX64(0x15C6790AAE7F80CBull, run_hash(&cfg));
    TEST_ASSERT_EQUAL_INT32(1794, vl_sim_tracks_issued(&g_a));
    vl_sim_counts(&g_a, &counts);
    TEST_ASSERT_EQUAL_UINT64(0, counts.stale_frames + counts.reassociations + counts.mismatches);
    /* Ranges and speeds without their fractions turn nothing on. */
    cfg.far_disparity_min = 1.0;
    cfg.far_disparity_max = 3.0;
    cfg.moving_speed = 4.0;
    cfg.reassoc_radius = 50.0;
    cfg.reassoc_fraction = 0.5;
    TEST_ASSERT_EQUAL_HEX64(0x15C6790AAE7F80CBull, run_hash(&cfg));
}

static void test_vl_sim_init_rejects_bad_conditions(void)
{
    vl_sim_config_t cfg;
    vl_sim_config_default(&cfg);
    cfg.stale_probability = 1.5;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    cfg.far_fraction = 0.1; /* with no disparity range */
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    cfg.calib_rotation_error[1] = NAN;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    cfg.reassoc_radius = -1.0;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
    vl_sim_config_default(&cfg);
    vl_sim_config_realistic(&cfg);
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
}

/** Index of id in a frame, or -1. */
static int find_id(const vl_stereo_frame_t *f, int32_t id)
{
    uint32_t i;
    for (i = 0; i < f->count; ++i) {
        if (f->obs[i].id == id) {
            return (int)i;
        }
    }
    return -1;
}

/** 1 when every observation of prev is in cur with exactly the same id and pixels. */
static int repeats(const vl_stereo_frame_t *cur, const vl_stereo_frame_t *prev)
{
    uint32_t i;
    for (i = 0; i < prev->count; ++i) {
        const int j = find_id(cur, prev->obs[i].id);
        if (j < 0 || memcmp(&cur->obs[j], &prev->obs[i], sizeof(prev->obs[i])) != 0) {
            return 0;
        }
    }
    return prev->count > 0;
}

/** What a drive with stale frames hands to a check of its carried tracks. */
typedef struct {
    vl_calibration_t cal;
    double R[9], p[3];           /* the true pose of the frame after the stale one */
    double Rstale[9], pstale[3]; /* the true pose of the stale frame */
    double du[4096], dv[4096], dd[4096];
    int n;
} carried_t;

/*
 * Runs cfg's drive (stale frames on) and, on each frame after a stale one, calls check for
 * every track carried over that stale frame and over no earlier one, with its point. Returns
 * how many stale frames it saw, after checking the simulator counted the same.
 */
static int visit_carried_after_stale(const vl_sim_config_t *cfg, carried_t *c,
                                     void (*check)(carried_t *c, const vl_stereo_obs_t *o, const double x[3]))
{
    static vl_stereo_frame_t prev, at_stale;
    vl_sim_counts_t counts;
    double pprev[3] = {0, 0, 0}, x[3];
    int k, stale_seen = 0, after_stale = 0;
    int32_t unshifted_from = 0, unshifted_next = 0, carried_below = 0;
    uint32_t i;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, cfg));
    vl_sim_calibration(&g_a, &c->cal);
    for (k = 0;; ++k) {
        const int32_t issued_before = vl_sim_tracks_issued(&g_a);
        int stale;
        if (vl_sim_step(&g_a, NULL, &g_fa, c->R, c->p) != 0) {
            break;
        }
        stale = k > 0 && repeats(&g_fa, &prev);
        if (after_stale && !stale) {
            for (i = 0; i < g_fa.count; ++i) {
                const int32_t id = g_fa.obs[i].id;
                if (id < unshifted_from || id >= carried_below || find_id(&at_stale, id) < 0) {
                    continue;
                }
                TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, id, x));
                check(c, &g_fa.obs[i], x);
            }
        }
        after_stale = 0;
        if (stale) {
            ++stale_seen;
            /* The truth moves on while the pixels stand still. */
            TEST_ASSERT_TRUE(fabs(c->p[0] - pprev[0]) + fabs(c->p[1] - pprev[1]) > 0.5);
            at_stale = g_fa;
            memcpy(c->Rstale, c->R, sizeof(c->R));
            memcpy(c->pstale, c->p, sizeof(c->p));
            after_stale = 1;
            /* Ids from the previous stale frame's new ones up to this frame's new ones are unshifted. */
            unshifted_from = unshifted_next;
            carried_below = issued_before;
            unshifted_next = issued_before;
        }
        prev = g_fa;
        memcpy(pprev, c->p, sizeof(c->p));
    }
    vl_sim_counts(&g_a, &counts);
    TEST_ASSERT_EQUAL_UINT64(counts.stale_frames, (uint64_t)stale_seen);
    return stale_seen;
}

/* 400 noiseless steps, one frame in ten stale. */
static void stale_drive(vl_sim_config_t *cfg)
{
    vl_sim_config_default(cfg);
    cfg->num_steps = 400;
    cfg->pixel_noise = 0.0;
    cfg->stale_probability = 0.1;
}

/* A carried track shows its point as seen from the stale frame's pose: one step of motion lost. */
static void check_one_step_lost(carried_t *c, const vl_stereo_obs_t *o, const double x[3])
{
    double px[3];
    reproject(&c->cal, c->Rstale, c->pstale, x, px);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[0], o->u_left);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[1], o->v_left);
    TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[2], o->u_right);
    reproject(&c->cal, c->R, c->p, x, px); /* and not from the frame's own pose */
    TEST_ASSERT_TRUE(fabs(px[0] - o->u_left) + fabs(px[1] - o->v_left) > 1e-3);
    ++c->n;
}

/* Keeps a carried track's offset from its one-step-lost pixels in u, v and disparity. */
static void collect_jump(carried_t *c, const vl_stereo_obs_t *o, const double x[3])
{
    double px[3];
    if (c->n >= 4096) {
        return;
    }
    reproject(&c->cal, c->Rstale, c->pstale, x, px);
    c->du[c->n] = o->u_left - px[0];
    c->dv[c->n] = o->v_left - px[1];
    c->dd[c->n] = (o->u_left - o->u_right) - (px[0] - px[2]);
    ++c->n;
}

static void test_vl_sim_stale_frames_repeat_exactly_then_lose_one_step(void)
{
    static carried_t c;
    vl_sim_config_t cfg;
    int stale_seen;
    stale_drive(&cfg);
    c.n = 0;
    stale_seen = visit_carried_after_stale(&cfg, &c, check_one_step_lost);
    TEST_ASSERT_TRUE(stale_seen > 20 && stale_seen < 65); /* 10 % of 399 */
    TEST_ASSERT_TRUE(c.n > 300);
}

/* Sample std of the n values v about zero (the jump has zero mean). */
static double rms(const double *v, int n)
{
    double acc = 0.0;
    int i;
    for (i = 0; i < n; ++i) {
        acc += v[i] * v[i];
    }
    return n > 0 ? sqrt(acc / n) : 0.0;
}

static void test_vl_sim_stale_jump_displaces_each_carried_track(void)
{
    /* With stale_jump, the first frame after a stale one shows each carried track off its
       lost-step pixels by one draw of the jump: std 1 px in u and v, 0.25 px in disparity. */
    static carried_t c;
    vl_sim_config_t cfg;
    stale_drive(&cfg);
    cfg.stale_jump = 1.0;
    cfg.stale_jump_disparity = 0.25;
    c.n = 0;
    (void)visit_carried_after_stale(&cfg, &c, collect_jump);
    TEST_ASSERT_TRUE(c.n > 300);
    TEST_ASSERT_DOUBLE_WITHIN(0.15, 1.0, rms(c.du, c.n));
    TEST_ASSERT_DOUBLE_WITHIN(0.15, 1.0, rms(c.dv, c.n));
    TEST_ASSERT_DOUBLE_WITHIN(0.05, 0.25, rms(c.dd, c.n));
    /* The realistic preset sets it (README, vislam-sim), and 0 turns it off bit for bit
       (test_vl_sim_stale_frames_repeat_exactly_then_lose_one_step). */
    vl_sim_config_realistic(&cfg);
    TEST_ASSERT_TRUE(cfg.stale_jump > 0.0 && cfg.stale_jump_disparity > 0.0);
    cfg.stale_jump = -1.0;
    TEST_ASSERT_EQUAL_INT(-1, vl_sim_init(&g_a, &cfg));
}

static void test_vl_sim_detection_frames_are_the_stale_ones(void)
{
    static vl_stereo_frame_t prev;
    vl_sim_config_t cfg;
    int k, stale_frames = 0, prev_stale = 0;
    uint32_t i;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 500;
    cfg.max_observations = 60;
    cfg.detect_below_fraction = 0.5; /* 30 */
    cfg.detect_new_fraction = 0.4;   /* 24 */
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    for (k = 0; vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0; ++k) {
        uint32_t fresh = 0;
        const int stale = k > 0 && repeats(&g_fa, &prev);
        for (i = 0; i < g_fa.count; ++i) {
            fresh += k > 0 && find_id(&prev, g_fa.obs[i].id) < 0;
        }
        if (k > 0) {
            /* New tracks only on stale frames; stale exactly when the last frame fell under 30
               observations and was not stale itself. */
            TEST_ASSERT_TRUE(fresh == 0 || stale);
            TEST_ASSERT_EQUAL_INT(prev.count < 30 && !prev_stale, stale);
            TEST_ASSERT_TRUE(fresh <= 24);
        }
        stale_frames += stale;
        prev_stale = stale;
        prev = g_fa;
    }
    TEST_ASSERT_TRUE(stale_frames > 10);
}

static void test_vl_sim_reassociated_ids_jump_to_another_point(void)
{
    vl_sim_config_t cfg;
    vl_sim_counts_t counts;
    vl_calibration_t cal;
    double R[9], p[3], x[3], px[3];
    uint32_t i;
    long jumped_obs = 0, first_jumps = 0;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 300;
    cfg.pixel_noise = 0.0;
    cfg.reassoc_probability = 0.5;
    cfg.reassoc_fraction = 0.05;
    cfg.reassoc_radius = 40.0;
    memset(g_id_state, 0, sizeof(g_id_state));
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    vl_sim_calibration(&g_a, &cal);
    while (vl_sim_step(&g_a, NULL, &g_fa, R, p) == 0) {
        for (i = 0; i < g_fa.count; ++i) {
            const vl_stereo_obs_t *o = &g_fa.obs[i];
            double err;
            TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, o->id, x));
            reproject(&cal, R, p, x, px);
            err = hypot(o->u_left - px[0], o->v_left - px[1]);
            if (err > 1e-6) {
                ++jumped_obs;
                if (g_id_state[o->id] == 0) {
                    /* At the hand-over the new point lies within the radius of the old one. */
                    TEST_ASSERT_TRUE(err <= cfg.reassoc_radius + 1e-9);
                    g_id_state[o->id] = 1;
                    ++first_jumps;
                }
            } else {
                /* Once handed over, an id never shows its first point again. */
                TEST_ASSERT_EQUAL_UINT8(0, g_id_state[o->id]);
            }
        }
    }
    vl_sim_counts(&g_a, &counts);
    TEST_ASSERT_EQUAL_UINT64(0, counts.stale_frames + counts.mismatches);
    TEST_ASSERT_TRUE(counts.reassociations > 50);
    /* Every hand-over shows (an id handed over twice counts once), and the id continues there. */
    TEST_ASSERT_TRUE(first_jumps <= (long)counts.reassociations && first_jumps > (long)counts.reassociations * 8 / 10);
    TEST_ASSERT_TRUE(jumped_obs > 3 * first_jumps);
}

/** World point of an observation through the true pose and a calibration (stereo triangulation). */
static void triangulate_world(const vl_calibration_t *cal, const double R[9], const double p[3],
                              const vl_stereo_obs_t *o, double w[3])
{
    const double *T = cal->cam_T_imu;
    const double z = cal->fx * cal->baseline / (o->u_left - o->u_right);
    const double c[3] = {(o->u_left - cal->cx) * z / cal->fx, (o->v_left - cal->cy) * z / cal->fy, z};
    double d[3], b[3];
    int i;
    for (i = 0; i < 3; ++i) {
        d[i] = c[i] - T[4 * i + 3];
    }
    for (i = 0; i < 3; ++i) { /* b = R_ci^T (c - t) */
        b[i] = T[i] * d[0] + T[4 + i] * d[1] + T[8 + i] * d[2];
    }
    for (i = 0; i < 3; ++i) {
        w[i] = R[3 * i] * b[0] + R[3 * i + 1] * b[1] + R[3 * i + 2] * b[2] + p[i];
    }
}

static void test_vl_sim_moving_points_move_at_their_speed(void)
{
    vl_sim_config_t cfg;
    vl_calibration_t cal;
    double R[9], p[3], w[3];
    static double first[MAX_IDS][4]; /* x, y, z, time of the first observation */
    int moving_pass;
    uint32_t i;
    for (moving_pass = 0; moving_pass < 2; ++moving_pass) {
        long tracks = 0, at_speed = 0;
        double max_static = 0.0;
        vl_sim_config_default(&cfg);
        cfg.num_steps = 200;
        cfg.pixel_noise = 0.0;
        cfg.moving_fraction = moving_pass ? 1.0 : 0.0;
        cfg.moving_speed = 5.0;
        memset(g_id_state, 0, sizeof(g_id_state));
        TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
        vl_sim_calibration(&g_a, &cal);
        while (vl_sim_step(&g_a, NULL, &g_fa, R, p) == 0) {
            const double t = (double)g_fa.utime * 1e-6;
            for (i = 0; i < g_fa.count; ++i) {
                const int32_t id = g_fa.obs[i].id;
                triangulate_world(&cal, R, p, &g_fa.obs[i], w);
                if (g_id_state[id] == 0) {
                    memcpy(first[id], w, sizeof(w));
                    first[id][3] = t;
                    g_id_state[id] = 1;
                } else if (t - first[id][3] > 1.0) {
                    const double dx = w[0] - first[id][0], dy = w[1] - first[id][1], dz = w[2] - first[id][2];
                    const double dist = sqrt(dx * dx + dy * dy + dz * dz);
                    if (g_id_state[id] == 1) {
                        ++tracks;
                        at_speed += fabs(dist / (t - first[id][3]) - cfg.moving_speed) < 1e-3 && fabs(dz) < 1e-6;
                        g_id_state[id] = 2;
                    }
                    if (dist > max_static) {
                        max_static = dist;
                    }
                }
            }
        }
        TEST_ASSERT_TRUE(tracks > 100);
        if (moving_pass) {
            TEST_ASSERT_EQUAL_INT(tracks, at_speed); /* horizontal, constant speed */
        } else {
            TEST_ASSERT_TRUE(max_static < 1e-4); /* rounding of an 80 m triangulation */
        }
    }
}

static void test_vl_sim_mismatches_replace_single_observations(void)
{
    vl_sim_config_t cfg;
    vl_sim_counts_t counts;
    vl_calibration_t cal;
    double R[9], p[3], x[3], px[3];
    uint32_t i;
    long off = 0;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 200;
    cfg.pixel_noise = 0.0;
    cfg.mismatch_probability = 0.02;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    vl_sim_calibration(&g_a, &cal);
    while (vl_sim_step(&g_a, NULL, &g_fa, R, p) == 0) {
        for (i = 0; i < g_fa.count; ++i) {
            const vl_stereo_obs_t *o = &g_fa.obs[i];
            TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, o->id, x));
            reproject(&cal, R, p, x, px);
            off += fabs(o->u_left - px[0]) + fabs(o->v_left - px[1]) + fabs(o->u_right - px[2]) > 1e-6;
            TEST_ASSERT_TRUE(o->u_left >= 0.0 && o->u_left <= cfg.image_width - 1.0);
            TEST_ASSERT_TRUE(o->u_right >= 0.0 && o->u_left >= o->u_right);
        }
    }
    vl_sim_counts(&g_a, &counts);
    TEST_ASSERT_EQUAL_INT64((int64_t)counts.mismatches, off);
    TEST_ASSERT_TRUE(off > 100); /* 2 % of about 17,000 */
}

static void test_vl_sim_far_points_have_small_disparity(void)
{
    vl_sim_config_t cfg;
    int far_pass;
    uint32_t i;
    for (far_pass = 0; far_pass < 2; ++far_pass) {
        long small = 0, n = 0;
        vl_sim_config_default(&cfg);
        cfg.num_steps = 150;
        cfg.pixel_noise = 0.0;
        cfg.far_fraction = far_pass ? 0.2 : 0.0;
        cfg.far_disparity_min = 1.0;
        cfg.far_disparity_max = 3.0;
        TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
        while (vl_sim_step(&g_a, NULL, &g_fa, NULL, NULL) == 0) {
            for (i = 0; i < g_fa.count; ++i) {
                const double d = g_fa.obs[i].u_left - g_fa.obs[i].u_right;
                TEST_ASSERT_TRUE(d > 0.0);
                small += d < 3.5; /* beyond max_depth (80 m gives 4.75 px) */
                ++n;
            }
        }
        if (far_pass) {
            TEST_ASSERT_TRUE(small > n / 20);
        } else {
            TEST_ASSERT_EQUAL_INT(0, small);
        }
    }
}

static void test_vl_sim_calibration_error_moves_pixels_not_the_calibration(void)
{
    vl_sim_config_t cfg;
    vl_calibration_t cal, truth_cal;
    double R[9], p[3], x[3], px[3];
    const double a = 0.5 * 3.14159265358979323846 / 180.0; /* 0.5 deg about the optical axis */
    uint32_t i;
    int j;
    long n = 0;
    double sum_nominal = 0.0;
    vl_sim_config_default(&cfg);
    cfg.num_steps = 100;
    cfg.pixel_noise = 0.0;
    cfg.calib_rotation_error[2] = 0.5;
    cfg.calib_translation_error[0] = 0.02;
    cfg.baseline_error = 0.01;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    vl_sim_calibration(&g_a, &cal);
    TEST_ASSERT_EQUAL_MEMORY(&cfg.calibration, &cal, sizeof(cal));
    /* The rig the observations come from, built here independently: Rz(a) * cam_T_imu, plus the
       translation error, and the longer baseline. */
    truth_cal = cal;
    truth_cal.baseline = cal.baseline * 1.01;
    for (j = 0; j < 4; ++j) {
        const double r0 = cal.cam_T_imu[j], r1 = cal.cam_T_imu[4 + j];
        truth_cal.cam_T_imu[j] = cos(a) * r0 - sin(a) * r1;
        truth_cal.cam_T_imu[4 + j] = sin(a) * r0 + cos(a) * r1;
    }
    truth_cal.cam_T_imu[3] += 0.02;
    while (vl_sim_step(&g_a, NULL, &g_fa, R, p) == 0) {
        for (i = 0; i < g_fa.count; ++i) {
            TEST_ASSERT_EQUAL_INT(0, vl_sim_landmark(&g_a, g_fa.obs[i].id, x));
            reproject(&truth_cal, R, p, x, px);
            TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[0], g_fa.obs[i].u_left);
            TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[1], g_fa.obs[i].v_left);
            TEST_ASSERT_DOUBLE_WITHIN(1e-6, px[2], g_fa.obs[i].u_right);
            reproject(&cal, R, p, x, px);
            sum_nominal += hypot(g_fa.obs[i].u_left - px[0], g_fa.obs[i].v_left - px[1]);
            ++n;
        }
    }
    TEST_ASSERT_TRUE(n > 1000);
    TEST_ASSERT_TRUE(sum_nominal / (double)n > 0.5); /* the nominal rig misses by pixels */
}

static void test_vl_sim_realistic_is_deterministic_and_noise_seed_changes_noise_only(void)
{
    vl_sim_config_t cfg;
    vl_sim_counts_t ca, cb;
    double Ra[9], pa[3], Rb[9], pb[3];
    uint32_t i;
    long differing = 0, obs = 0;
    int steps = 0;
    vl_sim_config_default(&cfg);
    vl_sim_config_realistic(&cfg);
    cfg.num_steps = 600;
    TEST_ASSERT_EQUAL_HEX64(run_hash(&cfg), run_hash(&cfg));
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_a, &cfg));
    cfg.noise_seed = 42;
    TEST_ASSERT_EQUAL_INT(0, vl_sim_init(&g_b, &cfg));
    while (vl_sim_step(&g_a, NULL, &g_fa, Ra, pa) == 0) {
        TEST_ASSERT_EQUAL_INT(0, vl_sim_step(&g_b, NULL, &g_fb, Rb, pb));
        TEST_ASSERT_EQUAL_MEMORY(pa, pb, sizeof(pa));
        TEST_ASSERT_EQUAL_UINT32(g_fa.count, g_fb.count);
        for (i = 0; i < g_fa.count; ++i) {
            TEST_ASSERT_EQUAL_INT32(g_fa.obs[i].id, g_fb.obs[i].id);
            differing += g_fa.obs[i].u_left != g_fb.obs[i].u_left;
        }
        obs += g_fa.count;
        ++steps;
    }
    vl_sim_counts(&g_a, &ca);
    vl_sim_counts(&g_b, &cb);
    TEST_ASSERT_EQUAL_UINT64(ca.stale_frames, cb.stale_frames);
    TEST_ASSERT_EQUAL_UINT64(ca.reassociations, cb.reassociations);
    TEST_ASSERT_TRUE(differing > obs / 2);
    /* The real drives' rates: 8 to 11 % stale frames, 67 to 73 observations per frame. */
    TEST_ASSERT_TRUE(ca.stale_frames > (uint64_t)steps * 6 / 100 && ca.stale_frames < (uint64_t)steps * 14 / 100);
    TEST_ASSERT_TRUE((double)obs / steps > 55.0 && (double)obs / steps < 80.0);
    TEST_ASSERT_TRUE(ca.reassociations > 0);
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
    RUN_TEST(test_vl_sim_step_samples_are_instantaneous_velocities);
    RUN_TEST(test_vl_sim_step_zero_noise_gives_exact_measurements);
    RUN_TEST(test_vl_sim_velocity_sensor_adds_the_turn_times_its_lever_arm);
    RUN_TEST(test_vl_sim_step_observation_statistics_like_real_data);
    RUN_TEST(test_vl_sim_conditions_off_leave_outputs_bit_identical);
    RUN_TEST(test_vl_sim_init_rejects_bad_conditions);
    RUN_TEST(test_vl_sim_stale_frames_repeat_exactly_then_lose_one_step);
    RUN_TEST(test_vl_sim_stale_jump_displaces_each_carried_track);
    RUN_TEST(test_vl_sim_detection_frames_are_the_stale_ones);
    RUN_TEST(test_vl_sim_reassociated_ids_jump_to_another_point);
    RUN_TEST(test_vl_sim_moving_points_move_at_their_speed);
    RUN_TEST(test_vl_sim_mismatches_replace_single_observations);
    RUN_TEST(test_vl_sim_far_points_have_small_disparity);
    RUN_TEST(test_vl_sim_calibration_error_moves_pixels_not_the_calibration);
    RUN_TEST(test_vl_sim_realistic_is_deterministic_and_noise_seed_changes_noise_only);
    return UNITY_END();
}
