/*
 * Prediction on SE(3): T <- T exp(tau (u - b)) with u the held velocities and b
 * their estimated offsets. In invariant error coordinates the error does not
 * move (Phi = I) except through the input noise and the offset error.
 */
#include "vl_predict.h"

#include <string.h>

#include "vl_estimator_internal.h"
#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_work.h"

void vl_predict_to(vl_estimator_t *e, int64_t utime)
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
        xi[i] = tau * (e->held_linear[i] - e->offset_linear[i]);
        xi[3 + i] = tau * (e->held_angular[i] - e->offset_angular[i]);
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
    const double sv2 = e->linear_velocity_var;
    const double sw2 = e->angular_velocity_var;
    const double noise_var[6] = {sv2, sv2, sv2, sw2, sw2, sw2};
    const double qv = e->cfg.linear_offset_walk * e->cfg.linear_offset_walk * tau;
    const double qw = e->cfg.angular_offset_walk * e->cfg.angular_offset_walk * tau;
    const double offset_var[6] = {qv, qv, qv, qw, qw, qw};
    vl_la_propagate(e->P, VL_LD, (int)n, G, noise_var, e->cfg.estimate_input_offsets ? offset_var : NULL,
                    e->work_PHt + (size_t)6 * n);
}
