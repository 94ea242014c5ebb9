/*
 * The update with the stereo camera model z = M pi(q), in the compressed form
 * y = [u_left, (v_left + v_right) / 2, u_right]. The row of landmark i is
 * A (rho_i - rho) with A = dy/dc Rc R^T: it does not depend on phi, so the
 * update cannot invent rotation information about the unobservable directions.
 */
#include "vl_update.h"

#include <string.h>

#include "vl_camera.h"
#include "vl_estimator_internal.h"
#include "vl_se3.h"
#include "vl_stereo.h"
#include "vl_window.h"
#include "vl_work.h"

/*
 * With b = R^T (l - p), to first order b = b_hat + R^T (rho_i - rho): the rows are
 * A = dy/dc Rc R^T on rho_i and -A on rho, and zero on phi.
 */
int vl_update_make_row(const vl_estimator_t *e, uint32_t slot, const vl_stereo_obs_t *o, vl_la_obs_t *row)
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3], b[3], c[3], dy_dc[9], y_pred[3], y[3], RcRt[9];
    vl_camera_extrinsics(cal, Rc, tc);
    if (vl_camera_point(e, Rc, tc, vl_landmark_point(e, slot), b, c) != 0) {
        return -1;
    }
    vl_stereo_project(cal, c, y_pred, dy_dc);
    vl_matmul_bt(Rc, e->R, RcRt, 3, 3, 3);
    vl_matmul(dy_dc, RcRt, row->H_landmark, 3, 3, 3);
    memset(row->H_pose, 0, sizeof(row->H_pose));
    if (e->cfg.mode != VL_MODE_MAPPING) {
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                row->H_pose[6 * i + VL_IDX_RHO + j] = -row->H_landmark[3 * i + j];
            }
        }
    }
    vl_stereo_compress(o, y);
    for (int r = 0; r < 3; ++r) {
        row->residual[r] = y[r] - y_pred[r];
    }
    vl_stereo_noise_var(e->pixel_var, row->noise_var);
    row->landmark_col = (int)vl_landmark_col(slot);
    return 0;
}

void vl_rows_swap(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t a, uint32_t b)
{
    if (a == b) {
        return;
    }
    vl_la_obs_t t = rows[a];
    rows[a] = rows[b];
    rows[b] = t;
    uint32_t s = e->work_slot[a];
    e->work_slot[a] = e->work_slot[b];
    e->work_slot[b] = s;
    uint32_t f = e->work_frame_obs[a];
    e->work_frame_obs[a] = e->work_frame_obs[b];
    e->work_frame_obs[b] = f;
}

/* The most observations whose joint update on n states fits mflop (the cost grows with the
 * count), but never none: a frame always corrects the state. */
static uint32_t rows_fitting(uint32_t n, double mflop)
{
    const double budget = mflop * 1e6;
    uint32_t k = 1;
    while (k < VL_MAX_FRAME_FEATURES && (double)vl_work_joint_update(n, k + 1u) <= budget) {
        ++k;
    }
    return k;
}

uint32_t vl_rows_cap(const vl_estimator_t *e)
{
    uint32_t cap = e->cfg.max_update_observations;
    if (e->cfg.max_update_work > 0.0) {
        const uint32_t k = rows_fitting(vl_state_dim(e), e->cfg.max_update_work);
        if (cap == 0 || k < cap) {
            cap = k;
        }
    }
    return cap;
}

void vl_rows_hold(vl_estimator_t *e, uint32_t first, uint32_t end)
{
    for (uint32_t i = first; i < end; ++i) {
        if (!e->cfg.apply_deferred || e->num_held >= VL_MAX_LANDMARKS) {
            e->counters.observations_deferred_dropped++;
        } else {
            e->held_obs[e->num_held++] = e->work_frame_obs[i];
        }
    }
}

void vl_rows_drop_held(vl_estimator_t *e)
{
    e->counters.observations_deferred_dropped += e->num_held;
    e->num_held = 0;
}

uint32_t vl_rows_from_held(vl_estimator_t *e)
{
    vl_la_obs_t *rows = e->work_rows;
    const vl_la_pending_t pending = vl_update_pending(e);
    uint32_t k = 0;
    for (uint32_t i = 0; i < e->num_held; ++i) {
        const vl_stereo_obs_t *o = &e->prev_obs[e->held_obs[i]];
        const int slot = vl_window_find_slot(e, o->id);
        if (slot < 0 || vl_update_make_row(e, (uint32_t)slot, o, &rows[k]) != 0) {
            e->counters.observations_deferred_dropped++; /* its landmark left the window, or turned behind */
            continue;
        }
        if (e->cfg.gate_chi2 > 0.0) {
            double S[9];
            vl_la_obs_covariance(vl_P(e), VL_LD, &rows[k], &pending, S);
            if (vl_mahalanobis3(S, rows[k].residual) > e->cfg.gate_chi2) {
                e->counters.observations_gated++;
                continue;
            }
        }
        e->work_slot[k] = (uint32_t)slot;
        e->work_frame_obs[k] = e->held_obs[i];
        k++;
    }
    if (e->cfg.max_deferred_work > 0.0) {
        const uint32_t cap = rows_fitting(vl_state_dim(e), e->cfg.max_deferred_work);
        if (k > cap) {
            e->counters.observations_deferred_dropped += k - cap;
            k = cap;
        }
    }
    return k;
}

/* Does row a's landmark go before row b's: used by fewer updates, then unused for longer. */
static int used_less(const vl_estimator_t *e, const vl_la_obs_t *a, const vl_la_obs_t *b)
{
    const vl_landmark_slot_t *sa = &e->slots[vl_landmark_slot_at(a->landmark_col)];
    const vl_landmark_slot_t *sb = &e->slots[vl_landmark_slot_at(b->landmark_col)];
    if (sa->updates != sb->updates) {
        return sa->updates < sb->updates;
    }
    return sa->last_update_frame < sb->last_update_frame;
}

/* The cap rows that go first by used_less (the earlier of equal rows) move to the front, in their order. */
static void limit_least_used(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t m, uint32_t cap)
{
    uint8_t *keep = e->work_support;
    memset(keep, 0, m);
    for (uint32_t c = 0; c < cap; ++c) {
        uint32_t best = m;
        for (uint32_t i = 0; i < m; ++i) {
            if (!keep[i] && (best == m || used_less(e, &rows[i], &rows[best]))) {
                best = i;
            }
        }
        keep[best] = 1;
    }
    uint32_t front = 0;
    for (uint32_t i = 0; i < m; ++i) {
        if (keep[i]) {
            vl_rows_swap(e, rows, front, i);
            keep[i] = keep[front];
            keep[front] = 1;
            front++;
        }
    }
}

/* The others stay in the window and are used in later frames. */
uint32_t vl_rows_limit(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t m, uint32_t cap)
{
    if (cap == 0 || m <= cap) {
        return m;
    }
    if (e->cfg.rotate_deferred) {
        limit_least_used(e, rows, m, cap);
    } else {
        for (uint32_t i = 0; i < cap; ++i) {
            vl_rows_swap(e, rows, i, (uint32_t)(((uint64_t)i * m) / cap));
        }
    }
    e->counters.observations_deferred += m - cap;
    return cap;
}

vl_la_pending_t vl_update_pending(const vl_estimator_t *e)
{
    const vl_la_pending_t p = {e->work_PHt, vl_la_padded_rows((int)vl_state_dim(e), VL_LD), (int)e->pending_cols};
    return p;
}

static vl_la_workspace_t workspace(vl_estimator_t *e)
{
    const vl_la_workspace_t ws = {e->work_PHt, e->work_S, e->work_dx, e->cfg.parallel_for, e->cfg.parallel_ctx};
    return ws;
}

void vl_update_downdate(vl_estimator_t *e)
{
    if (e->pending_cols > 0) {
        const vl_la_workspace_t ws = workspace(e);
        vl_la_downdate_landmarks(vl_P(e), VL_LD, (int)vl_state_dim(e), &ws, (int)e->pending_cols);
        e->pending_cols = 0;
    }
}

vl_status_t vl_update_apply(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t m)
{
    if (m == 0) {
        return VL_OK;
    }
    /* The workspaces hold at most VL_OBS_DIM * VL_MAX_LANDMARKS columns; a frame's rows never
     * exceed them (one row block per window landmark), so this only guards the invariant. */
    if (e->pending_cols + VL_OBS_DIM * m > VL_OBS_DIM * VL_MAX_LANDMARKS) {
        vl_update_downdate(e);
    }
    const vl_la_workspace_t ws = workspace(e);
    const uint32_t n = vl_state_dim(e);
    double nis = 0.0;
    if (vl_la_update_core(vl_P(e), VL_LD, (int)n, rows, (int)m, &ws, (int)e->pending_cols, &nis) != 0 ||
        !vl_all_finite(e->work_dx, (int)n)) {
        e->counters.numerical_failures++;
        return VL_ERR_NOT_POSITIVE_DEFINITE;
    }
    e->pending_cols += VL_OBS_DIM * m;
    /* X <- exp(dx) X on SE_{K+1}(3): every position turns with the rotation
     * correction and moves by J_l(phi) times its own translation correction. */
    const double *dx = e->work_dx;
    double dR[9], dp[3], Jl[9], Rn[9], v[3], w[3];
    vl_se3_exp(&dx[VL_IDX_RHO], dR, dp);
    vl_so3_left_jacobian(&dx[VL_IDX_PHI], Jl);
    vl_matmul(dR, e->R, Rn, 3, 3, 3);
    memcpy(e->R, Rn, sizeof(Rn));
    vl_so3_normalize(e->R);
    vl_matmul(dR, e->p, v, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        e->p[i] = v[i] + dp[i];
        e->offset_linear[i] += dx[VL_IDX_OFFSET_LIN + i];
        e->offset_angular[i] += dx[VL_IDX_OFFSET_ANG + i];
        e->sensor_position[i] += dx[VL_IDX_SENSOR + i];
    }
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        double *l = &e->landmark_state[3 * s];
        vl_matmul(dR, l, v, 3, 3, 1);
        vl_matmul(Jl, &dx[vl_landmark_col(s)], w, 3, 3, 1);
        for (int i = 0; i < 3; ++i) {
            l[i] = v[i] + w[i];
        }
    }
    for (uint32_t i = 0; i < m; ++i) {
        vl_landmark_slot_t *s = &e->slots[vl_landmark_slot_at(rows[i].landmark_col)];
        s->updates++;
        s->last_update_frame = e->frame_index;
    }
    e->counters.observations_used += m;
    e->innovation_nis += nis;
    e->innovation_rows += VL_OBS_DIM * m;
    return VL_OK;
}
