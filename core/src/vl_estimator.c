/*
 * The estimator: prediction on SE(3), stereo landmark initialization, the joint
 * update, and the bounded landmark window with exact marginalization.
 *
 * State order: [rho, phi (pose, right perturbation), linear offset, angular offset,
 * landmark 0, landmark 1, ...]. Offsets are always present in the layout; with
 * estimate_input_offsets off their covariance stays zero, so they never move.
 */
#include "vislam/vislam.h"

#include <math.h>
#include <string.h>

#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_stereo.h"

#define LD VL_STATE_DIM_MAX
#define IDX_OFFSET_LIN 6
#define IDX_OFFSET_ANG 9

typedef char vl_assert_capacity_positive[(VL_MAX_LANDMARKS >= 1) ? 1 : -1];
typedef char vl_assert_capacity_bounded[(VL_MAX_LANDMARKS <= 4096) ? 1 : -1];
typedef char vl_assert_frame_capacity[(VL_MAX_FRAME_FEATURES >= 1) ? 1 : -1];
typedef char vl_assert_pending_capacity[(VL_MAX_PENDING >= VL_MAX_FRAME_FEATURES) ? 1 : -1];

static double *P_at(vl_estimator_t *e, uint32_t row, uint32_t col)
{
    return &e->P[(size_t)col * LD + row];
}

static uint32_t landmark_col(uint32_t slot)
{
    return VL_CORE_DIM + 3u * slot;
}

static void log_msg(const vl_estimator_t *e, vl_log_level_t level, int64_t utime, const char *msg)
{
    if (e->cfg.log != NULL) {
        e->cfg.log(e->cfg.log_user, level, utime, msg);
    }
}

static int all_finite(const double *v, int n)
{
    for (int i = 0; i < n; ++i) {
        if (!isfinite(v[i])) {
            return 0;
        }
    }
    return 1;
}

/* ---------------------------------------------------------------- geometry */

/* cam_T_imu as rotation and translation. */
static void camera_extrinsics(const vl_calibration_t *cal, double Rc[9], double tc[3])
{
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Rc[3 * i + j] = cal->cam_T_imu[4 * i + j];
        }
        tc[i] = cal->cam_T_imu[4 * i + 3];
    }
}

/* World point of a landmark state and d(point)/d(state). */
static void landmark_world_point(const vl_estimator_t *e, uint32_t slot, double pw[3], double dpw[9])
{
    const double *lam = &e->landmark_state[3 * slot];
    if (e->cfg.landmark_param == VL_LANDMARK_XYZ) {
        memcpy(pw, lam, 3 * sizeof(double));
        if (dpw != NULL) {
            static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
            memcpy(dpw, I3, sizeof(I3));
        }
        return;
    }
    const vl_landmark_slot_t *s = &e->slots[slot];
    const double rho = lam[2];
    const double m[3] = {lam[0] / rho, lam[1] / rho, 1.0 / rho};
    double Rm[3];
    vl_matmul(s->anchor_R, m, Rm, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        pw[i] = Rm[i] + s->anchor_p[i];
    }
    if (dpw != NULL) {
        /* p = R_a [a, b, 1] / rho + t_a */
        for (int i = 0; i < 3; ++i) {
            dpw[3 * i + 0] = s->anchor_R[3 * i + 0] / rho;
            dpw[3 * i + 1] = s->anchor_R[3 * i + 1] / rho;
            dpw[3 * i + 2] = -Rm[i] / rho;
        }
    }
}

/*
 * Predicted compressed observation of a world point, d y / d xi (pose, 3x6) and
 * d y / d p_w (3x3). Returns 0 when the point is in front of the camera.
 */
static int project_world_point(const vl_estimator_t *e, const double pw[3], double y[3], double H_pose[18],
                               double dy_dpw[9])
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3];
    camera_extrinsics(cal, Rc, tc);

    /* body point b = R^T (p_w - p), camera point c = Rc b + tc */
    double d[3] = {pw[0] - e->p[0], pw[1] - e->p[1], pw[2] - e->p[2]};
    double b[3], c[3];
    vl_matmul_at(e->R, d, b, 3, 3, 1);
    vl_matmul(Rc, b, c, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        c[i] += tc[i];
    }
    if (!(c[2] > 1e-3)) {
        return -1;
    }
    double dy_dc[9];
    vl_stereo_project(cal, c, y, dy_dc);

    /* d b / d xi = -odot(b) (right perturbation of the world-from-IMU pose) */
    double odot[18], dy_db[9];
    vl_circle_dot(b, odot);
    vl_matmul(dy_dc, Rc, dy_db, 3, 3, 3);
    vl_matmul(dy_db, odot, H_pose, 3, 3, 6);
    for (int i = 0; i < 18; ++i) {
        H_pose[i] = -H_pose[i];
    }
    /* d b / d p_w = R^T */
    vl_matmul_bt(dy_db, e->R, dy_dpw, 3, 3, 3);
    return 0;
}

/* Predicted observation of a window landmark and its Jacobians. */
static int predict_observation(const vl_estimator_t *e, uint32_t slot, double y[3], double H_pose[18],
                               double H_lm[9])
{
    double pw[3], dpw[9], dy_dpw[9];
    landmark_world_point(e, slot, pw, dpw);
    if (project_world_point(e, pw, y, H_pose, dy_dpw) != 0) {
        return -1;
    }
    vl_matmul(dy_dpw, dpw, H_lm, 3, 3, 3);
    return 0;
}

/* Squared Mahalanobis length r^T S^-1 r of a 3-vector; a non-SPD S gives infinity. */
static double mahalanobis3(const double S[9], const double r[3])
{
    const double d00 = S[0];
    if (!(d00 > 0.0)) {
        return INFINITY;
    }
    const double l00 = sqrt(d00);
    const double l10 = S[3] / l00, l20 = S[6] / l00;
    const double d11 = S[4] - l10 * l10;
    if (!(d11 > 0.0)) {
        return INFINITY;
    }
    const double l11 = sqrt(d11);
    const double l21 = (S[7] - l20 * l10) / l11;
    const double d22 = S[8] - l20 * l20 - l21 * l21;
    if (!(d22 > 0.0)) {
        return INFINITY;
    }
    const double l22 = sqrt(d22);
    const double w0 = r[0] / l00;
    const double w1 = (r[1] - l10 * w0) / l11;
    const double w2 = (r[2] - l20 * w0 - l21 * w1) / l22;
    return w0 * w0 + w1 * w1 + w2 * w2;
}

/* World point and its pixel-noise covariance from one compressed observation at the current pose. */
static void triangulate_world(const vl_estimator_t *e, const double y[3], double pw[3], double C[9])
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3], c[3], dc_dy[9], d[3], b[3], J[9], RRc[9], tmp[9];
    camera_extrinsics(cal, Rc, tc);
    vl_stereo_triangulate(cal, y, c, dc_dy);
    for (int i = 0; i < 3; ++i) {
        d[i] = c[i] - tc[i];
    }
    vl_matmul_at(Rc, d, b, 3, 3, 1);
    vl_matmul(e->R, b, pw, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        pw[i] += e->p[i];
    }
    vl_matmul_bt(e->R, Rc, RRc, 3, 3, 3);
    vl_matmul(RRc, dc_dy, J, 3, 3, 3);
    const double s2 = e->cfg.pixel_noise * e->cfg.pixel_noise;
    const double noise[9] = {s2, 0, 0, 0, 0.5 * s2, 0, 0, 0, s2};
    vl_matmul(J, noise, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, J, C, 3, 3, 3);
}

/* ---------------------------------------------------------------- prediction */

static void propagate_to(vl_estimator_t *e, int64_t utime)
{
    const double tau = (double)(utime - e->state_utime) * 1e-6;
    if (tau <= 0.0) {
        return;
    }
    if (tau > e->cfg.max_propagation_dt) {
        e->counters.time_gaps++;
        log_msg(e, VL_LOG_WARN, utime, "long gap between inputs; propagating across it");
    }

    double u[6];
    for (int i = 0; i < 3; ++i) {
        u[i] = e->held_linear[i] - e->offset_linear[i];
        u[3 + i] = e->held_angular[i] - e->offset_angular[i];
    }
    double xi[6], dR[9], dp[3];
    for (int i = 0; i < 6; ++i) {
        xi[i] = tau * u[i];
    }
    vl_se3_exp(xi, dR, dp);

    {
        /* Phi = [[Ad(exp(-tau u)), -tau J_r(tau u)], [0, I]]; noise enters through -tau J_r. */
        double Rinv[9], pinv[3], Ad[36], Jr[36];
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                Rinv[3 * i + j] = dR[3 * j + i];
            }
        }
        vl_matmul(Rinv, dp, pinv, 3, 3, 1);
        for (int i = 0; i < 3; ++i) {
            pinv[i] = -pinv[i];
        }
        vl_se3_adjoint(Rinv, pinv, Ad);
        vl_se3_right_jacobian(xi, Jr);

        double Phi[144], Q[144];
        memset(Phi, 0, sizeof(Phi));
        memset(Q, 0, sizeof(Q));
        const int offsets = e->cfg.estimate_input_offsets;
        for (int i = 0; i < 6; ++i) {
            for (int j = 0; j < 6; ++j) {
                Phi[12 * i + j] = Ad[6 * i + j];
                Phi[12 * i + 6 + j] = offsets ? -tau * Jr[6 * i + j] : 0.0;
            }
            Phi[12 * (6 + i) + 6 + i] = 1.0;
        }
        const double sv2 = e->cfg.linear_velocity_noise * e->cfg.linear_velocity_noise;
        const double sw2 = e->cfg.angular_velocity_noise * e->cfg.angular_velocity_noise;
        /* Q_pose = tau^2 J_r diag(sv2, sw2) J_r^T */
        for (int i = 0; i < 6; ++i) {
            for (int j = 0; j < 6; ++j) {
                double acc = 0.0;
                for (int k = 0; k < 6; ++k) {
                    acc += Jr[6 * i + k] * Jr[6 * j + k] * (k < 3 ? sv2 : sw2);
                }
                Q[12 * i + j] = tau * tau * acc;
            }
        }
        if (offsets) {
            const double qv = e->cfg.linear_offset_walk * e->cfg.linear_offset_walk * tau;
            const double qw = e->cfg.angular_offset_walk * e->cfg.angular_offset_walk * tau;
            for (int i = 0; i < 3; ++i) {
                Q[12 * (6 + i) + 6 + i] = qv;
                Q[12 * (9 + i) + 9 + i] = qw;
            }
        }
        vl_la_propagate_core(e->P, LD, (int)vl_state_dim(e), Phi, Q);
    }

    /* T <- T exp(tau u) */
    double Rn[9], t[3];
    vl_matmul(e->R, dR, Rn, 3, 3, 3);
    vl_matmul(e->R, dp, t, 3, 3, 1);
    memcpy(e->R, Rn, sizeof(Rn));
    vl_so3_normalize(e->R);
    for (int i = 0; i < 3; ++i) {
        e->p[i] += t[i];
    }
    e->state_utime = utime;
}

/* ---------------------------------------------------------------- window */

static int find_slot(const vl_estimator_t *e, int32_t id)
{
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        if (e->slots[s].id == id) {
            return (int)s;
        }
    }
    return -1;
}

static void landmark_output(const vl_estimator_t *e, uint32_t slot, vl_landmark_t *out)
{
    const vl_landmark_slot_t *s = &e->slots[slot];
    double dpw[9], Pll[9], tmp[9];
    landmark_world_point(e, slot, out->position, dpw);
    const uint32_t c = landmark_col(slot);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Pll[3 * i + j] = e->P[(size_t)(c + j) * LD + (c + i)];
        }
    }
    vl_matmul(dpw, Pll, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, dpw, out->covariance, 3, 3, 3);
    out->id = s->id;
    out->observations = s->observations;
    out->first_utime = s->first_utime;
    out->last_utime = s->last_utime;
}

/* Hands the landmark to the map and drops its rows and columns (exact marginal). */
static void marginalize_slot(vl_estimator_t *e, uint32_t slot)
{
    if (e->cfg.landmark_sink != NULL) {
        vl_landmark_t lm;
        landmark_output(e, slot, &lm);
        e->cfg.landmark_sink(e->cfg.landmark_sink_user, &lm);
    }
    const uint32_t last = e->num_landmarks - 1u;
    if (slot != last) {
        vl_la_move_block(e->P, LD, (int)vl_state_dim(e), (int)landmark_col(slot), (int)landmark_col(last));
        e->slots[slot] = e->slots[last];
        memcpy(&e->landmark_state[3 * slot], &e->landmark_state[3 * last], 3 * sizeof(double));
        e->work_seen[slot] = e->work_seen[last];
    }
    e->num_landmarks--;
    e->counters.landmarks_marginalized++;
}

/* ---------------------------------------------------------------- initialization */

/*
 * Admits a landmark from one stereo observation y (compressed). The new block
 * gets its exact first-order covariance and cross-covariance to every state
 * through the pose: lambda = g(T exp(xi), y).
 */
static void admit_landmark(vl_estimator_t *e, int32_t id, const double y[3])
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3], c[3], dc_dy[9], b[3], d[3];
    camera_extrinsics(cal, Rc, tc);
    vl_stereo_triangulate(cal, y, c, dc_dy);
    for (int i = 0; i < 3; ++i) {
        d[i] = c[i] - tc[i];
    }
    vl_matmul_at(Rc, d, b, 3, 3, 1); /* b = Rc^T (c - tc), the point in the IMU frame */

    const uint32_t slot = e->num_landmarks;
    vl_landmark_slot_t *s = &e->slots[slot];
    double *lam = &e->landmark_state[3 * slot];
    double J_pose[18], J_obs[9], odot[18];
    vl_circle_dot(b, odot); /* d (exp(xi) b) / d xi at xi = 0 */

    if (e->cfg.landmark_param == VL_LANDMARK_XYZ) {
        double Rb[3], RRc[9];
        vl_matmul(e->R, b, Rb, 3, 3, 1);
        for (int i = 0; i < 3; ++i) {
            lam[i] = Rb[i] + e->p[i];
        }
        vl_matmul(e->R, odot, J_pose, 3, 3, 6);
        vl_matmul_bt(e->R, Rc, RRc, 3, 3, 3); /* R Rc^T */
        vl_matmul(RRc, dc_dy, J_obs, 3, 3, 3);
    } else {
        /* Anchor: the left camera at admission, w_T_cam = T inverse(cam_T_imu). */
        double RcT_tc[3];
        vl_matmul_bt(e->R, Rc, s->anchor_R, 3, 3, 3);
        vl_matmul_at(Rc, tc, RcT_tc, 3, 3, 1);
        double RR[3];
        vl_matmul(e->R, RcT_tc, RR, 3, 3, 1);
        for (int i = 0; i < 3; ++i) {
            s->anchor_p[i] = e->p[i] - RR[i];
        }
        const double z = c[2];
        lam[0] = c[0] / z;
        lam[1] = c[1] / z;
        lam[2] = 1.0 / z;
        const double dl_dc[9] = {1.0 / z, 0.0, -c[0] / (z * z), 0.0, 1.0 / z, -c[1] / (z * z),
                                 0.0,     0.0, -1.0 / (z * z)};
        double Rc_odot[18];
        vl_matmul(Rc, odot, Rc_odot, 3, 3, 6);
        vl_matmul(dl_dc, Rc_odot, J_pose, 3, 3, 6);
        vl_matmul(dl_dc, dc_dy, J_obs, 3, 3, 3);
    }
    if (e->cfg.mode == VL_MODE_MAPPING) {
        /* Mapping treats the trajectory as known: no pose uncertainty, no correlation. */
        memset(J_pose, 0, sizeof(J_pose));
    }
    const double s2 = e->cfg.pixel_noise * e->cfg.pixel_noise;
    const double noise[3] = {s2, 0.5 * s2, s2};
    vl_la_append_landmark(e->P, LD, (int)vl_state_dim(e), J_pose, J_obs, noise);

    s->id = id;
    s->observations = 1;
    s->unseen_frames = 0;
    s->first_utime = e->state_utime;
    s->last_utime = e->state_utime;
    e->work_seen[slot] = 1;
    e->num_landmarks++;
    e->counters.landmarks_initialized++;
    if (e->num_landmarks > e->counters.window_peak) {
        e->counters.window_peak = e->num_landmarks;
    }
}

/* ---------------------------------------------------------------- pending tracks */

static vl_pending_track_t *pending_touch(vl_estimator_t *e, int32_t id, int *duplicate)
{
    *duplicate = 0;
    for (uint32_t i = 0; i < e->num_pending; ++i) {
        vl_pending_track_t *t = &e->pending[i];
        if (t->id == id) {
            if (t->last_frame == e->frame_index) {
                *duplicate = 1;
                return t;
            }
            t->frames_seen++;
            t->last_frame = e->frame_index;
            return t;
        }
    }
    if (e->num_pending >= VL_MAX_PENDING) {
        return NULL;
    }
    vl_pending_track_t *t = &e->pending[e->num_pending++];
    t->id = id;
    t->frames_seen = 1;
    t->last_frame = e->frame_index;
    return t;
}

/* Keeps only candidates seen in this frame: tracks have no gaps, an unseen one has ended. */
static void pending_compact(vl_estimator_t *e)
{
    uint32_t out = 0;
    for (uint32_t i = 0; i < e->num_pending; ++i) {
        if (e->pending[i].last_frame == e->frame_index && e->pending[i].id >= 0) {
            e->pending[out++] = e->pending[i];
        }
    }
    e->num_pending = out;
}

/* ---------------------------------------------------------------- public API */

vl_status_t vl_init(vl_estimator_t *e, const vl_config_t *cfg)
{
    if (e == NULL || cfg == NULL) {
        return VL_ERR_NULL;
    }
    vl_status_t st = vl_config_check(cfg);
    if (st != VL_OK) {
        return st;
    }
    vl_la_configure();
    memset(e, 0, offsetof(vl_estimator_t, P));
    e->cfg = *cfg;
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(e->R, I3, sizeof(I3));
    /* Only the leading 12 x 12 block is live at start; the rest is written as landmarks arrive. */
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        memset(&e->P[(size_t)j * LD], 0, VL_CORE_DIM * sizeof(double));
    }
    if (cfg->estimate_input_offsets) {
        for (int i = 0; i < 3; ++i) {
            *P_at(e, IDX_OFFSET_LIN + i, IDX_OFFSET_LIN + i) = cfg->linear_offset_prior * cfg->linear_offset_prior;
            *P_at(e, IDX_OFFSET_ANG + i, IDX_OFFSET_ANG + i) = cfg->angular_offset_prior * cfg->angular_offset_prior;
        }
    }
    e->initialized = 1;
    return VL_OK;
}

vl_status_t vl_propagate(vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    if (e == NULL || imu == NULL) {
        return VL_ERR_NULL;
    }
    if (!e->initialized) {
        return VL_ERR_NOT_READY;
    }
    if (!all_finite(imu->linear_velocity, 3) || !all_finite(imu->angular_velocity, 3)) {
        e->counters.imu_rejected++;
        log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample with NaN or infinity rejected");
        return VL_ERR_NON_FINITE;
    }
    if (e->have_imu && (imu->utime <= e->last_imu_utime || imu->utime < e->state_utime)) {
        e->counters.imu_rejected++;
        log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample out of time order rejected");
        return VL_ERR_TIME_ORDER;
    }
    if (e->have_imu) {
        propagate_to(e, imu->utime);
    } else {
        e->state_utime = imu->utime;
        e->have_imu = 1;
    }
    memcpy(e->held_linear, imu->linear_velocity, sizeof(e->held_linear));
    memcpy(e->held_angular, imu->angular_velocity, sizeof(e->held_angular));
    e->last_imu_utime = imu->utime;
    e->counters.imu_accepted++;
    return VL_OK;
}

/* Observation validity before any use: finite pixels, a real id, positive disparity. */
static int observation_valid(const vl_stereo_obs_t *o)
{
    return o->id >= 0 && isfinite(o->u_left) && isfinite(o->v_left) && isfinite(o->u_right) &&
           isfinite(o->v_right);
}

static double depth_of(const vl_calibration_t *cal, double disparity)
{
    return cal->fx * cal->baseline / disparity;
}

/*
 * Does a candidate's observation agree with the point its previous observation
 * gave? The comparison allows for that point's pixel noise, one step of motion
 * noise (dt seconds) and this observation's noise: the same gate as updates.
 */
static int track_consistent(const vl_estimator_t *e, const vl_pending_track_t *t, const double y[3], double dt)
{
    if (e->cfg.gate_chi2 <= 0.0) {
        return 1;
    }
    double y_pred[3], Hp[18], Hx[9];
    if (project_world_point(e, t->point, y_pred, Hp, Hx) != 0) {
        return 0;
    }
    const double sv2 = e->cfg.linear_velocity_noise * e->cfg.linear_velocity_noise * dt * dt;
    const double sw2 = e->cfg.angular_velocity_noise * e->cfg.angular_velocity_noise * dt * dt;
    const double s2 = e->cfg.pixel_noise * e->cfg.pixel_noise;
    double S[9], tmp[9], HQ[18];
    vl_matmul(Hx, t->covariance, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, Hx, S, 3, 3, 3);
    for (int r = 0; r < 3; ++r) {
        for (int j = 0; j < 6; ++j) {
            HQ[6 * r + j] = Hp[6 * r + j] * (j < 3 ? sv2 : sw2);
        }
    }
    double HQH[9];
    vl_matmul_bt(HQ, Hp, HQH, 3, 6, 3);
    for (int i = 0; i < 9; ++i) {
        S[i] += HQH[i];
    }
    S[0] += s2;
    S[4] += 0.5 * s2;
    S[8] += s2;
    const double r[3] = {y[0] - y_pred[0], y[1] - y_pred[1], y[2] - y_pred[2]};
    return mahalanobis3(S, r) <= e->cfg.gate_chi2;
}

/* Candidate for admission, ordered by score. */
typedef struct {
    uint32_t obs;
    double score;
} candidate_t;

vl_status_t vl_update(vl_estimator_t *e, const vl_stereo_frame_t *frame)
{
    if (e == NULL || frame == NULL) {
        return VL_ERR_NULL;
    }
    if (!e->initialized || !e->have_imu) {
        if (e->initialized) {
            e->counters.frames_rejected++;
        }
        return VL_ERR_NOT_READY;
    }
    if (frame->utime < e->state_utime || (e->counters.frames_accepted > 0 && frame->utime <= e->last_frame_utime)) {
        e->counters.frames_rejected++;
        log_msg(e, VL_LOG_WARN, frame->utime, "frame out of time order rejected");
        return VL_ERR_TIME_ORDER;
    }
    vl_status_t result = VL_OK;
    uint32_t count = frame->count;
    e->counters.observations_received += count;
    if (count > VL_MAX_FRAME_FEATURES) {
        e->counters.frames_truncated++;
        e->counters.observations_truncated += count - VL_MAX_FRAME_FEATURES;
        log_msg(e, VL_LOG_WARN, frame->utime, "frame over VL_MAX_FRAME_FEATURES truncated");
        count = VL_MAX_FRAME_FEATURES;
        result = VL_FRAME_TRUNCATED;
    }

    propagate_to(e, frame->utime);
    const double frame_dt = (e->counters.frames_accepted > 0) ? (double)(frame->utime - e->last_frame_utime) * 1e-6 : 0.0;
    e->last_frame_utime = frame->utime;
    e->frame_index++;
    e->counters.frames_accepted++;

    if (e->cfg.mode == VL_MODE_IMU_ONLY) {
        return result;
    }

    const vl_calibration_t *cal = &e->cfg.calibration;
    memset(e->work_seen, 0, sizeof(e->work_seen));

    /* 1. Observations of window landmarks become update rows; the rest are candidates. */
    vl_la_obs_t *rows = e->work_rows;
    uint32_t k = 0;
    candidate_t candidates[VL_MAX_FRAME_FEATURES];
    uint32_t num_candidates = 0;
    const double s2 = e->cfg.pixel_noise * e->cfg.pixel_noise;

    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        if (!observation_valid(o)) {
            e->counters.observations_invalid++;
            continue;
        }
        const double disparity = o->u_left - o->u_right;
        const int slot = find_slot(e, o->id);
        if (slot >= 0) {
            if (e->work_seen[slot]) {
                e->counters.observations_invalid++; /* the same id twice in one frame */
                continue;
            }
            e->work_seen[slot] = 1;
            vl_landmark_slot_t *s = &e->slots[slot];
            s->unseen_frames = 0;
            s->last_utime = frame->utime;
            s->observations++;
            if (!(disparity > 0.0)) {
                e->counters.observations_low_disparity++;
                continue;
            }
            vl_la_obs_t *row = &rows[k];
            double y_pred[3], y[3];
            if (predict_observation(e, (uint32_t)slot, y_pred, row->H_pose, row->H_landmark) != 0) {
                e->counters.observations_gated++;
                continue;
            }
            vl_stereo_compress(o, y);
            for (int r = 0; r < 3; ++r) {
                row->residual[r] = y[r] - y_pred[r];
            }
            row->noise_var[0] = s2;
            row->noise_var[1] = 0.5 * s2;
            row->noise_var[2] = s2;
            row->landmark_col = (int)landmark_col((uint32_t)slot);
            if (e->cfg.mode == VL_MODE_MAPPING) {
                memset(row->H_pose, 0, sizeof(row->H_pose));
            }
            if (e->cfg.gate_chi2 > 0.0) {
                double S[9];
                vl_la_obs_covariance(e->P, LD, row, S);
                if (!(mahalanobis3(S, row->residual) <= e->cfg.gate_chi2)) {
                    e->counters.observations_gated++;
                    continue;
                }
            }
            e->work_frame_obs[k] = i;
            k++;
        } else {
            int duplicate = 0;
            vl_pending_track_t *t = pending_touch(e, o->id, &duplicate);
            if (duplicate) {
                e->counters.observations_invalid++;
                continue;
            }
            if (!(disparity >= e->cfg.min_disparity) || depth_of(cal, disparity) > e->cfg.max_depth) {
                e->counters.observations_low_disparity++;
                if (t != NULL) {
                    t->frames_seen = 0; /* no usable point to compare the next observation with */
                }
                continue;
            }
            if (t == NULL) {
                continue; /* pending table full: the track is retried next frame */
            }
            double y[3], pw[3], C[9];
            vl_stereo_compress(o, y);
            if (t->frames_seen >= 2 && !track_consistent(e, t, y, frame_dt)) {
                e->counters.tracks_inconsistent++;
                t->frames_seen = 1;
            }
            triangulate_world(e, y, pw, C);
            memcpy(t->point, pw, sizeof(pw));
            memcpy(t->covariance, C, sizeof(C));
            if (t->frames_seen < e->cfg.min_track_length) {
                continue;
            }
            /* Larger disparity (nearer, better conditioned) and longer tracks go first. */
            const uint32_t age = t->frames_seen - 1u;
            candidates[num_candidates].obs = i;
            candidates[num_candidates].score = disparity * (1.0 + 0.5 * (double)(age < 4u ? age : 4u));
            num_candidates++;
        }
    }

    /* 2. Joint update. */
    if (k > 0) {
        vl_la_workspace_t ws = {e->work_PHt, e->work_S, e->work_dx};
        const uint32_t n = vl_state_dim(e);
        if (vl_la_update(e->P, LD, (int)n, rows, (int)k, &ws) != 0) {
            e->counters.numerical_failures++;
            log_msg(e, VL_LOG_ERROR, frame->utime, "innovation covariance not positive definite; update refused");
            result = VL_ERR_NOT_POSITIVE_DEFINITE;
        } else if (!all_finite(e->work_dx, (int)n)) {
            e->counters.numerical_failures++;
            result = VL_ERR_NOT_POSITIVE_DEFINITE;
        } else {
            double dR[9], dp[3], Rn[9], t[3];
            vl_se3_exp(e->work_dx, dR, dp);
            vl_matmul(e->R, dR, Rn, 3, 3, 3);
            vl_matmul(e->R, dp, t, 3, 3, 1);
            memcpy(e->R, Rn, sizeof(Rn));
            vl_so3_normalize(e->R);
            for (int i = 0; i < 3; ++i) {
                e->p[i] += t[i];
                e->offset_linear[i] += e->work_dx[IDX_OFFSET_LIN + i];
                e->offset_angular[i] += e->work_dx[IDX_OFFSET_ANG + i];
            }
            for (uint32_t j = VL_CORE_DIM; j < n; ++j) {
                e->landmark_state[j - VL_CORE_DIM] += e->work_dx[j];
            }
            e->counters.observations_used += k;
        }
    }

    /* 3. Tracks that ended leave the window for the map. Walk down: marginalizing
     * moves the last slot into the freed one. */
    for (uint32_t s = e->num_landmarks; s-- > 0;) {
        if (e->work_seen[s]) {
            continue;
        }
        if (++e->slots[s].unseen_frames > e->cfg.max_unseen_frames) {
            marginalize_slot(e, s);
        }
    }

    /* 4. Admissions, best first; room is made only from landmarks not seen now. */
    for (uint32_t i = 1; i < num_candidates; ++i) {
        candidate_t c = candidates[i];
        uint32_t j = i;
        while (j > 0 && candidates[j - 1].score < c.score) {
            candidates[j] = candidates[j - 1];
            --j;
        }
        candidates[j] = c;
    }
    for (uint32_t i = 0; i < num_candidates; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[candidates[i].obs];
        if (e->num_landmarks >= e->cfg.max_landmarks) {
            int victim = -1;
            uint32_t longest = 0;
            for (uint32_t s = 0; s < e->num_landmarks; ++s) {
                if (!e->work_seen[s] && e->slots[s].unseen_frames >= longest) {
                    longest = e->slots[s].unseen_frames;
                    victim = (int)s;
                }
            }
            if (victim < 0) {
                e->counters.landmarks_deferred += num_candidates - i;
                break;
            }
            marginalize_slot(e, (uint32_t)victim);
            e->counters.landmarks_evicted++;
        }
        double y[3];
        vl_stereo_compress(o, y);
        admit_landmark(e, o->id, y);
        /* An admitted id leaves the pending table. */
        for (uint32_t p = 0; p < e->num_pending; ++p) {
            if (e->pending[p].id == o->id) {
                e->pending[p].id = -1;
                break;
            }
        }
    }
    pending_compact(e);
    return result;
}

vl_status_t vl_get_pose(const vl_estimator_t *e, vl_pose_t *out)
{
    if (e == NULL || out == NULL) {
        return VL_ERR_NULL;
    }
    if (!e->initialized) {
        return VL_ERR_NOT_READY;
    }
    out->utime = e->state_utime;
    memcpy(out->rotation, e->R, sizeof(e->R));
    memcpy(out->position, e->p, sizeof(e->p));
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            out->covariance[6 * i + j] = e->P[(size_t)j * LD + i];
        }
    }
    for (int i = 0; i < 3; ++i) {
        out->linear_velocity[i] = e->held_linear[i] - e->offset_linear[i];
        out->angular_velocity[i] = e->held_angular[i] - e->offset_angular[i];
        out->linear_offset[i] = e->offset_linear[i];
        out->angular_offset[i] = e->offset_angular[i];
    }
    return VL_OK;
}

vl_status_t vl_get_landmarks(const vl_estimator_t *e, vl_landmark_t *out, size_t capacity, size_t *count)
{
    if (e == NULL || count == NULL || (out == NULL && capacity > 0)) {
        return VL_ERR_NULL;
    }
    *count = e->num_landmarks;
    const size_t n = (capacity < e->num_landmarks) ? capacity : e->num_landmarks;
    for (size_t s = 0; s < n; ++s) {
        landmark_output(e, (uint32_t)s, &out[s]);
    }
    return (capacity < e->num_landmarks) ? VL_ERR_CAPACITY : VL_OK;
}

vl_status_t vl_flush_landmarks(vl_estimator_t *e)
{
    if (e == NULL) {
        return VL_ERR_NULL;
    }
    /* Marginalize from the end so no block moves. */
    while (e->num_landmarks > 0) {
        marginalize_slot(e, e->num_landmarks - 1u);
    }
    return VL_OK;
}

const vl_counters_t *vl_get_counters(const vl_estimator_t *e)
{
    return (e != NULL) ? &e->counters : NULL;
}

uint32_t vl_window_size(const vl_estimator_t *e)
{
    return (e != NULL) ? e->num_landmarks : 0u;
}

uint32_t vl_state_dim(const vl_estimator_t *e)
{
    return (e != NULL) ? VL_CORE_DIM + 3u * e->num_landmarks : 0u;
}
