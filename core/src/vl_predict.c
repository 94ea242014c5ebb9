/*
 * Prediction on SE(3): T <- T exp(tau (u - b)) with u the velocity over the
 * interval and b the estimated offsets. In invariant error coordinates the error
 * does not move (Phi = I) except through the input noise and the offset error.
 * A step moves the mean and P's core block (pose and offsets) at once; its
 * effect on the landmark rows waits in e->deferred until vl_predict_settle.
 */
#include "vl_predict.h"

#include <math.h>
#include <string.h>

#include "vl_estimator_internal.h"
#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_update.h"
#include "vl_work.h"

/*
 * T <- T exp(xi), xi = tau u, with the input's noise (variance per axis of u)
 * and, when coupled, the parameters' error coupled in and the offsets walking
 * (offset_var, NULL when they are not estimated). Input noise n and offset
 * error db both act as u -> u - n - db, which moves the pose error by G (n + db)
 * with G = -tau Ad(T_new) J_r(tau u), and each landmark error by hat(l_i) times
 * its rotation rows (the world turns under the landmarks, which stay put). An
 * error ds of the velocity sensor's position leaves the sensor's velocity
 * wrongly corrected by w x ds: the body twist moves by -hat(w) ds on its linear
 * rows, and the pose error by G's linear columns times hat(w) ds.
 */
static void advance(vl_estimator_t *e, int64_t utime, double tau, const double xi[6], const double noise_var[6],
                    int coupled, const double offset_var[6], const double sensor_skew[9])
{
    double dR[9], dp[3], Rn[9], t[3];
    vl_se3_exp(xi, dR, dp);
    vl_matmul(e->R, dR, Rn, 3, 3, 3);
    vl_matmul(e->R, dp, t, 3, 3, 1);
    memcpy(e->R, Rn, sizeof(Rn));
    vl_so3_normalize(e->R);
    for (int i = 0; i < 3; ++i) {
        e->p[i] += t[i];
    }
    e->state_utime = utime;

    double Ad[36], Jr[36], Gp[36];
    vl_se3_adjoint(e->R, e->p, Ad);
    vl_se3_right_jacobian(xi, Jr);
    vl_matmul(Ad, Jr, Gp, 6, 6, 6);
    for (int i = 0; i < 36; ++i) {
        Gp[i] *= -tau;
    }
    /* The parameters' columns (6 x VL_PARAM_DIM, row-major): the offsets', then the sensor position's. */
    double Gt[6 * VL_PARAM_DIM] = {0};
    if (coupled && vl_predict_sensor_estimated(e)) {
        double W[9];
        const double w[3] = {xi[3] / tau, xi[4] / tau, xi[5] / tau};
        vl_skew(w, W);
        for (int i = 0; i < 6; ++i) {
            for (int j = 0; j < 3; ++j) {
                double v = 0.0;
                for (int k = 0; k < 3; ++k) {
                    v += Gp[6 * i + k] * W[3 * k + j];
                }
                Gt[VL_PARAM_DIM * i + 6 + j] = v;
            }
        }
    }
    if (sensor_skew != NULL) {
        /* The body twist is T (u - n - db) with T = [I hat(p); 0 I]: G becomes G T, so the
         * angular noise and offsets reach the linear velocity through the lever arm. */
        for (int i = 0; i < 6; ++i) {
            double add[3] = {0.0, 0.0, 0.0};
            for (int j = 0; j < 3; ++j) {
                for (int k = 0; k < 3; ++k) {
                    add[j] += Gp[6 * i + k] * sensor_skew[3 * k + j];
                }
            }
            for (int j = 0; j < 3; ++j) {
                Gp[6 * i + 3 + j] += add[j];
            }
        }
    }
    if (coupled && offset_var != NULL) {
        for (int i = 0; i < 6; ++i) {
            memcpy(&Gt[VL_PARAM_DIM * i], &Gp[6 * i], 6 * sizeof(double));
        }
    }
    /* The offsets' correlations fade over offset_correlation_time (vl_la_propagate). */
    const double tc = e->cfg.offset_correlation_time;
    const double decay = (coupled && offset_var != NULL && tc > 0.0) ? exp(-tau / tc) : 1.0;
    vl_work_predict(e, coupled, decay != 1.0);
    vl_predict_defer(e, Gp, coupled ? Gt : NULL, noise_var, offset_var, decay);
}

/*
 * Moves the state to utime with the velocity u = (lin, ang) over the interval,
 * less the estimated offsets. noise_share scales the input noise: the variance
 * of u in units of one sample's variance (1 for a held sample).
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
    double xi[6];
    for (int i = 0; i < 3; ++i) {
        xi[i] = tau * (lin[i] - e->offset_linear[i]);
        xi[3 + i] = tau * (ang[i] - e->offset_angular[i]);
    }
    double S[9], turn[3];
    const int lever = vl_predict_lever_term(e, &xi[3], turn, S);
    if (lever) {
        for (int i = 0; i < 3; ++i) {
            xi[i] += turn[i]; /* tau (v - w x p) */
        }
    }
    const double sv2 = e->linear_velocity_var * noise_share;
    const double sw2 = e->angular_velocity_var * noise_share;
    const double noise_var[6] = {sv2, sv2, sv2, sw2, sw2, sw2};
    e->step_noise_time2 += tau * tau * noise_share;
    e->step_time += tau;
    const double qv = e->cfg.linear_offset_walk * e->cfg.linear_offset_walk * tau;
    const double qw = e->cfg.angular_offset_walk * e->cfg.angular_offset_walk * tau;
    const double offset_var[6] = {qv, qv, qv, qw, qw, qw};
    for (int i = 0; i < 3; ++i) {
        e->step_turn[i] += xi[3 + i];
    }
    const int offsets = e->cfg.estimate_input_offsets;
    advance(e, utime, tau, xi, noise_var, offsets || vl_predict_sensor_estimated(e), offsets ? offset_var : NULL,
            lever ? S : NULL);
}

int vl_predict_sensor_estimated(const vl_estimator_t *e)
{
    return e->cfg.velocity_sensor_std_x > 0.0 || e->cfg.velocity_sensor_std_y > 0.0 ||
           e->cfg.velocity_sensor_std_z > 0.0;
}

int vl_predict_sensor_skew(const vl_estimator_t *e, double skew[9])
{
    const double *p = e->sensor_position;
    if (p[0] == 0.0 && p[1] == 0.0 && p[2] == 0.0) {
        return 0;
    }
    vl_skew(p, skew);
    return 1;
}

int vl_predict_lever_term(const vl_estimator_t *e, const double w[3], double out[3], double skew[9])
{
    double S[9];
    if (!vl_predict_sensor_skew(e, skew != NULL ? skew : S)) {
        out[0] = out[1] = out[2] = 0.0;
        return 0;
    }
    vl_matmul(skew != NULL ? skew : S, w, out, 3, 3, 1);
    return 1;
}

/*
 * Between updates the landmarks do not move, so every step's G = B Gp with B
 * (n x 6) fixed: identity on the pose rows, zero on the parameters', hat(l_s)
 * times the rotation rows' selector on landmark s (zero when mapping), and so
 * is the parameters' map B Gt. As B has no parameter rows (E^T B = 0), with
 * U = [B, E] each step's Phi = I + B Gt E^T moves U within itself, Phi U = U F
 * with F = [I Gt; 0 I], and K steps give
 *   P_K = (I + U Y E^T) P_0 (I + U Y E^T)^T + U A U^T,
 * Y the parameter columns of F_K ... F_1 - I (here [sum Gt; 0]) and A the noise
 * G Q G^T and the offsets' walk propagated as the core block itself is, from
 * zero: the sequential recursion exactly, in exact arithmetic. So a step
 * propagates the core block, A and Y (O(1)); vl_predict_settle applies the rest.
 *
 * The offsets' decay a per step (their correlations fading, offset_correlation_time)
 * makes the parameters' transition diagonal, D = diag(a I6, I3), and fits the same
 * accumulators: F = [I Gt; 0 D], the core block and A propagate with it (with the
 * offsets' refill, vl_la_propagate), and Y <- (F (I + [0 Y])) - I in its parameter
 * columns, i.e. Y_pose += Gt (I + Y_param) and Y_param <- D (I + Y_param) - I;
 * vl_la_settle applies I + U Y E^T whatever Y's parameter rows hold.
 */
void vl_predict_defer(vl_estimator_t *e, const double Gp[36], const double Gt[6 * VL_PARAM_DIM],
                      const double noise_var[6], const double offset_var[6], double decay)
{
    vl_deferred_prediction_t *d = &e->deferred;
    if (d->steps == 0) {
        for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
            memcpy(&d->core0[VL_CORE_DIM * j], &e->P[(size_t)j * VL_LD], VL_CORE_DIM * sizeof(double));
        }
        memset(d->transition, 0, sizeof(d->transition));
        memset(d->noise, 0, sizeof(d->noise));
    }
    double R[36]; /* the offsets' block before the step, which the decay refills */
    for (uint32_t j = 0; j < 6 && decay != 1.0; ++j) {
        memcpy(&R[6 * j], &e->P[(size_t)(VL_IDX_OFFSET_LIN + j) * VL_LD + VL_IDX_OFFSET_LIN], 6 * sizeof(double));
    }
    vl_la_propagate(e->P, VL_LD, Gp, Gt, noise_var, offset_var, decay, R);
    vl_la_propagate(d->noise, VL_CORE_DIM, Gp, Gt, noise_var, offset_var, decay, R);
    if (Gt != NULL) {
        /* Y_pose += Gt (I + Y_param); Y_param <- D (I + Y_param) - I. */
        double *Y = d->transition;
        for (int j = 0; j < VL_PARAM_DIM; ++j) {
            for (int i = 0; i < 6; ++i) {
                double v = Gt[VL_PARAM_DIM * i + j];
                for (int k = 0; k < VL_PARAM_DIM; ++k) {
                    v += Gt[VL_PARAM_DIM * i + k] * Y[VL_CORE_DIM * j + 6 + k];
                }
                Y[VL_CORE_DIM * j + i] += v;
            }
        }
        for (int j = 0; j < VL_PARAM_DIM; ++j) {
            for (int k = 0; k < 6; ++k) { /* the offsets' rows */
                const double one = (k == j) ? 1.0 : 0.0;
                Y[VL_CORE_DIM * j + 6 + k] = decay * (one + Y[VL_CORE_DIM * j + 6 + k]) - one;
            }
        }
    }
    d->steps++;
}

void vl_predict_settle(vl_estimator_t *e)
{
    if (e->deferred.steps == 0) {
        return;
    }
    const uint32_t n = vl_state_dim(e);
    /* Mapping takes the trajectory as known: B's landmark rows are zero. */
    const int moving = e->cfg.mode != VL_MODE_MAPPING;
    vl_la_settle(e->P, VL_LD, (int)n, &e->deferred, moving ? e->landmark_state : NULL, e->work_PHt);
    vl_work_settle(e, n, moving);
    e->deferred.steps = 0;
}

void vl_predict_landmark_block(const vl_estimator_t *e, uint32_t slot, double B[36])
{
    const uint32_t c = vl_landmark_col(slot);
    const uint32_t idx[6] = {VL_IDX_PHI, VL_IDX_PHI + 1, VL_IDX_PHI + 2, c, c + 1, c + 2};
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            B[6 * i + j] = e->P[(size_t)idx[j] * VL_LD + idx[i]];
        }
    }
    if (e->pending_cols > 0) { /* between a frame's update and its downdate (no prediction is deferred then) */
        const vl_la_pending_t pending = vl_update_pending(e);
        double share[9];
        vl_la_pending_share(&pending, (int)c, share);
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                B[6 * (3 + i) + 3 + j] -= share[3 * j + i];
            }
        }
    }
    if (e->deferred.steps == 0) {
        return;
    }
    double cross[3 * VL_CORE_DIM], block[9];
    const double *point = e->cfg.mode != VL_MODE_MAPPING ? vl_landmark_point(e, slot) : NULL;
    vl_la_settled_landmark(e->P, VL_LD, (int)c, &e->deferred, point, cross, block);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            const double lr = cross[3 * (VL_IDX_PHI + j) + i]; /* landmark row i, rotation column j */
            B[6 * (3 + i) + j] = lr;
            B[6 * j + 3 + i] = lr;
            B[6 * (3 + i) + 3 + j] = block[3 * j + i];
        }
    }
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
 * Past max_imu_silence no sample says how the vehicle moves, and a stale one is
 * never integrated. The frames do: the motion between the last two (their
 * updated poses, e->frame_velocity) carries on at constant velocity, with three
 * times the sensor's noise per axis for what that guess misses (a change of
 * speed, the poses' own error), and the turn rate itself on the angular axes (a
 * turn may end within a frame). Without that motion (before two frames, or
 * outside slam mode, where the frames do not move the pose) the mean stays, and
 * the noise also covers the held sample's speed and turn rate. No input is
 * integrated, so the parameters do not couple in and the offsets do not walk
 * (seconds of their walk are nothing beside their prior).
 */
void vl_predict_silence_to(vl_estimator_t *e, int64_t utime)
{
    vl_predict_to(e, e->last_imu_utime + vl_limit_us(e->cfg.max_imu_silence));
    const double tau = (double)vl_utime_diff(utime, e->state_utime) * 1e-6;
    if (tau <= 0.0) {
        return;
    }
    double v = 3.0 * sqrt(e->linear_velocity_var), w = 3.0 * sqrt(e->angular_velocity_var), xi[6] = {0};
    if (e->have_frame_velocity) {
        for (int i = 0; i < 6; ++i) {
            xi[i] = tau * e->frame_velocity[i];
        }
        w += vl_norm3(&e->frame_velocity[3]); /* a turn may end at once */
    } else if (e->held_trusted) {
        v += vl_norm3(e->held_linear);
        w += vl_norm3(e->held_angular);
    }
    const double noise_var[6] = {v * v, v * v, v * v, w * w, w * w, w * w};
    advance(e, utime, tau, xi, noise_var, 0, NULL, NULL); /* the frames' own body velocity: no lever arm */
    e->unknown_motion = 1;
    e->unknown_motion_var[0] = v * v;
    e->unknown_motion_var[1] = w * w;
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
