/**
 * @file vl_sim.c
 * @brief Synthetic visual-inertial scenario (see vl_sim.h).
 *
 * A planner integrates the true motion ahead of the vehicle and keeps its
 * poses in a ring. Points are scattered around each planned pose in a disc
 * (not in bands beside the road: bands leave the view empty straight ahead
 * of every corner), once the path is planned far enough on both sides to
 * keep them off the road. The vehicle then replays the planned poses one step
 * at a time and observes the points.
 */
#include "vl_sim.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

#define VL_SIM_TWO_PI 6.283185307179586476925286766559

/* ---------- random numbers ---------- */

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

static void rng_seed(vl_sim_rng_t *r, uint64_t seed, uint64_t stream)
{
    /* Mixing the stream tag through splitmix keeps streams of nearby seeds unrelated. */
    uint64_t st = seed ^ (stream * 0xD1B54A32D192ED03ULL);
    int i;
    for (i = 0; i < 4; ++i) {
        r->s[i] = splitmix64(&st);
    }
    r->spare = 0.0;
    r->has_spare = 0;
}

static uint64_t rotl(uint64_t x, int k)
{
    return (x << k) | (x >> (64 - k));
}

static uint64_t rng_next(vl_sim_rng_t *r)
{
    uint64_t *s = r->s;
    const uint64_t result = rotl(s[1] * 5, 7) * 9;
    const uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

/** Uniform in [0, 1). */
static double rng_uniform(vl_sim_rng_t *r)
{
    return (double)(rng_next(r) >> 11) * 0x1.0p-53;
}

/** Standard normal (Box-Muller; the second deviate is kept for the next call). */
static double rng_normal(vl_sim_rng_t *r)
{
    double u1, u2, rad;
    if (r->has_spare) {
        r->has_spare = 0;
        return r->spare;
    }
    u1 = 1.0 - rng_uniform(r); /* (0, 1]: log stays finite */
    u2 = rng_uniform(r);
    rad = sqrt(-2.0 * log(u1));
    r->spare = rad * sin(VL_SIM_TWO_PI * u2);
    r->has_spare = 1;
    return rad * cos(VL_SIM_TWO_PI * u2);
}

/* ---------- small SE(3) helpers ---------- */

static void mat3_mul(const double A[9], const double B[9], double C[9])
{
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            C[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
        }
    }
}

void vl_sim_integrate(double R[9], double p[3], const double u[6], double tau)
{
    const double rho[3] = {tau * u[0], tau * u[1], tau * u[2]};
    const double phi[3] = {tau * u[3], tau * u[4], tau * u[5]};
    const double th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
    const double th = sqrt(th2);
    double A, B, C;
    double K[9], K2[9], dR[9], V[9], Rn[9], Vr[3];
    int i;

    if (th < 0.1) {
        /* Series: (th - sin th) / th^3 cancels badly in the closed form at small angles. */
        const double t4 = th2 * th2, t6 = t4 * th2, t8 = t4 * t4;
        A = 1.0 - th2 / 6.0 + t4 / 120.0 - t6 / 5040.0 + t8 / 362880.0;
        B = 0.5 - th2 / 24.0 + t4 / 720.0 - t6 / 40320.0 + t8 / 3628800.0;
        C = 1.0 / 6.0 - th2 / 120.0 + t4 / 5040.0 - t6 / 362880.0 + t8 / 39916800.0;
    } else {
        const double sh = sin(0.5 * th);
        A = sin(th) / th;
        B = 2.0 * sh * sh / th2;
        C = (th - sin(th)) / (th2 * th);
    }

    K[0] = 0.0;
    K[1] = -phi[2];
    K[2] = phi[1];
    K[3] = phi[2];
    K[4] = 0.0;
    K[5] = -phi[0];
    K[6] = -phi[1];
    K[7] = phi[0];
    K[8] = 0.0;
    mat3_mul(K, K, K2);
    for (i = 0; i < 9; ++i) {
        const double eye = (i % 4 == 0) ? 1.0 : 0.0;
        dR[i] = eye + A * K[i] + B * K2[i];
        V[i] = eye + B * K[i] + C * K2[i];
    }
    for (i = 0; i < 3; ++i) {
        Vr[i] = V[3 * i] * rho[0] + V[3 * i + 1] * rho[1] + V[3 * i + 2] * rho[2];
    }
    for (i = 0; i < 3; ++i) {
        p[i] += R[3 * i] * Vr[0] + R[3 * i + 1] * Vr[1] + R[3 * i + 2] * Vr[2];
    }
    mat3_mul(R, dR, Rn);
    memcpy(R, Rn, sizeof(Rn));
}

/* ---------- configuration ---------- */

void vl_sim_kitti_calibration(vl_calibration_t *cal)
{
    /* The real 0027 sequence's cam_T_imu (IMU x fwd, y left, z up -> camera x right, y down, z fwd). */
    /* clang-format off */
    static const double cam_T_imu[16] = {
        -1.08863514e-03, -9.99976347e-01,  6.78718180e-03,  1.14389871e+00,
        -8.51207214e-03, -6.77767115e-03, -9.99940872e-01, -3.12718471e-01,
         9.99963177e-01, -1.14634293e-03, -8.50449310e-03,  7.26546045e-01,
         0.0,             0.0,             0.0,             1.0};
    /* clang-format on */
    memset(cal, 0, sizeof(*cal));
    cal->fx = 707.0912;
    cal->fy = 707.0912;
    cal->cx = 601.8873;
    cal->cy = 183.1104;
    cal->baseline = 0.5371506;
    memcpy(cal->cam_T_imu, cam_T_imu, sizeof(cam_T_imu));
}

void vl_sim_config_default(vl_sim_config_t *cfg)
{
    int i;
    if (cfg == NULL) {
        return;
    }
    memset(cfg, 0, sizeof(*cfg));
    cfg->seed = 1;
    cfg->noise_seed = 0;
    cfg->num_steps = 300;
    cfg->start_utime = INT64_C(1317384000000000);
    cfg->dt_min = 0.099;
    cfg->dt_max = 0.109;

    cfg->speed = 8.0;
    cfg->speed_wobble = 1.0;
    cfg->side_wobble = 0.1;
    cfg->turn_angle = 1.5707963267948966;
    cfg->left_turn_probability = 0.5;
    cfg->turn_angle_spread = 0.15;
    cfg->turn_period = 8.5;
    cfg->first_turn_time = 5.0;
    cfg->turn_duration = 3.0;
    cfg->yaw_wobble = 0.03;
    cfg->roll_pitch_rate = 0.02;

    cfg->points_per_meter = 2.5;
    cfg->road_half_width = 3.0;
    cfg->scatter_radius = 40.0;
    cfg->scatter_exponent = 1.5;
    cfg->height_min = -1.0;
    cfg->height_max = 6.0;

    vl_sim_kitti_calibration(&cfg->calibration);
    cfg->image_width = 1241.0;
    cfg->image_height = 376.0;
    cfg->border_margin = 8.0;
    cfg->min_depth = 1.0;
    cfg->max_depth = 80.0;
    cfg->max_observations = VL_MAX_FRAME_FEATURES;
    cfg->detect_probability = 1.0;
    cfg->track_length_mean = 40.0;
    cfg->track_length_min = 2;

    cfg->pixel_noise = 1.0;
    cfg->linear_noise = 0.5;
    cfg->angular_noise = 0.05;
    for (i = 0; i < 3; ++i) {
        cfg->linear_offset[i] = 0.0;
        cfg->angular_offset[i] = 0.005;
        cfg->velocity_sensor[i] = 0.0;
    }
    cfg->interval_velocities = 0;
}

void vl_sim_config_realistic(vl_sim_config_t *cfg)
{
    /* Rates from tools/sim/track_stats.py on 0022, 0027 and 0034 (0027's ground truth for the
       outliers); see the README's vislam-sim paragraph. */
    int i;
    if (cfg == NULL) {
        return;
    }
    cfg->max_observations = 95;
    cfg->points_per_meter = 4.0;       /* enough untracked points for 35 to 48 new tracks per detection */
    cfg->pixel_noise = 0.3;            /* v_left - v_right has a std of 0.38 px on every drive */
    cfg->stale_probability = 0.0;      /* the real stale frames are the detection frames */
    cfg->detect_below_fraction = 0.53; /* 50 of 95: detection when fewer than 50 tracks remain */
    cfg->detect_new_fraction = 0.47;   /* 45 of 95: 35 to 48 new tracks per detection frame */
    cfg->reassoc_probability = 0.04;   /* 0.044 ids per frame on 0027 jump and then continue */
    cfg->reassoc_fraction = 0.02;      /* 1.3 ids in such a frame, of about 65 continued */
    cfg->reassoc_radius = 60.0;
    cfg->moving_fraction = 0.05; /* 2.8 % of 0027's tracks have a median one-step error > 3 px */
    cfg->moving_speed = 3.0;
    cfg->mismatch_probability = 0.0002; /* 0.02 % of 0027's observations are off by > 10 px alone */
    cfg->far_fraction = 0.06;           /* real: 1 to 5 % of observations under 2 px, 14 to 18 % under 5 */
    cfg->far_disparity_min = 0.8;
    cfg->far_disparity_max = 4.8;
    for (i = 0; i < 3; ++i) { /* a guess: the data cannot show a calibration error */
        cfg->calib_rotation_error[i] = (i == 1) ? -0.1 : 0.1;
        cfg->calib_translation_error[i] = (i == 1) ? -0.01 : 0.01;
    }
    cfg->baseline_error = 0.002;
    /* Across a stale frame 0027's carried tracks scatter by 1.25 / 1.35 px in u / v and 0.20 px in
       disparity (robust std) about the one-step-lost motion, against 0.42 / 0.37 / 0.12 px over an
       ordinary step: the jump is their difference in quadrature, 1.18 / 1.30 / 0.15 px. */
    cfg->stale_jump = 1.2;
    cfg->stale_jump_disparity = 0.15;
}

static int finite_all(const double *x, size_t n)
{
    size_t i;
    for (i = 0; i < n; ++i) {
        if (!isfinite(x[i])) {
            return 0;
        }
    }
    return 1;
}

static int unit_range(double x)
{
    return x >= 0.0 && x <= 1.0;
}

static int config_ok(const vl_sim_config_t *c)
{
    const double scalars[] = {c->dt_min,
                              c->dt_max,
                              c->speed,
                              c->speed_wobble,
                              c->side_wobble,
                              c->turn_angle,
                              c->left_turn_probability,
                              c->turn_angle_spread,
                              c->turn_period,
                              c->first_turn_time,
                              c->turn_duration,
                              c->yaw_wobble,
                              c->roll_pitch_rate,
                              c->points_per_meter,
                              c->road_half_width,
                              c->scatter_radius,
                              c->scatter_exponent,
                              c->height_min,
                              c->height_max,
                              c->image_width,
                              c->image_height,
                              c->border_margin,
                              c->min_depth,
                              c->max_depth,
                              c->detect_probability,
                              c->track_length_mean,
                              c->pixel_noise,
                              c->linear_noise,
                              c->angular_noise,
                              c->stale_probability,
                              c->detect_below_fraction,
                              c->detect_new_fraction,
                              c->reassoc_probability,
                              c->reassoc_fraction,
                              c->reassoc_radius,
                              c->moving_fraction,
                              c->moving_speed,
                              c->mismatch_probability,
                              c->far_fraction,
                              c->far_disparity_min,
                              c->far_disparity_max,
                              c->baseline_error,
                              c->stale_jump,
                              c->stale_jump_disparity};
    if (!finite_all(scalars, sizeof(scalars) / sizeof(scalars[0])) || !finite_all(c->linear_offset, 3) ||
        !finite_all(c->angular_offset, 3) || !finite_all(c->velocity_sensor, 3) || !finite_all(&c->calibration.fx, 5) ||
        !finite_all(c->calibration.cam_T_imu, 16) || !finite_all(c->calib_rotation_error, 3) ||
        !finite_all(c->calib_translation_error, 3)) {
        return 0;
    }
    if (!(unit_range(c->stale_probability) && unit_range(c->detect_below_fraction) &&
          unit_range(c->detect_new_fraction) && unit_range(c->reassoc_probability) && unit_range(c->reassoc_fraction) &&
          unit_range(c->moving_fraction) && unit_range(c->mismatch_probability) && unit_range(c->far_fraction) &&
          c->reassoc_radius >= 0.0 && c->stale_jump >= 0.0 && c->stale_jump < 1e3 && c->stale_jump_disparity >= 0.0 &&
          c->stale_jump_disparity < 1e3 && c->moving_speed >= 0.0 && c->moving_speed < 1e3 &&
          c->baseline_error > -0.5 && c->baseline_error < 0.5 &&
          (c->far_fraction == 0.0 || (c->far_disparity_min > 0.0 && c->far_disparity_max >= c->far_disparity_min)))) {
        return 0;
    }
    return c->dt_min > 0.0 && c->dt_max >= c->dt_min && c->dt_max < 1000.0 && c->turn_period > 0.0 &&
           c->turn_duration > 0.0 && c->turn_duration <= c->turn_period && c->turn_angle_spread >= 0.0 &&
           c->left_turn_probability >= 0.0 && c->left_turn_probability <= 1.0 && c->points_per_meter >= 0.0 &&
           c->road_half_width >= 0.0 && c->scatter_radius > c->road_half_width && c->scatter_exponent > 0.0 &&
           c->height_max >= c->height_min && c->max_depth < 1e4 && c->scatter_radius < 1e4 && c->calibration.fx > 0.0 &&
           c->calibration.fy > 0.0 && c->calibration.baseline > 0.0 && c->border_margin >= 0.0 &&
           c->image_width > 2.0 * c->border_margin + 1.0 && c->image_height > 2.0 * c->border_margin + 1.0 &&
           c->min_depth > 0.0 && c->max_depth > c->min_depth && c->max_observations >= 1 &&
           c->max_observations <= VL_MAX_FRAME_FEATURES && c->detect_probability >= 0.0 &&
           c->detect_probability <= 1.0 && c->track_length_min >= 1 &&
           c->track_length_mean >= (double)c->track_length_min && c->track_length_mean < 1e6 && c->pixel_noise >= 0.0 &&
           c->linear_noise >= 0.0 && c->angular_noise >= 0.0;
}

/* ---------- the true motion ---------- */

/** Angle of turn k, a pure function of (seed, k) so the path needs no per-turn storage. */
static double turn_angle_of(const vl_sim_config_t *c, int64_t k)
{
    uint64_t st = c->seed * 0x2545F4914F6CDD1DULL ^ ((uint64_t)k * 0x9E3779B97F4A7C15ULL);
    const double u1 = 1.0 - (double)(splitmix64(&st) >> 11) * 0x1.0p-53;
    const double u2 = (double)(splitmix64(&st) >> 11) * 0x1.0p-53;
    const double u3 = (double)(splitmix64(&st) >> 11) * 0x1.0p-53;
    const double n = sqrt(-2.0 * log(u1)) * cos(VL_SIM_TWO_PI * u2);
    const double sign = (u3 < c->left_turn_probability) ? 1.0 : -1.0;
    return sign * c->turn_angle * (1.0 + c->turn_angle_spread * n);
}

/** True body velocities [v; w] at s seconds after step 0. */
static void velocity_profile(const vl_sim_t *sim, double s, double u[6])
{
    const vl_sim_config_t *c = &sim->cfg;
    const double *ph = sim->phase;
    const double k_real = floor((s - c->first_turn_time) / c->turn_period + 0.5);
    double yaw = c->yaw_wobble * sin(VL_SIM_TWO_PI * s / 9.7 + ph[5]);

    if (k_real >= 0.0) {
        /* Raised-cosine bump: integrates to the turn angle over turn_duration. */
        const double x = s - (c->first_turn_time + k_real * c->turn_period);
        const double D = c->turn_duration;
        if (fabs(x) < 0.5 * D) {
            yaw += turn_angle_of(c, (int64_t)k_real) / D * (1.0 + cos(VL_SIM_TWO_PI * x / D));
        }
    }
    u[0] = c->speed + c->speed_wobble * sin(VL_SIM_TWO_PI * s / 13.0 + ph[0]);
    u[1] = c->side_wobble * sin(VL_SIM_TWO_PI * s / 5.3 + ph[1]);
    u[2] = c->side_wobble * sin(VL_SIM_TWO_PI * s / 3.7 + ph[2]);
    u[3] = c->roll_pitch_rate * sin(VL_SIM_TWO_PI * s / 2.9 + ph[3]);
    u[4] = c->roll_pitch_rate * sin(VL_SIM_TWO_PI * s / 4.1 + ph[4]);
    u[5] = yaw;
}

static const vl_sim_pose_t *ring_at(const vl_sim_t *sim, uint64_t k)
{
    return &sim->ring[k % VL_SIM_POSE_RING];
}

/**
 * 1 when a new point at x must be dropped: it lies on the road (within
 * road_half_width of a planned pose near segment k), or in an area an earlier
 * part of the path already filled (within scatter_radius of a pose more than
 * two radii back along the path). The second test keeps the world's density
 * when the path comes back; it reaches as far back as the pose ring does.
 */
static int reject_point(const vl_sim_t *sim, uint64_t k, const double x[3])
{
    const vl_sim_config_t *c = &sim->cfg;
    const double reach = c->scatter_radius + c->road_half_width;
    const double w2 = c->road_half_width * c->road_half_width;
    const double r2 = c->scatter_radius * c->scatter_radius;
    const double s = ring_at(sim, k)->s;
    const uint64_t oldest = sim->planned > VL_SIM_POSE_RING ? sim->planned - VL_SIM_POSE_RING : 0;
    uint64_t j;
    for (j = k + 1; j-- > oldest;) {
        const vl_sim_pose_t *q = ring_at(sim, j);
        const double dx = x[0] - q->p[0], dy = x[1] - q->p[1];
        const double d2 = dx * dx + dy * dy;
        if (d2 < w2 || (s - q->s > 2.0 * c->scatter_radius && d2 < r2)) {
            return 1;
        }
    }
    /* Path length bounds straight-line distance: poses farther ahead cannot be near x. */
    for (j = k + 1; j < sim->planned && ring_at(sim, j)->s - s <= reach; ++j) {
        const double dx = x[0] - ring_at(sim, j)->p[0], dy = x[1] - ring_at(sim, j)->p[1];
        if (dx * dx + dy * dy < w2) {
            return 1;
        }
    }
    return 0;
}

/**
 * Puts a point far ahead of the vehicle instead: at a depth whose disparity is uniform in
 * [far_disparity_min, far_disparity_max], within the camera's horizontal view. Placed from the
 * vehicle's current pose, not the segment's, so the disparity it is first seen with is the drawn one.
 */
static void place_far(vl_sim_t *sim, double x[3])
{
    const vl_sim_config_t *c = &sim->cfg;
    vl_sim_rng_t *r = &sim->rng_place;
    const vl_sim_pose_t *at = ring_at(sim, sim->step);
    const double half_view = 0.6; /* rad: inside the KITTI camera's 40-degree half view */
    const double bearing = half_view * (2.0 * rng_uniform(r) - 1.0);
    const double disp = c->far_disparity_min + (c->far_disparity_max - c->far_disparity_min) * rng_uniform(r);
    const double depth = c->calibration.fx * c->calibration.baseline / disp;
    const double h = c->height_min + (c->height_max - c->height_min) * rng_uniform(r);
    const double b[3] = {depth * cos(bearing), depth * sin(bearing), h};
    int i;
    for (i = 0; i < 3; ++i) {
        x[i] = at->p[i] + at->R[3 * i] * b[0] + at->R[3 * i + 1] * b[1] + at->R[3 * i + 2] * b[2];
    }
}

/** Scatters the points of planned segment k (from pose k to k + 1). */
static void scatter_segment(vl_sim_t *sim, uint64_t k)
{
    const vl_sim_config_t *c = &sim->cfg;
    vl_sim_rng_t *r = &sim->rng_map;
    const vl_sim_pose_t *at = ring_at(sim, k);
    const double len = ring_at(sim, k + 1)->s - at->s;

    sim->spawn_carry += c->points_per_meter * len;
    while (sim->spawn_carry >= 1.0) {
        const double ang = VL_SIM_TWO_PI * rng_uniform(r);
        const double rad =
            c->road_half_width + (c->scatter_radius - c->road_half_width) * pow(rng_uniform(r), c->scatter_exponent);
        const double h = c->height_min + (c->height_max - c->height_min) * rng_uniform(r);
        const double b[3] = {len * rng_uniform(r) + rad * cos(ang), rad * sin(ang), h};
        vl_sim_point_t *pt = &sim->points[sim->next_point];
        double x[3];
        int i, far = 0;

        sim->spawn_carry -= 1.0;
        for (i = 0; i < 3; ++i) {
            x[i] = at->p[i] + at->R[3 * i] * b[0] + at->R[3 * i + 1] * b[1] + at->R[3 * i + 2] * b[2];
        }
        /* The map stream's draws above happen either way, so the other points stay where they were. */
        if (c->far_fraction > 0.0 && rng_uniform(&sim->rng_place) < c->far_fraction) {
            place_far(sim, x);
            far = 1;
        }
        if (!far && reject_point(sim, k, x)) {
            continue;
        }
        memcpy(pt->x, x, sizeof(x));
        memset(pt->v, 0, sizeof(pt->v));
        memset(pt->shift, 0, sizeof(pt->shift));
        pt->t0 = at->utime;
        pt->far = (uint8_t)far;
        pt->moving = 0;
        pt->shifted = 0;
        if (c->moving_fraction > 0.0 && rng_uniform(&sim->rng_place) < c->moving_fraction) {
            const double heading = VL_SIM_TWO_PI * rng_uniform(&sim->rng_place);
            pt->v[0] = c->moving_speed * cos(heading);
            pt->v[1] = c->moving_speed * sin(heading);
            pt->moving = 1;
        }
        /* Recycling a slot silently ends the old point's track: its id is never seen again. */
        pt->track_id = -1;
        pt->remaining = 0;
        sim->next_point = (sim->next_point + 1) % VL_SIM_MAX_POINTS;
        if (sim->num_points < VL_SIM_MAX_POINTS) {
            ++sim->num_points;
        }
    }
}

/** Plans one more step: the velocities of the last planned pose and the next pose. */
static void plan_one(vl_sim_t *sim)
{
    const vl_sim_config_t *c = &sim->cfg;
    vl_sim_pose_t *cur = &sim->ring[(sim->planned - 1) % VL_SIM_POSE_RING];
    vl_sim_pose_t *nxt = &sim->ring[sim->planned % VL_SIM_POSE_RING];
    const double s = (double)(cur->utime - c->start_utime) * 1e-6;
    const double dt = c->dt_min + (c->dt_max - c->dt_min) * rng_uniform(&sim->rng_path);
    int64_t dt_us = (int64_t)floor(dt * 1e6 + 0.5);
    double tau, len;

    if (dt_us < 1) {
        dt_us = 1;
    }
    tau = (double)dt_us * 1e-6;
    velocity_profile(sim, s, cur->u);

    nxt->utime = cur->utime + dt_us;
    memcpy(nxt->R, cur->R, sizeof(cur->R));
    memcpy(nxt->p, cur->p, sizeof(cur->p));
    if (c->interval_velocities) {
        vl_sim_integrate(nxt->R, nxt->p, cur->u, tau);
    } else {
        const double h = tau / VL_SIM_SUBSTEPS;
        int j;
        for (j = 0; j < VL_SIM_SUBSTEPS; ++j) {
            double u[6];
            velocity_profile(sim, s + ((double)j + 0.5) * h, u);
            vl_sim_integrate(nxt->R, nxt->p, u, h);
        }
    }

    len = tau * sqrt(cur->u[0] * cur->u[0] + cur->u[1] * cur->u[1] + cur->u[2] * cur->u[2]);
    nxt->s = cur->s + len;
    ++sim->planned;
}

/* ---------- public API ---------- */

/** The calibration the observations are made with: the nominal one moved by the configured errors. */
static void perturbed_calibration(const vl_sim_config_t *c, vl_calibration_t *out)
{
    const double deg = VL_SIM_TWO_PI / 360.0;
    const double phi[3] = {c->calib_rotation_error[0] * deg, c->calib_rotation_error[1] * deg,
                           c->calib_rotation_error[2] * deg};
    const double *e = c->calib_translation_error;
    double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1}, t[3] = {0, 0, 0};
    double u[6];
    const double *T = c->calibration.cam_T_imu;
    int i, j;

    *out = c->calibration;
    if (phi[0] == 0.0 && phi[1] == 0.0 && phi[2] == 0.0 && e[0] == 0.0 && e[1] == 0.0 && e[2] == 0.0 &&
        c->baseline_error == 0.0) {
        return; /* untouched, so the plain simulator's pixels stay bit for bit */
    }
    u[0] = u[1] = u[2] = 0.0;
    u[3] = phi[0];
    u[4] = phi[1];
    u[5] = phi[2];
    vl_sim_integrate(R, t, u, 1.0); /* R = exp(hat(phi)) */
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            out->cam_T_imu[4 * i + j] = R[3 * i] * T[j] + R[3 * i + 1] * T[4 + j] + R[3 * i + 2] * T[8 + j];
        }
        out->cam_T_imu[4 * i + 3] = R[3 * i] * T[3] + R[3 * i + 1] * T[7] + R[3 * i + 2] * T[11] + e[i];
    }
    out->baseline = c->calibration.baseline * (1.0 + c->baseline_error);
}

int vl_sim_init(vl_sim_t *sim, const vl_sim_config_t *cfg)
{
    vl_sim_pose_t *p0;
    int i;
    if (sim == NULL || cfg == NULL || !config_ok(cfg)) {
        return -1;
    }
    memset(sim, 0, sizeof(*sim));
    sim->cfg = *cfg;
    rng_seed(&sim->rng_path, cfg->seed, 1);
    rng_seed(&sim->rng_map, cfg->seed, 2);
    rng_seed(&sim->rng_track, cfg->seed, 3);
    rng_seed(&sim->rng_noise, cfg->seed ^ (cfg->noise_seed * 0xA0761D6478BD642FULL), 4 + cfg->noise_seed);
    /* Tags far from 4 + noise_seed for any practical noise_seed, so no stream coincides. */
    rng_seed(&sim->rng_event, cfg->seed, UINT64_C(0x5EED000000000005));
    rng_seed(&sim->rng_place, cfg->seed, UINT64_C(0x5EED000000000006));
    rng_seed(&sim->rng_jump, cfg->seed, UINT64_C(0x5EED000000000007));
    perturbed_calibration(cfg, &sim->obs_calib);
    for (i = 0; i < 8; ++i) {
        sim->phase[i] = VL_SIM_TWO_PI * rng_uniform(&sim->rng_path);
    }
    p0 = &sim->ring[0];
    p0->utime = cfg->start_utime;
    p0->R[0] = p0->R[4] = p0->R[8] = 1.0;
    sim->planned = 1;
    sim->step = 0;
    return 0;
}

/** Farthest depth a far point is observable at, m. */
#define VL_SIM_FAR_DEPTH 1e4

/** True [u_left, v, u_right, depth] of a world point seen from a pose; 1 when observable. */
/** The world point x in the observations' camera frame at pose. */
static void camera_point(const vl_sim_t *sim, const vl_sim_pose_t *pose, const double x[3], double cam[3])
{
    const double *T = sim->obs_calib.cam_T_imu;
    const double d[3] = {x[0] - pose->p[0], x[1] - pose->p[1], x[2] - pose->p[2]};
    double b[3];
    int i;
    for (i = 0; i < 3; ++i) { /* b = R^T d: the point in the IMU frame */
        b[i] = pose->R[i] * d[0] + pose->R[3 + i] * d[1] + pose->R[6 + i] * d[2];
    }
    for (i = 0; i < 3; ++i) {
        cam[i] = T[4 * i] * b[0] + T[4 * i + 1] * b[1] + T[4 * i + 2] * b[2] + T[4 * i + 3];
    }
}

static int project(const vl_sim_t *sim, const vl_sim_pose_t *pose, const double x[3], int far, double px[4])
{
    const vl_sim_config_t *c = &sim->cfg;
    const vl_calibration_t *cal = &sim->obs_calib;
    const double max_depth = far ? VL_SIM_FAR_DEPTH : c->max_depth;
    double cam[3];
    double lo_u, hi_u, lo_v, hi_v;

    camera_point(sim, pose, x, cam);
    if (!(cam[2] > c->min_depth && cam[2] < max_depth)) {
        return 0;
    }
    px[0] = cal->fx * cam[0] / cam[2] + cal->cx;
    px[1] = cal->fy * cam[1] / cam[2] + cal->cy;
    px[2] = px[0] - cal->fx * cal->baseline / cam[2];
    px[3] = cam[2];
    lo_u = c->border_margin;
    hi_u = c->image_width - 1.0 - c->border_margin;
    lo_v = c->border_margin;
    hi_v = c->image_height - 1.0 - c->border_margin;
    return px[0] >= lo_u && px[0] <= hi_u && px[2] >= lo_u && px[2] <= hi_u && px[1] >= lo_v && px[1] <= hi_v;
}

/** Where the current track of a point sees it at time utime (moving points move, lost motion shifts). */
static void point_position(const vl_sim_point_t *pt, int64_t utime, double y[3])
{
    int i;
    memcpy(y, pt->x, 3 * sizeof(double));
    if (pt->moving) {
        const double dt = (double)(utime - pt->t0) * 1e-6;
        for (i = 0; i < 3; ++i) {
            y[i] += pt->v[i] * dt;
        }
    }
    if (pt->shifted) {
        for (i = 0; i < 3; ++i) {
            y[i] += pt->shift[i];
        }
    }
}

/** project() of a point's current track position. */
static int project_point(const vl_sim_t *sim, const vl_sim_pose_t *pose, const vl_sim_point_t *pt, double px[4])
{
    double y[3];
    point_position(pt, pose->utime, y);
    return project(sim, pose, y, pt->far, px);
}

/** A noisy pixel inside [0, hi]: out-of-image draws are redrawn so observations stay in the image. */
static double noisy_pixel(vl_sim_t *sim, double value, double hi)
{
    int tries;
    double m = value;
    for (tries = 0; tries < 64; ++tries) {
        m = value + sim->cfg.pixel_noise * rng_normal(&sim->rng_noise);
        if (m >= 0.0 && m <= hi) {
            return m;
        }
    }
    return value < 0.0 ? 0.0 : (value > hi ? hi : value);
}

static uint32_t draw_track_length(vl_sim_t *sim)
{
    const vl_sim_config_t *c = &sim->cfg;
    /* floor(Exp(m)) has mean about m - 0.5, hence the half frame. */
    const double m = c->track_length_mean - (double)c->track_length_min + 0.5;
    const double u = 1.0 - rng_uniform(&sim->rng_track);
    double extra = (m > 0.5) ? floor(-log(u) * m) : 0.0;
    if (extra > 1e6) {
        extra = 1e6;
    }
    return c->track_length_min + (uint32_t)extra;
}

/** round(fraction * max_observations), at least 1. */
static uint32_t share_of_frame(const vl_sim_config_t *c, double fraction)
{
    const double n = floor(fraction * (double)c->max_observations + 0.5);
    return n < 1.0 ? 1u : (uint32_t)n;
}

/**
 * Hands the id of observed point cand_point[slot] to another visible untracked point within
 * reassoc_radius px of it (uniformly among them); the old point's track ends. 1 when handed over.
 */
static int reassociate(vl_sim_t *sim, const vl_sim_pose_t *pose, uint32_t slot)
{
    const double r2 = sim->cfg.reassoc_radius * sim->cfg.reassoc_radius;
    vl_sim_point_t *src = &sim->points[sim->cand_point[slot]];
    uint32_t i, eligible = 0, pick;
    double at[4], px[4];
    int pass;

    if (!project_point(sim, pose, src, at)) {
        return 0;
    }
    /* Two passes (count, then take the pick-th) keep it allocation-free. */
    pick = 0;
    for (pass = 0; pass < 2; ++pass) {
        uint32_t seen = 0;
        for (i = 0; i < sim->num_points; ++i) {
            vl_sim_point_t *pt = &sim->points[i];
            double du, dv;
            if (pt->track_id >= 0 || !project_point(sim, pose, pt, px)) {
                continue;
            }
            du = px[0] - at[0];
            dv = px[1] - at[1];
            if (du * du + dv * dv > r2) {
                continue;
            }
            if (pass == 1 && seen == pick) {
                pt->track_id = src->track_id;
                pt->remaining = src->remaining;
                pt->shifted = 0;
                memset(pt->shift, 0, sizeof(pt->shift));
                src->track_id = -1;
                src->remaining = 0;
                sim->cand_point[slot] = i;
                ++sim->counts.reassociations;
                return 1;
            }
            ++seen;
        }
        if (pass == 0) {
            eligible = seen;
            if (eligible == 0) {
                return 0;
            }
            pick = (uint32_t)(rng_uniform(&sim->rng_event) * (double)eligible);
            if (pick >= eligible) {
                pick = eligible - 1;
            }
        }
    }
    return 0;
}

/** Re-associates a share of the n_cont continued tracks of this frame (a frame chosen by the caller). */
static void reassociate_frame(vl_sim_t *sim, const vl_sim_pose_t *pose, uint32_t n_cont)
{
    uint32_t i, chosen = 0;
    if (n_cont == 0) {
        return;
    }
    for (i = 0; i < n_cont; ++i) {
        if (rng_uniform(&sim->rng_event) < sim->cfg.reassoc_fraction) {
            chosen += (uint32_t)reassociate(sim, pose, i);
        }
    }
    if (chosen == 0) {
        uint32_t slot = (uint32_t)(rng_uniform(&sim->rng_event) * (double)n_cont);
        (void)reassociate(sim, pose, slot < n_cont ? slot : n_cont - 1);
    }
}

/** Moves what a track sees by T(k+1) T(k)^-1, so it shows pose k at step k + 1 (motion lost). */
static void lose_one_step(vl_sim_point_t *pt, const vl_sim_pose_t *k0, const vl_sim_pose_t *k1)
{
    double y[3], d[3], b[3];
    int i;
    point_position(pt, k0->utime, y);
    for (i = 0; i < 3; ++i) {
        d[i] = y[i] - k0->p[i];
    }
    for (i = 0; i < 3; ++i) {
        b[i] = k0->R[i] * d[0] + k0->R[3 + i] * d[1] + k0->R[6 + i] * d[2];
    }
    for (i = 0; i < 3; ++i) {
        pt->shift[i] += k1->R[3 * i] * b[0] + k1->R[3 * i + 1] * b[1] + k1->R[3 * i + 2] * b[2] + k1->p[i] - y[i];
    }
    pt->shifted = 1;
}

/**
 * Displaces what a track carried over a stale frame sees from pose k1 on: the point as seen from
 * k1 with its u and v moved by stale_jump px and its disparity by stale_jump_disparity px (one
 * draw each), back in the world. A point that k1 cannot see keeps its place.
 */
static void jump(vl_sim_t *sim, vl_sim_point_t *pt, const vl_sim_pose_t *k1)
{
    const vl_calibration_t *cal = &sim->obs_calib;
    const double *T = cal->cam_T_imu;
    double y[3], b[3], cam[3], moved[3], back[3];
    double u, v, disp, z;
    int i;
    point_position(pt, k1->utime, y);
    camera_point(sim, k1, y, cam);
    /* Three draws whatever follows, so the stream stays aligned across points. */
    u = sim->cfg.stale_jump * rng_normal(&sim->rng_jump);
    v = sim->cfg.stale_jump * rng_normal(&sim->rng_jump);
    disp = sim->cfg.stale_jump_disparity * rng_normal(&sim->rng_jump);
    if (!(cam[2] > 0.0)) {
        return;
    }
    disp += cal->fx * cal->baseline / cam[2];
    if (!(disp > 0.0)) {
        return; /* a jump through zero disparity: no place to see it at */
    }
    z = cal->fx * cal->baseline / disp;
    u += cal->fx * cam[0] / cam[2];
    v += cal->fy * cam[1] / cam[2];
    moved[0] = u * z / cal->fx - cam[0];
    moved[1] = v * z / cal->fy - cam[1];
    moved[2] = z - cam[2];
    for (i = 0; i < 3; ++i) { /* camera to IMU (the rotation's transpose), then to the world */
        b[i] = T[i] * moved[0] + T[4 + i] * moved[1] + T[8 + i] * moved[2];
    }
    for (i = 0; i < 3; ++i) {
        back[i] = k1->R[3 * i] * b[0] + k1->R[3 * i + 1] * b[1] + k1->R[3 * i + 2] * b[2];
        pt->shift[i] += back[i];
    }
    pt->shifted = 1;
}

int vl_sim_step(vl_sim_t *sim, vl_imu_sample_t *imu, vl_stereo_frame_t *frame, double true_R[9], double true_p[3])
{
    const vl_sim_config_t *c;
    const vl_sim_pose_t *pose;
    uint32_t n_obs = 0, n_cont, i, new_cap;
    int stale = 0, may_detect = 1;
    double px[4];

    if (sim == NULL) {
        return 1;
    }
    c = &sim->cfg;
    if (c->num_steps != 0 && sim->step >= c->num_steps) {
        return 1;
    }

    pose = &sim->ring[sim->step % VL_SIM_POSE_RING];
    {
        /* Points must exist wherever the camera can look (max_depth ahead, widened by the
           scatter radius because a pose scatters behind itself too), and each scattered
           segment needs the path planned scatter_radius beyond it for the road test. */
        const double scatter_ahead = c->max_depth + c->scatter_radius + 5.0;
        const double plan_ahead = scatter_ahead + c->scatter_radius + c->road_half_width + 5.0;
        while (sim->planned < sim->step + 2 || (ring_at(sim, sim->planned - 1)->s - pose->s < plan_ahead &&
                                                sim->planned - sim->step < VL_SIM_POSE_RING - 1)) {
            plan_one(sim);
        }
        while (sim->scattered + 1 < sim->planned && ring_at(sim, sim->scattered)->s - pose->s < scatter_ahead) {
            scatter_segment(sim, sim->scattered++);
        }
    }

    if (sim->step > 0) {
        if (c->stale_probability > 0.0 && rng_uniform(&sim->rng_event) < c->stale_probability) {
            stale = 1;
        }
        if (c->detect_below_fraction > 0.0) {
            /* Not twice in a row: the real stale frames stand alone (at least 2 frames apart). */
            if (sim->last_count < share_of_frame(c, c->detect_below_fraction) && !sim->last_stale) {
                stale = 1;
            }
            may_detect = stale;
        }
    }
    new_cap = c->detect_new_fraction > 0.0 ? share_of_frame(c, c->detect_new_fraction) : VL_MAX_FRAME_FEATURES;

    /* Pass 1: continue live tracks (in slot order) while they stay visible and young. A stale
       frame continues every one of them as it was. */
    for (i = 0; i < sim->num_points; ++i) {
        vl_sim_point_t *pt = &sim->points[i];
        if (pt->track_id < 0) {
            continue;
        }
        if (stale) {
            sim->cand_point[n_obs++] = i;
        } else if (pt->remaining > 0 && n_obs < c->max_observations && project_point(sim, pose, pt, px)) {
            --pt->remaining;
            sim->cand_point[n_obs++] = i;
        } else {
            pt->track_id = -1;
            pt->remaining = 0;
            pt->shifted = 0;
            memset(pt->shift, 0, sizeof(pt->shift));
        }
    }
    /* Ids are issued in order, so sorting the continued tracks by id gives an ascending frame. */
    for (i = 1; i < n_obs; ++i) {
        const uint32_t v = sim->cand_point[i];
        uint32_t j = i;
        while (j > 0 && sim->points[sim->cand_point[j - 1]].track_id > sim->points[v].track_id) {
            sim->cand_point[j] = sim->cand_point[j - 1];
            --j;
        }
        sim->cand_point[j] = v;
    }
    n_cont = n_obs;
    if (!stale && c->reassoc_probability > 0.0 && rng_uniform(&sim->rng_event) < c->reassoc_probability) {
        reassociate_frame(sim, pose, n_cont);
    }

    /* Pass 2: start new tracks on visible untracked points. */
    for (i = 0; may_detect && i < sim->num_points && n_obs < c->max_observations && n_obs - n_cont < new_cap; ++i) {
        vl_sim_point_t *pt = &sim->points[i];
        if (pt->track_id >= 0 || !project_point(sim, pose, pt, px)) {
            continue; /* continued this frame, or not visible */
        }
        if (rng_uniform(&sim->rng_track) >= c->detect_probability) {
            continue;
        }
        pt->track_id = sim->next_track_id++;
        pt->remaining = draw_track_length(sim) - 1;
        pt->shifted = 0; /* a new track sees the point where it is */
        memset(pt->shift, 0, sizeof(pt->shift));
        point_position(pt, pose->utime, sim->track_x[(uint32_t)pt->track_id % VL_SIM_MAX_TRACKS]);
        sim->cand_point[n_obs++] = i;
    }

    /* Measurements: noise draws in a fixed order (IMU first, then pixels by id). */
    sim->last_true_imu.utime = pose->utime;
    for (i = 0; i < 3; ++i) {
        sim->last_true_imu.linear_velocity[i] = pose->u[i];
        sim->last_true_imu.angular_velocity[i] = pose->u[3 + i];
    }
    {
        double lin[3], ang[3];
        const double *w = &pose->u[3], *q = c->velocity_sensor;
        const double turn[3] = {w[1] * q[2] - w[2] * q[1], w[2] * q[0] - w[0] * q[2], w[0] * q[1] - w[1] * q[0]};
        for (i = 0; i < 3; ++i) {
            lin[i] = pose->u[i] + turn[i] + c->linear_offset[i] + c->linear_noise * rng_normal(&sim->rng_noise);
        }
        for (i = 0; i < 3; ++i) {
            ang[i] = pose->u[3 + i] + c->angular_offset[i] + c->angular_noise * rng_normal(&sim->rng_noise);
        }
        if (imu != NULL) {
            imu->utime = pose->utime;
            memcpy(imu->linear_velocity, lin, sizeof(lin));
            memcpy(imu->angular_velocity, ang, sizeof(ang));
        }
    }
    if (stale) {
        /* Repeat the last frame's observations of the continued tracks. Both lists ascend by id;
           a track whose point slot was recycled since is missing from cand_point. */
        uint32_t r = 0, w;
        for (w = 0; w < n_cont; ++w) {
            const int32_t id = sim->points[sim->cand_point[w]].track_id;
            while (r < sim->last_count && sim->last_obs[r].id < id) {
                ++r;
            }
            sim->last_obs[w] = sim->last_obs[r]; /* r >= w: reading ahead of the writes */
            ++r;
        }
    }
    for (i = stale ? n_cont : 0; i < n_obs; ++i) {
        const vl_sim_point_t *pt = &sim->points[sim->cand_point[i]];
        const double hu = c->image_width - 1.0, hv = c->image_height - 1.0;
        vl_stereo_obs_t *o = &sim->last_obs[i];
        (void)project_point(sim, pose, pt, px);
        o->id = pt->track_id;
        o->u_left = noisy_pixel(sim, px[0], hu);
        o->v_left = noisy_pixel(sim, px[1], hv);
        o->u_right = noisy_pixel(sim, px[2], hu);
        o->v_right = noisy_pixel(sim, px[1], hv);
        if (c->mismatch_probability > 0.0 && i < n_cont && rng_uniform(&sim->rng_event) < c->mismatch_probability) {
            /* Another location's pixels: anywhere in the image, a disparity of 1 to 40 px. */
            const double disp = 1.0 + 39.0 * rng_uniform(&sim->rng_event);
            o->u_left = hu * rng_uniform(&sim->rng_event);
            o->v_left = hv * rng_uniform(&sim->rng_event);
            o->u_right = o->u_left > disp ? o->u_left - disp : 0.0;
            o->v_right = o->v_left;
            ++sim->counts.mismatches;
        }
    }
    if (stale) {
        const vl_sim_pose_t *next = ring_at(sim, sim->step + 1);
        for (i = 0; i < n_cont; ++i) {
            lose_one_step(&sim->points[sim->cand_point[i]], pose, next);
            if (c->stale_jump > 0.0 || c->stale_jump_disparity > 0.0) {
                jump(sim, &sim->points[sim->cand_point[i]], next);
            }
        }
        ++sim->counts.stale_frames;
    }
    sim->last_count = n_obs;
    sim->last_stale = (uint8_t)stale;
    if (frame != NULL) {
        frame->utime = pose->utime;
        frame->count = n_obs;
        memcpy(frame->obs, sim->last_obs, n_obs * sizeof(sim->last_obs[0]));
    }
    if (true_R != NULL) {
        memcpy(true_R, pose->R, sizeof(pose->R));
    }
    if (true_p != NULL) {
        memcpy(true_p, pose->p, sizeof(pose->p));
    }

    sim->vehicle_distance = pose->s;
    ++sim->step;
    return 0;
}

void vl_sim_counts(const vl_sim_t *sim, vl_sim_counts_t *counts)
{
    if (counts == NULL) {
        return;
    }
    if (sim == NULL) {
        memset(counts, 0, sizeof(*counts));
        return;
    }
    *counts = sim->counts;
}

void vl_sim_calibration(const vl_sim_t *sim, vl_calibration_t *calib)
{
    if (sim != NULL && calib != NULL) {
        *calib = sim->cfg.calibration;
    }
}

int vl_sim_landmark(const vl_sim_t *sim, int32_t id, double position[3])
{
    if (sim == NULL || position == NULL || id < 0 || id >= sim->next_track_id ||
        (int64_t)id < (int64_t)sim->next_track_id - VL_SIM_MAX_TRACKS) {
        return -1;
    }
    memcpy(position, sim->track_x[(uint32_t)id % VL_SIM_MAX_TRACKS], 3 * sizeof(double));
    return 0;
}

const vl_imu_sample_t *vl_sim_true_imu(const vl_sim_t *sim)
{
    return sim != NULL ? &sim->last_true_imu : NULL;
}

uint64_t vl_sim_steps_done(const vl_sim_t *sim)
{
    return sim != NULL ? sim->step : 0;
}

int32_t vl_sim_tracks_issued(const vl_sim_t *sim)
{
    return sim != NULL ? sim->next_track_id : 0;
}

double vl_sim_distance(const vl_sim_t *sim)
{
    return sim != NULL ? sim->vehicle_distance : 0.0;
}
