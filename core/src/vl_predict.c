/*
 * Prediction on SE(3): T <- T exp(tau (u - b)) with u the velocity over the
 * interval and b the estimated offsets. In invariant error coordinates the error
 * does not move (Phi = I) except through the input noise and the offset error.
 */
#include "vl_predict.h"

#include <string.h>

#include "vl_estimator_internal.h"
#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_work.h"

/*
 * Moves the state to utime with the velocity u = (lin, ang) over the interval.
 * noise_share scales the input noise: the variance of u in units of one
 * sample's variance (1 for a held sample).
 */
static void predict_with(vl_estimator_t *e, int64_t utime, const double lin[3], const double ang[3], double noise_share)
{
    const double tau = (double)vl_utime_diff(utime, e->state_utime) * 1e-6;
    if (tau <= 0.0) {
        return;
    }
    if (tau > e->cfg.max_propagation_dt) {
        e->counters.time_gaps++;
        vl_log_msg(e, VL_LOG_WARN, utime, "long gap between inputs; propagating across it");
    }

    double xi[6], dR[9], dp[3];
    for (int i = 0; i < 3; ++i) {
        xi[i] = tau * (lin[i] - e->offset_linear[i]);
        xi[3 + i] = tau * (ang[i] - e->offset_angular[i]);
    }
    vl_se3_exp(xi, dR, dp);

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

    /*
     * Input noise n and offset error db both act as u -> u - n - db, which moves
     * the pose error by G (n + db) with G = -tau Ad(T_new) J_r(tau u), and each
     * landmark error by hat(l_i) times its rotation rows (the world turns under
     * the landmarks, which stay put).
     */
    double Ad[36], Jr[36], Gp[36];
    vl_se3_adjoint(e->R, e->p, Ad);
    vl_se3_right_jacobian(xi, Jr);
    vl_matmul(Ad, Jr, Gp, 6, 6, 6);
    for (int i = 0; i < 36; ++i) {
        Gp[i] *= -tau;
    }
    const uint32_t n = vl_state_dim(e);
    vl_work_predict(e, n, e->cfg.estimate_input_offsets);
    double *G = e->work_PHt; /* n x 6, column-major; the update workspace is free here */
    for (int j = 0; j < 6; ++j) {
        double *col = &G[(size_t)j * n];
        for (int i = 0; i < 6; ++i) {
            col[i] = Gp[6 * i + j];
            col[6 + i] = 0.0;
        }
        const double *phi_rows = &Gp[6 * VL_IDX_PHI + j]; /* column j of the rotation rows, stride 6 */
        const double psi[3] = {phi_rows[0], phi_rows[6], phi_rows[12]};
        for (uint32_t s = 0; s < e->num_landmarks; ++s) {
            double *g = &col[vl_landmark_col(s)];
            if (e->cfg.mode == VL_MODE_MAPPING) {
                g[0] = g[1] = g[2] = 0.0; /* the trajectory is taken as known */
                continue;
            }
            const double *l = vl_landmark_point(e, s);
            g[0] = l[1] * psi[2] - l[2] * psi[1];
            g[1] = l[2] * psi[0] - l[0] * psi[2];
            g[2] = l[0] * psi[1] - l[1] * psi[0];
        }
    }
    const double sv2 = e->linear_velocity_var * noise_share;
    const double sw2 = e->angular_velocity_var * noise_share;
    const double noise_var[6] = {sv2, sv2, sv2, sw2, sw2, sw2};
    const double qv = e->cfg.linear_offset_walk * e->cfg.linear_offset_walk * tau;
    const double qw = e->cfg.angular_offset_walk * e->cfg.angular_offset_walk * tau;
    const double offset_var[6] = {qv, qv, qv, qw, qw, qw};
    vl_la_propagate(e->P, VL_LD, (int)n, G, noise_var, e->cfg.estimate_input_offsets ? offset_var : NULL,
                    e->work_PHt + (size_t)6 * n);
}

/* Without a trusted sample there is no motion to integrate: the clock moves alone. */
static int skip_untrusted(vl_estimator_t *e, int64_t utime)
{
    if (e->held_trusted) {
        return 0;
    }
    if (vl_utime_diff(utime, e->state_utime) > 0) {
        e->state_utime = utime;
    }
    return 1;
}

void vl_predict_to(vl_estimator_t *e, int64_t utime)
{
    if (!skip_untrusted(e, utime)) {
        predict_with(e, utime, e->held_linear, e->held_angular, 1.0);
    }
}

/*
 * An instantaneous sample pins the velocity at its time; between two samples it
 * is taken as linear. The pose integrates that line's mean over what is left of
 * the interval, the line at the middle of [state_utime, imu->utime] (on a
 * sample-to-sample interval: the trapezoid rule, (u_prev + u_new) / 2). The
 * mean of two independent samples with weights (1 - w, w) has (1 - w)^2 + w^2
 * of one sample's variance (that neighbouring intervals share a sample is not
 * modelled).
 */
void vl_predict_to_sample(vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    if (!e->cfg.interpolate_velocities) {
        vl_predict_to(e, imu->utime); /* the held sample */
        return;
    }
    if (skip_untrusted(e, imu->utime)) {
        return;
    }
    const double span = (double)vl_utime_diff(imu->utime, e->last_imu_utime);
    const double middle = 0.5 * (double)(vl_utime_diff(e->state_utime, e->last_imu_utime) + span);
    const double w = span > 0.0 ? middle / span : 1.0;
    double lin[3], ang[3];
    for (int i = 0; i < 3; ++i) {
        lin[i] = e->held_linear[i] + w * (imu->linear_velocity[i] - e->held_linear[i]);
        ang[i] = e->held_angular[i] + w * (imu->angular_velocity[i] - e->held_angular[i]);
    }
    const double share = (1.0 - w) * (1.0 - w) + w * w;
    predict_with(e, imu->utime, lin, ang, share);
}
