/*
 * The estimator: prediction on SE(3), stereo landmark initialization, the joint
 * update, and the bounded landmark window with exact marginalization.
 *
 * The state layout is in vl_estimator_internal.h.
 *
 * Errors are invariant (world-frame) errors of the group SE_{K+1}(3) formed by the
 * pose and the landmarks: T = exp(xi) T_hat, l_i = exp(phi) l_hat_i + J_l(phi) rho_i.
 * In these coordinates the six unobservable directions (moving the whole world)
 * do not depend on the estimate, so linearizing at a changing estimate cannot
 * create information about them: without that, an EKF on this problem soon
 * claims centimetres of certainty about an absolute position it cannot observe,
 * then gates away good observations. Prediction leaves the error unchanged
 * (Phi = I) apart from the input offsets; the observation of landmark i depends
 * only on rho_i - rho, not on phi.
 */
#include "vislam/vislam.h"

#include <math.h>
#include <string.h>

#include "vl_camera.h"
#include "vl_estimator_internal.h"
#include "vl_linalg.h"
#include "vl_se3.h"
#include "vl_stereo.h"

/* Fewer tracked observations than this never count as a re-association. */
#define VL_MIN_ROWS_FOR_REASSOCIATION 8
/* Adapted noise stays within this factor (of the std) of its configured value, either way. */
#define VL_NOISE_ADAPT_RANGE 100.0
/* Rows of evidence the pixel noise estimate averages over (its forgetting scale). */
#define VL_PIXEL_NOISE_MEMORY 1000.0
/* Step of the velocity noise in log-variance per frame, at a frame that fully informs the pose. */
#define VL_VELOCITY_NOISE_GAIN 0.05
/* Variance factor applied when frame after frame contradicts the prior. */
#define VL_NOISE_WIDEN_ON_CONTRADICTION 4.0

/* Admission score bonus per frame of track age (frames seen before this one)... */
#define VL_ADMISSION_AGE_BONUS 0.5
/* ...counted up to this age: a track already seen 4 frames ranks at 3x its disparity. */
#define VL_ADMISSION_AGE_CAP 4u

typedef char vl_assert_capacity_positive[(VL_MAX_LANDMARKS >= 1) ? 1 : -1];
typedef char vl_assert_capacity_bounded[(VL_MAX_LANDMARKS <= 4096) ? 1 : -1];
typedef char vl_assert_frame_capacity[(VL_MAX_FRAME_FEATURES >= 1) ? 1 : -1];
typedef char vl_assert_pending_capacity[(VL_MAX_PENDING >= VL_MAX_FRAME_FEATURES) ? 1 : -1];

/* ---------------------------------------------------------------- prediction */

static void propagate_to(vl_estimator_t *e, int64_t utime)
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

/* World position and covariance: delta l = rho_i - hat(l) phi (or rho_i alone when mapping). */
static void landmark_output(const vl_estimator_t *e, uint32_t slot, vl_landmark_t *out)
{
    const vl_landmark_slot_t *s = &e->slots[slot];
    const double *l = vl_landmark_point(e, slot);
    memcpy(out->position, l, 3 * sizeof(double));
    const uint32_t c = vl_landmark_col(slot);
    const uint32_t idx[6] = {VL_IDX_PHI, VL_IDX_PHI + 1, VL_IDX_PHI + 2, c, c + 1, c + 2};
    double B[36];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            B[6 * i + j] = e->P[(size_t)idx[j] * VL_LD + idx[i]];
        }
    }
    double J[18] = {0};
    if (e->cfg.mode != VL_MODE_MAPPING) {
        double S[9];
        vl_skew(l, S);
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                J[6 * i + j] = -S[3 * i + j];
            }
        }
    }
    J[3] = J[6 + 4] = J[12 + 5] = 1.0;
    double JB[18];
    vl_matmul(J, B, JB, 3, 6, 6);
    vl_matmul_bt(JB, J, out->covariance, 3, 6, 3);
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
        vl_la_move_block(e->P, VL_LD, (int)vl_state_dim(e), (int)vl_landmark_col(slot), (int)vl_landmark_col(last));
        e->slots[slot] = e->slots[last];
        memcpy(&e->landmark_state[3 * slot], &e->landmark_state[3 * last], 3 * sizeof(double));
        e->work_seen[slot] = e->work_seen[last];
    }
    e->num_landmarks--;
    e->counters.landmarks_marginalized++;
}

/* ---------------------------------------------------------------- initialization */

/*
 * Admits a landmark from one stereo observation y (compressed): l = R b + p with
 * b the triangulated point in the IMU frame. In invariant coordinates its error is
 * rho (the pose's) plus the pixel part, so it gets the exact first-order
 * cross-covariance to every state through the pose translation error.
 */
static void admit_landmark(vl_estimator_t *e, int32_t id, const double y[3])
{
    const uint32_t slot = e->num_landmarks;
    vl_landmark_slot_t *s = &e->slots[slot];
    double *l = &e->landmark_state[3 * slot];
    double J_pose[18] = {0}, J_obs[9], noise[3];
    vl_camera_triangulate_world(e, y, l, J_obs);
    if (e->cfg.mode != VL_MODE_MAPPING) {
        for (int i = 0; i < 3; ++i) {
            J_pose[6 * i + VL_IDX_RHO + i] = 1.0;
        }
    }
    vl_stereo_noise_var(e->pixel_var, noise);
    vl_la_append_landmark(e->P, VL_LD, (int)vl_state_dim(e), J_pose, J_obs, noise);

    s->id = id;
    s->observations = 1;
    s->unseen_frames = 0;
    s->first_utime = e->state_utime;
    s->last_utime = e->state_utime;
    e->work_seen[slot] = VL_SEEN;
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

/* ---------------------------------------------------------------- update */

/*
 * Update rows of one window landmark's observation; -1 when it is behind the camera.
 * With b = R^T (l - p), to first order b = b_hat + R^T (rho_i - rho): the rows are
 * A = dy/dc Rc R^T on rho_i and -A on rho, and zero on phi.
 */
static int make_row(const vl_estimator_t *e, uint32_t slot, const vl_stereo_obs_t *o, vl_la_obs_t *row)
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

/* Squared pixel length of a row's residual after a correction dx. */
static double residual_after(const vl_la_obs_t *row, const double *dx)
{
    double acc = 0.0;
    const double *dl = &dx[row->landmark_col];
    for (int r = 0; r < 3; ++r) {
        double v = row->residual[r];
        for (int j = 0; j < 6; ++j) {
            v -= row->H_pose[6 * r + j] * dx[j];
        }
        for (int j = 0; j < 3; ++j) {
            v -= row->H_landmark[3 * r + j] * dl[j];
        }
        acc += v * v;
    }
    return acc;
}

static void swap_rows(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t a, uint32_t b)
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

/* splitmix64: hypotheses drawn from the frame index, so a replay draws the same ones. */
static uint64_t next_random(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Rows whose prior innovation passes gate_chi2, flagged in work_inlier; returns how many fail. */
static uint32_t gate_rows(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k)
{
    uint32_t failed = 0;
    for (uint32_t i = 0; i < k; ++i) {
        double S[9];
        vl_la_obs_covariance(e->P, VL_LD, &rows[i], S);
        e->work_inlier[i] = vl_mahalanobis3(S, rows[i].residual) <= e->cfg.gate_chi2;
        failed += !e->work_inlier[i];
    }
    return failed;
}

/*
 * 1-point RANSAC: each hypothesis is the state one observation alone would give;
 * the observations it explains to within ransac_threshold pixels are its
 * support. Replaces the work_inlier flags with the best hypothesis' support.
 */
static void ransac_rows(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k)
{
    uint8_t *inlier = e->work_inlier;
    const int n = (int)vl_state_dim(e);
    const double thr2 = e->cfg.ransac_threshold * e->cfg.ransac_threshold;
    const uint32_t hypotheses = e->cfg.ransac_hypotheses < k ? e->cfg.ransac_hypotheses : k;
    uint32_t best_support = 0;
    uint64_t rng = e->frame_index;
    for (uint32_t h = 0; h < hypotheses; ++h) {
        const uint32_t pick = (uint32_t)(next_random(&rng) % k);
        if (vl_la_single_correction(e->P, VL_LD, n, &rows[pick], e->work_PHt, e->work_dx) != 0) {
            continue;
        }
        uint8_t *flags = e->work_support;
        uint32_t support = 0;
        for (uint32_t i = 0; i < k; ++i) {
            flags[i] = residual_after(&rows[i], e->work_dx) <= thr2;
            support += flags[i];
        }
        if (support > best_support) {
            best_support = support;
            memcpy(inlier, flags, k);
        }
    }
}

/* Moves the rows flagged in work_inlier to the front; returns how many there are. */
static uint32_t partition_rows(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t k)
{
    uint8_t *inlier = e->work_inlier;
    uint32_t m = 0;
    for (uint32_t i = 0; i < k; ++i) {
        if (inlier[i]) {
            swap_rows(e, rows, m, i);
            uint8_t t = inlier[m];
            inlier[m] = inlier[i];
            inlier[i] = t;
            m++;
        }
    }
    return m;
}

/* Joint update with the first m rows, and the state correction it gives. */
static vl_status_t apply_update(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t m)
{
    if (m == 0) {
        return VL_OK;
    }
    vl_la_workspace_t ws = {e->work_PHt, e->work_S, e->work_dx};
    const uint32_t n = vl_state_dim(e);
    if (vl_la_update(e->P, VL_LD, (int)n, rows, (int)m, &ws) != 0 || !vl_all_finite(e->work_dx, (int)n)) {
        e->counters.numerical_failures++;
        return VL_ERR_NOT_POSITIVE_DEFINITE;
    }
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
    }
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        double *l = &e->landmark_state[3 * s];
        vl_matmul(dR, l, v, 3, 3, 1);
        vl_matmul(Jl, &dx[vl_landmark_col(s)], w, 3, 3, 1);
        for (int i = 0; i < 3; ++i) {
            l[i] = v[i] + w[i];
        }
    }
    e->counters.observations_used += m;
    return VL_OK;
}

/* ---------------------------------------------------------------- noise adaptation */

/* Keeps a variance within the adaptation's bounds around its configured value. */
static double clamp_var(double var, double configured_std)
{
    const double f = VL_NOISE_ADAPT_RANGE;
    const double lo = configured_std * configured_std / (f * f), hi = configured_std * configured_std * f * f;
    return var < lo ? lo : (var > hi ? hi : var);
}

/* The k-th smallest of v[0..n) (0-based); reorders v. Quickselect with a middle pivot: deterministic. */
static double select_kth(double *v, uint32_t n, uint32_t k)
{
    uint32_t lo = 0, hi = n - 1u;
    while (lo < hi) {
        const double pivot = v[lo + (hi - lo) / 2u];
        uint32_t i = lo, j = hi;
        while (i <= j) {
            while (v[i] < pivot) {
                ++i;
            }
            while (v[j] > pivot) {
                --j;
            }
            if (i <= j) {
                const double t = v[i];
                v[i] = v[j];
                v[j] = t;
                ++i;
                if (j == 0u) {
                    break;
                }
                --j;
            }
        }
        if (k <= j) {
            hi = j;
        } else if (k >= i) {
            lo = i;
        } else {
            return v[k];
        }
    }
    return v[k];
}

/*
 * Residual-based covariance matching for the pixel noise, made robust. After the
 * update, an observation's post-fit residual e has E[e e^T] = R - H P+ H^T, so
 * each row gives (e_r^2 + (H P+ H^T)_rr) / w_r as a sample of the pixel variance
 * (w_r the row's share: 1, 1/2, 1). The median over every row of the frame,
 * outliers included, scaled to a variance (the median of chi-square(1) is 0.455),
 * is blind to a minority of outliers and is not truncated by the inlier
 * selection. It enters an average that forgets faster the more rows a frame has.
 */
static void adapt_pixel_noise(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k)
{
    static const double share[3] = {1.0, 0.5, 1.0};
    double samples[VL_OBS_DIM * VL_MAX_LANDMARKS];
    uint32_t n = 0;
    for (uint32_t i = 0; i < k; ++i) {
        double S[9];
        vl_la_obs_covariance(e->P, VL_LD, &rows[i], S); /* H P+ H^T + R */
        for (int r = 0; r < 3; ++r) {
            double res = rows[i].residual[r];
            for (int j = 0; j < 6; ++j) {
                res -= rows[i].H_pose[6 * r + j] * e->work_dx[j];
            }
            for (int j = 0; j < 3; ++j) {
                res -= rows[i].H_landmark[3 * r + j] * e->work_dx[rows[i].landmark_col + j];
            }
            samples[n++] = (res * res + S[4 * r] - rows[i].noise_var[r]) / share[r];
        }
    }
    if (n < 3u) {
        return;
    }
    const double sample = select_kth(samples, n, n / 2u) / 0.455;
    const double w = 1.0 - exp(-(double)k / VL_PIXEL_NOISE_MEMORY);
    e->pixel_var = clamp_var((1.0 - w) * e->pixel_var + w * sample, e->cfg.pixel_noise);
}

/*
 * Covariance matching for the velocity noise on the pose correction: for a
 * consistent filter E[dx dx^T] = P- - P+ on the pose block. More correction than
 * the filter expected means its prediction was too confident (noise too small),
 * less means too timid. Each variance moves by a fraction of log(ratio), weighted
 * by how much the frame informed that block, so weak frames barely move it.
 */
static void adapt_velocity_noise(vl_estimator_t *e, const double prior_diag[6])
{
    const double *dx = e->work_dx;
    double *var[2] = {&e->linear_velocity_var, &e->angular_velocity_var};
    const double configured[2] = {e->cfg.linear_velocity_noise, e->cfg.angular_velocity_noise};
    for (int b = 0; b < 2; ++b) {
        double expected = 0.0, seen = 0.0, prior = 0.0;
        for (int i = 3 * b; i < 3 * b + 3; ++i) {
            prior += prior_diag[i];
            expected += prior_diag[i] - *vl_P_at(e, (uint32_t)i, (uint32_t)i);
            seen += dx[i] * dx[i];
        }
        if (!(expected > 1e-12 * prior) || !(prior > 0.0)) {
            continue;
        }
        double ratio = seen / expected;
        ratio = ratio < 0.1 ? 0.1 : (ratio > 10.0 ? 10.0 : ratio);
        const double gain = VL_VELOCITY_NOISE_GAIN * (expected / prior);
        *var[b] = clamp_var(*var[b] * exp(gain * log(ratio)), configured[b]);
    }
}

/*
 * Re-linearizes the rejected rows (rows[first .. first + count)) at the corrected
 * state, keeps those within gate_chi2 of their posterior innovation covariance,
 * and moves them to the front of rows. Returns how many were kept.
 *
 * The others are broken tracks: the seed data's tracker, when it detects new
 * features, hands some existing ids to different points (their pixels jump tens
 * of pixels away from the point's history but agree with its future). Such a
 * landmark leaves the window for the map and its id starts a new landmark from
 * this observation; its slot is marked VL_SEEN_BROKEN in work_seen and the observation is
 * listed in work_broken.
 */
static uint32_t rescue_outliers(vl_estimator_t *e, const vl_stereo_frame_t *frame, vl_la_obs_t *rows,
                                uint32_t first, uint32_t count)
{
    uint32_t m = 0;
    for (uint32_t i = first; i < first + count; ++i) {
        const uint32_t slot = e->work_slot[i];
        vl_la_obs_t row;
        if (make_row(e, slot, &frame->obs[e->work_frame_obs[i]], &row) != 0) {
            continue;
        }
        double S[9];
        vl_la_obs_covariance(e->P, VL_LD, &row, S);
        if (vl_mahalanobis3(S, row.residual) <= e->cfg.gate_chi2) {
            rows[m] = row;
            e->work_slot[m] = slot;
            m++;
        } else {
            e->work_seen[slot] = VL_SEEN_BROKEN;
            e->work_broken[e->num_broken++] = e->work_frame_obs[i];
        }
    }
    return m;
}

/* ---------------------------------------------------------------- public API */

/* The state vl_init gives: identity pose, empty window, configured noise; counters zero. */
static void init_state(vl_estimator_t *e, const vl_config_t *cfg)
{
    memset(e, 0, offsetof(vl_estimator_t, P));
    e->cfg = *cfg;
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(e->R, I3, sizeof(I3));
    /* Only the leading 12 x 12 block is live at start; the rest is written as landmarks arrive. */
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        memset(&e->P[(size_t)j * VL_LD], 0, VL_CORE_DIM * sizeof(double));
    }
    if (cfg->estimate_input_offsets) {
        for (int i = 0; i < 3; ++i) {
            *vl_P_at(e, VL_IDX_OFFSET_LIN + i, VL_IDX_OFFSET_LIN + i) =
                cfg->linear_offset_prior * cfg->linear_offset_prior;
            *vl_P_at(e, VL_IDX_OFFSET_ANG + i, VL_IDX_OFFSET_ANG + i) =
                cfg->angular_offset_prior * cfg->angular_offset_prior;
        }
    }
    e->linear_velocity_var = cfg->linear_velocity_noise * cfg->linear_velocity_noise;
    e->angular_velocity_var = cfg->angular_velocity_noise * cfg->angular_velocity_noise;
    e->pixel_var = cfg->pixel_noise * cfg->pixel_noise;
    e->initialized = 1;
}

/*
 * Back to vl_init's state with the same configuration, counters kept. The
 * window's landmarks are dropped, not mapped: after a divergence they are
 * corrupt, and after a new timeline they belong to a world the restart does
 * not share. keep_clock keeps the time bookkeeping and the held IMU sample, so
 * the inputs that follow a divergence continue as before; a new timeline (and
 * vl_reset) starts the clock afresh.
 */
static void reset_state(vl_estimator_t *e, int keep_clock)
{
    const vl_estimator_t *old = e; /* the fields are copied out before init_state clears them */
    const vl_config_t cfg = old->cfg;
    vl_counters_t counters = old->counters;
    counters.landmarks_discarded += old->num_landmarks;
    counters.resets++;
    const int have_imu = old->have_imu, have_frame = old->have_frame, imu_silent = old->imu_silent;
    const int64_t state_utime = old->state_utime, last_imu = old->last_imu_utime;
    const int64_t last_frame = old->last_frame_utime, clock = old->clock_utime;
    double held_linear[3], held_angular[3];
    memcpy(held_linear, old->held_linear, sizeof(held_linear));
    memcpy(held_angular, old->held_angular, sizeof(held_angular));
    init_state(e, &cfg);
    e->counters = counters;
    if (keep_clock) {
        e->have_imu = have_imu;
        e->have_frame = have_frame;
        e->imu_silent = imu_silent;
        e->state_utime = state_utime;
        e->last_imu_utime = last_imu;
        e->last_frame_utime = last_frame;
        e->clock_utime = clock;
        memcpy(e->held_linear, held_linear, sizeof(held_linear));
        memcpy(e->held_angular, held_angular, sizeof(held_angular));
    }
}

vl_status_t vl_init(vl_estimator_t *e, const vl_config_t *cfg)
{
    if (e == NULL || cfg == NULL) {
        return VL_ERR_NULL;
    }
    if (((uintptr_t)(const void *)e % VL_ESTIMATOR_ALIGN) != 0) {
        return VL_ERR_MISALIGNED;
    }
    vl_status_t st = vl_config_check(cfg);
    if (st != VL_OK) {
        return st;
    }
    vl_la_configure();
    init_state(e, cfg);
    return VL_OK;
}

vl_status_t vl_reset(vl_estimator_t *e)
{
    if (e == NULL) {
        return VL_ERR_NULL;
    }
    if (!e->initialized) {
        return VL_ERR_NOT_READY;
    }
    reset_state(e, 0);
    return VL_OK;
}

typedef enum { INPUT_IMU, INPUT_FRAME } input_kind_t;

/*
 * The time policy (the first IMU sample sets the clock without it): an input
 * farther than max_time_jump from the clock, either way, is a jump; otherwise
 * each kind must move forward as before.
 */
static vl_status_t check_time(const vl_estimator_t *e, input_kind_t kind, int64_t utime)
{
    const int64_t limit = vl_limit_us(e->cfg.max_time_jump);
    const int64_t d = vl_utime_diff(utime, e->clock_utime);
    if (d > limit || d < -limit) {
        return VL_ERR_TIME_JUMP;
    }
    if (kind == INPUT_IMU) {
        return (utime <= e->last_imu_utime || utime < e->state_utime) ? VL_ERR_TIME_ORDER : VL_OK;
    }
    return (utime < e->state_utime || (e->have_frame && utime <= e->last_frame_utime)) ? VL_ERR_TIME_ORDER : VL_OK;
}

/* An input passed the time policy: the clock follows it and no new timeline is pending. */
static void time_passed(vl_estimator_t *e, int64_t utime)
{
    if (utime > e->clock_utime) {
        e->clock_utime = utime;
    }
    e->timeline_count = 0;
}

/*
 * A time-refused input. Consecutive ones that follow one another (each within
 * max_time_jump of the previous, each kind strictly forward, so a stuck clock
 * never qualifies) are a candidate timeline; any input that passes the policy
 * ends it. Returns nonzero when the candidate has new_timeline_samples inputs.
 */
static int note_timeline(vl_estimator_t *e, input_kind_t kind, int64_t utime)
{
    int follows = e->timeline_count > 0;
    if (follows) {
        const int64_t limit = vl_limit_us(e->cfg.max_time_jump);
        const int64_t d = vl_utime_diff(utime, e->timeline_last_utime);
        follows = d <= limit && d >= -limit;
        if (kind == INPUT_IMU && e->timeline_have_imu && utime <= e->timeline_last_imu_utime) {
            follows = 0;
        }
        if (kind == INPUT_FRAME && e->timeline_have_frame && utime <= e->timeline_last_frame_utime) {
            follows = 0;
        }
    }
    if (!follows) {
        e->timeline_count = 0;
        e->timeline_have_imu = 0;
        e->timeline_have_frame = 0;
    }
    e->timeline_count++;
    e->timeline_last_utime = utime;
    if (kind == INPUT_IMU) {
        e->timeline_have_imu = 1;
        e->timeline_last_imu_utime = utime;
    } else {
        e->timeline_have_frame = 1;
        e->timeline_last_frame_utime = utime;
    }
    return e->timeline_count >= e->cfg.new_timeline_samples;
}

/*
 * The divergence guard: a non-finite state, a covariance with a negative or
 * non-finite diagonal or a core block violating |P_ij| <= sqrt(P_ii P_jj) (a
 * necessary condition of positive semi-definiteness, cheap enough for every
 * step), or, in SLAM, divergence_frames failed updates in a row.
 */
static int diverged(const vl_estimator_t *e)
{
    if (!vl_all_finite(e->R, 9) || !vl_all_finite(e->p, 3) || !vl_all_finite(e->offset_linear, 3) ||
        !vl_all_finite(e->offset_angular, 3) || !vl_all_finite(e->landmark_state, 3 * (int)e->num_landmarks)) {
        return 1;
    }
    const uint32_t n = vl_state_dim(e);
    for (uint32_t i = 0; i < n; ++i) {
        const double d = e->P[(size_t)i * VL_LD + i];
        if (!(d >= 0.0) || !isfinite(d)) {
            return 1;
        }
    }
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        for (uint32_t i = 0; i < j; ++i) {
            const double pij = e->P[(size_t)j * VL_LD + i];
            const double bound = e->P[(size_t)i * VL_LD + i] * e->P[(size_t)j * VL_LD + j];
            if (!isfinite(pij) || pij * pij > bound * (1.0 + 1e-6)) {
                return 1;
            }
        }
    }
    return e->cfg.mode == VL_MODE_SLAM && e->cfg.divergence_frames > 0 &&
           e->failed_frame_run >= e->cfg.divergence_frames;
}

/* After an input was used: a diverged estimator restarts (VL_RESET), else result stands. */
static vl_status_t guard_divergence(vl_estimator_t *e, int64_t utime, vl_status_t result)
{
    if (!diverged(e)) {
        return result;
    }
    reset_state(e, 1);
    e->counters.divergence_resets++;
    vl_log_msg(e, VL_LOG_ERROR, utime, "estimator diverged; re-initialized with the same configuration");
    return VL_RESET;
}

/* Euclidean length of a finite 3-vector, scaled so that squaring cannot overflow. */
static double norm3(const double v[3])
{
    const double m = fmax(fabs(v[0]), fmax(fabs(v[1]), fabs(v[2])));
    if (m == 0.0) {
        return 0.0;
    }
    const double a = v[0] / m, b = v[1] / m, c = v[2] / m;
    return m * sqrt(a * a + b * b + c * c);
}

static int imu_plausible(const vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    return norm3(imu->linear_velocity) <= e->cfg.max_speed && norm3(imu->angular_velocity) <= e->cfg.max_rotation_rate;
}

vl_status_t vl_propagate(vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    if (e == NULL || imu == NULL) {
        return VL_ERR_NULL;
    }
    if (!e->initialized) {
        return VL_ERR_NOT_READY;
    }
    if (!vl_all_finite(imu->linear_velocity, 3) || !vl_all_finite(imu->angular_velocity, 3)) {
        e->counters.imu_rejected++;
        vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample with NaN or infinity rejected");
        return VL_ERR_NON_FINITE;
    }
    if (!imu_plausible(e, imu)) {
        e->counters.imu_rejected++;
        e->counters.imu_implausible++;
        vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample beyond max_speed or max_rotation_rate rejected");
        return VL_ERR_IMPLAUSIBLE;
    }
    vl_status_t result = VL_OK;
    if (e->have_imu) {
        const vl_status_t st = check_time(e, INPUT_IMU, imu->utime);
        if (st != VL_OK) {
            if (!note_timeline(e, INPUT_IMU, imu->utime)) {
                e->counters.imu_rejected++;
                if (st == VL_ERR_TIME_JUMP) {
                    e->counters.time_jumps++;
                    vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample jumping in time rejected");
                } else {
                    vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample out of time order rejected");
                }
                return st;
            }
            /* The inputs follow a new timeline: restart on it with this sample. */
            reset_state(e, 0);
            e->counters.timeline_changes++;
            vl_log_msg(e, VL_LOG_WARN, imu->utime, "inputs follow a new timeline; re-initialized on it");
            result = VL_RESET;
        }
    }
    if (e->have_imu) {
        const int64_t silence = vl_limit_us(e->cfg.max_imu_silence);
        if (vl_utime_diff(imu->utime, e->last_imu_utime) > silence) {
            /* The held velocity is trusted for max_imu_silence; the motion after that
             * is unknown, so the clock jumps over it rather than invent it. */
            if (!e->imu_silent) {
                e->counters.imu_silences++;
            }
            vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU back after a silence; the motion during it is not propagated");
            propagate_to(e, e->last_imu_utime + silence);
            e->state_utime = imu->utime;
        } else {
            propagate_to(e, imu->utime);
        }
        time_passed(e, imu->utime);
    } else {
        e->state_utime = imu->utime;
        e->clock_utime = imu->utime;
        e->timeline_count = 0;
        e->have_imu = 1;
    }
    e->imu_silent = 0;
    memcpy(e->held_linear, imu->linear_velocity, sizeof(e->held_linear));
    memcpy(e->held_angular, imu->angular_velocity, sizeof(e->held_angular));
    e->last_imu_utime = imu->utime;
    e->counters.imu_accepted++;
    return guard_divergence(e, imu->utime, result);
}

/* Observation validity before any use: finite pixels and a real id. */
static int observation_valid(const vl_stereo_obs_t *o)
{
    return o->id >= 0 && isfinite(o->u_left) && isfinite(o->v_left) && isfinite(o->u_right) &&
           isfinite(o->v_right);
}

/*
 * Physically possible: every pixel inside the image (image_width x image_height,
 * 2 cx x 2 cy when 0) widened by image_margin, and a disparity no larger than
 * max_disparity.
 */
static int observation_plausible(const vl_estimator_t *e, const vl_stereo_obs_t *o)
{
    const vl_config_t *c = &e->cfg;
    const double m = c->image_margin;
    const double w = (c->image_width > 0.0 ? c->image_width : 2.0 * c->calibration.cx) + m;
    const double h = (c->image_height > 0.0 ? c->image_height : 2.0 * c->calibration.cy) + m;
    return o->u_left >= -m && o->u_left <= w && o->u_right >= -m && o->u_right <= w && o->v_left >= -m &&
           o->v_left <= h && o->v_right >= -m && o->v_right <= h && o->u_left - o->u_right <= c->max_disparity;
}

static double depth_of(const vl_calibration_t *cal, double disparity)
{
    return cal->fx * cal->baseline / disparity;
}

/* A pending track's world point and its covariance from pixel noise alone, from observation y. */
static void pending_triangulate(const vl_estimator_t *e, const double y[3], vl_pending_track_t *t)
{
    double J[9], nv[3], tmp[9];
    vl_camera_triangulate_world(e, y, t->point, J);
    vl_stereo_noise_var(e->pixel_var, nv);
    const double noise[9] = {nv[0], 0, 0, 0, nv[1], 0, 0, 0, nv[2]};
    vl_matmul(J, noise, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, J, t->covariance, 3, 3, 3);
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
    if (vl_camera_project_world(e, t->point, y_pred, Hp, Hx) != 0) {
        return 0;
    }
    const double sv2 = e->linear_velocity_var * dt * dt;
    const double sw2 = e->angular_velocity_var * dt * dt;
    double nv[3];
    vl_stereo_noise_var(e->pixel_var, nv);
    double S[9], tmp[9], HQ[18];
    vl_matmul(Hx, t->covariance, tmp, 3, 3, 3);
    vl_matmul_bt(tmp, Hx, S, 3, 3, 3);
    for (int r = 0; r < 3; ++r) {
        for (int j = 0; j < 6; ++j) {
            HQ[6 * r + j] = Hp[6 * r + j] * (j < VL_IDX_PHI ? sv2 : sw2);
        }
    }
    double HQH[9];
    vl_matmul_bt(HQ, Hp, HQH, 3, 6, 3);
    for (int i = 0; i < 9; ++i) {
        S[i] += HQH[i];
    }
    S[0] += nv[0];
    S[4] += nv[1];
    S[8] += nv[2];
    const double r[3] = {y[0] - y_pred[0], y[1] - y_pred[1], y[2] - y_pred[2]};
    return vl_mahalanobis3(S, r) <= e->cfg.gate_chi2;
}

/* Candidate for admission, ordered by score. */
typedef struct {
    uint32_t obs;
    double score;
} candidate_t;

/* Admission candidates of one frame (on the stack of vl_update: a few KiB). */
typedef struct {
    candidate_t item[VL_MAX_FRAME_FEATURES];
    uint32_t count;
} candidates_t;

static void add_candidate(candidates_t *c, uint32_t obs, double score)
{
    if (c->count < VL_MAX_FRAME_FEATURES) {
        c->item[c->count].obs = obs;
        c->item[c->count].score = score;
        c->count++;
    }
}

/* Larger disparity (nearer, better conditioned) and longer tracks go first. */
static double admission_score(double disparity, uint32_t frames_seen)
{
    const uint32_t age = frames_seen - 1u;
    const uint32_t counted = age < VL_ADMISSION_AGE_CAP ? age : VL_ADMISSION_AGE_CAP;
    return disparity * (1.0 + VL_ADMISSION_AGE_BONUS * (double)counted);
}

static int disparity_admissible(const vl_estimator_t *e, double disparity)
{
    return disparity >= e->cfg.min_disparity && depth_of(&e->cfg.calibration, disparity) <= e->cfg.max_depth;
}

/*
 * Step 1: observations of window landmarks become update rows (returns how
 * many); the others feed the pending tracks and, once old and consistent
 * enough, become admission candidates.
 */
static uint32_t classify_observations(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count,
                                      double frame_dt, candidates_t *candidates)
{
    vl_la_obs_t *rows = e->work_rows;
    uint32_t k = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        if (!observation_valid(o)) {
            e->counters.observations_invalid++;
            continue;
        }
        if (!observation_plausible(e, o)) {
            e->counters.observations_implausible++;
            continue;
        }
        const double disparity = o->u_left - o->u_right;
        const int slot = find_slot(e, o->id);
        if (slot >= 0) {
            if (e->work_seen[slot] != VL_SEEN_NONE) {
                e->counters.observations_invalid++; /* the same id twice in one frame */
                continue;
            }
            e->work_seen[slot] = VL_SEEN;
            vl_landmark_slot_t *s = &e->slots[slot];
            s->unseen_frames = 0;
            s->last_utime = frame->utime;
            s->observations++;
            if (!(disparity > 0.0)) {
                e->counters.observations_low_disparity++;
                continue;
            }
            if (make_row(e, (uint32_t)slot, o, &rows[k]) != 0) {
                e->counters.observations_behind_camera++;
                continue;
            }
            e->work_frame_obs[k] = i;
            e->work_slot[k] = (uint32_t)slot;
            k++;
            continue;
        }
        int duplicate = 0;
        vl_pending_track_t *t = pending_touch(e, o->id, &duplicate);
        if (duplicate) {
            e->counters.observations_invalid++;
            continue;
        }
        if (!disparity_admissible(e, disparity)) {
            e->counters.observations_low_disparity++;
            if (t != NULL) {
                t->frames_seen = 0; /* no usable point to compare the next observation with */
            }
            continue;
        }
        if (t == NULL) {
            continue; /* pending table full: the track is retried next frame */
        }
        double y[3];
        vl_stereo_compress(o, y);
        if (t->frames_seen >= 2 && !track_consistent(e, t, y, frame_dt)) {
            e->counters.tracks_inconsistent++;
            t->frames_seen = 1;
        }
        pending_triangulate(e, y, t);
        if (t->frames_seen >= e->cfg.min_track_length) {
            add_candidate(candidates, i, admission_score(disparity, t->frames_seen));
        }
    }
    return k;
}

/* Marks every row's landmark as a broken track (see rescue_outliers). */
static void break_all_rows(vl_estimator_t *e, uint32_t k)
{
    for (uint32_t i = 0; i < k; ++i) {
        e->work_seen[e->work_slot[i]] = VL_SEEN_BROKEN;
        e->work_broken[e->num_broken++] = e->work_frame_obs[i];
    }
}

/*
 * Step 2: outlier rejection, the joint update with the inliers, then a second
 * update with the outliers that agree with the corrected state.
 */
static vl_status_t update_with_rows(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t k)
{
    vl_la_obs_t *rows = e->work_rows;
    if (k == 0) {
        return VL_OK;
    }
    if (e->cfg.gate_chi2 <= 0.0) {
        return apply_update(e, rows, k); /* no outlier rejection at all (the seed's plain EKF) */
    }
    const uint32_t contradicting = gate_rows(e, rows, k);
    if (k >= VL_MIN_ROWS_FOR_REASSOCIATION && (double)contradicting > e->cfg.max_broken_fraction * (double)k) {
        /* Most tracks contradict the state at once: the tracker re-associated its
         * ids (it does so when it detects new features). None of these
         * observations is trusted; every observed landmark restarts. */
        e->counters.frames_reassociated++;
        e->counters.observations_gated += k;
        break_all_rows(e, k);
        /* A tracker re-associates on single frames; frame after frame contradicting
         * the prior means the prior is overconfident: widen the motion noise. */
        if (e->cfg.adaptive_noise && ++e->reassociated_run >= 2) {
            const double f = VL_NOISE_WIDEN_ON_CONTRADICTION;
            e->linear_velocity_var = clamp_var(e->linear_velocity_var * f, e->cfg.linear_velocity_noise);
            e->angular_velocity_var = clamp_var(e->angular_velocity_var * f, e->cfg.angular_velocity_noise);
            e->pixel_var = clamp_var(e->pixel_var * f, e->cfg.pixel_noise);
        }
        return VL_OK;
    }
    e->reassociated_run = 0;
    if (e->cfg.ransac_hypotheses > 0 && k >= 2) {
        ransac_rows(e, rows, k);
    }
    uint32_t inliers = partition_rows(e, rows, k);
    const uint32_t rest = k - inliers;
    const uint32_t cap = e->cfg.max_update_observations;
    if (cap > 0 && inliers > cap) {
        /* A time bound: an evenly spread subset of the inliers; the others stay
         * in the window and are used in later frames. */
        for (uint32_t i = 0; i < cap; ++i) {
            swap_rows(e, rows, i, (uint32_t)(((uint64_t)i * inliers) / cap));
        }
        e->counters.observations_deferred += inliers - cap;
        inliers = cap;
    }
    double prior_diag[6];
    for (uint32_t i = 0; i < 6; ++i) {
        prior_diag[i] = *vl_P_at(e, i, i);
    }
    vl_status_t st = apply_update(e, rows, inliers);
    if (st == VL_OK && inliers > 0 && e->cfg.adaptive_noise) {
        adapt_pixel_noise(e, rows, k);
        adapt_velocity_noise(e, prior_diag);
    }
    if (st != VL_OK || rest == 0) {
        e->counters.observations_gated += rest;
        return st;
    }
    uint32_t rescued = rescue_outliers(e, frame, rows, inliers, rest);
    e->counters.observations_rescued += rescued;
    e->counters.observations_gated += rest - rescued;
    if (cap > 0 && inliers + rescued > cap) {
        e->counters.observations_deferred += inliers + rescued - cap;
        rescued = cap - inliers;
    }
    return apply_update(e, rows, rescued);
}

/* Step 3: tracks that ended or broke leave the window for the map. */
static void retire_landmarks(vl_estimator_t *e)
{
    /* Walk down: marginalizing moves the last slot into the freed one. */
    for (uint32_t s = e->num_landmarks; s-- > 0;) {
        if (e->work_seen[s] == VL_SEEN_BROKEN) {
            marginalize_slot(e, s);
            e->counters.tracks_broken++;
        } else if (e->work_seen[s] == VL_SEEN_NONE && ++e->slots[s].unseen_frames > e->cfg.max_unseen_frames) {
            marginalize_slot(e, s);
        }
    }
}

/* The unobserved landmark unseen longest, or -1: a landmark observed now is never evicted. */
static int eviction_victim(const vl_estimator_t *e)
{
    int victim = -1;
    uint32_t longest = 0;
    for (uint32_t s = 0; s < e->num_landmarks; ++s) {
        if (e->work_seen[s] == VL_SEEN_NONE && e->slots[s].unseen_frames >= longest) {
            longest = e->slots[s].unseen_frames;
            victim = (int)s;
        }
    }
    return victim;
}

/* Step 4: admissions, best first, including the restarts of broken tracks. */
static void admit_candidates(vl_estimator_t *e, const vl_stereo_frame_t *frame, candidates_t *c)
{
    for (uint32_t b = 0; b < e->num_broken; ++b) {
        const vl_stereo_obs_t *o = &frame->obs[e->work_broken[b]];
        const double disparity = o->u_left - o->u_right;
        if (disparity_admissible(e, disparity)) {
            add_candidate(c, e->work_broken[b], disparity);
        }
    }
    for (uint32_t i = 1; i < c->count; ++i) { /* insertion sort: stable, so deterministic */
        const candidate_t item = c->item[i];
        uint32_t j = i;
        while (j > 0 && c->item[j - 1].score < item.score) {
            c->item[j] = c->item[j - 1];
            --j;
        }
        c->item[j] = item;
    }
    for (uint32_t i = 0; i < c->count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[c->item[i].obs];
        if (e->num_landmarks >= e->cfg.max_landmarks) {
            const int victim = eviction_victim(e);
            if (victim < 0) {
                e->counters.landmarks_deferred += c->count - i;
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
}

/*
 * A frame that repeats the previous frame's pixels exactly, for every id the two
 * share, is the same image delivered twice: the vehicle moved on, the image did not.
 */
static int frame_repeats_previous(const vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    uint32_t common = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        for (uint32_t j = 0; j < e->num_prev_obs; ++j) {
            const vl_stereo_obs_t *q = &e->prev_obs[j];
            if (q->id != o->id) {
                continue;
            }
            if (q->u_left != o->u_left || q->v_left != o->v_left || q->u_right != o->u_right ||
                q->v_right != o->v_right) {
                return 0;
            }
            common++;
            break;
        }
    }
    return common > 0;
}

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
    const vl_status_t time_st = check_time(e, INPUT_FRAME, frame->utime);
    if (time_st != VL_OK) {
        /* A frame adds to a candidate timeline; the restart waits for an IMU sample to set the clock. */
        (void)note_timeline(e, INPUT_FRAME, frame->utime);
        e->counters.frames_rejected++;
        if (time_st == VL_ERR_TIME_JUMP) {
            e->counters.time_jumps++;
            vl_log_msg(e, VL_LOG_WARN, frame->utime, "frame jumping in time rejected");
        } else {
            vl_log_msg(e, VL_LOG_WARN, frame->utime, "frame out of time order rejected");
        }
        return time_st;
    }
    time_passed(e, frame->utime);
    if (vl_utime_diff(frame->utime, e->last_imu_utime) > vl_limit_us(e->cfg.max_imu_silence)) {
        e->counters.frames_rejected++;
        e->counters.frames_imu_silent++;
        if (!e->imu_silent) {
            e->imu_silent = 1;
            e->counters.imu_silences++;
            vl_log_msg(e, VL_LOG_WARN, frame->utime, "IMU silent longer than max_imu_silence; frames refused");
        }
        return VL_ERR_IMU_SILENT;
    }
    vl_status_t result = VL_OK;
    uint32_t count = frame->count;
    e->counters.observations_received += count;
    if (count > VL_MAX_FRAME_FEATURES) {
        e->counters.frames_truncated++;
        e->counters.observations_truncated += count - VL_MAX_FRAME_FEATURES;
        vl_log_msg(e, VL_LOG_WARN, frame->utime, "frame over VL_MAX_FRAME_FEATURES truncated");
        count = VL_MAX_FRAME_FEATURES;
        result = VL_FRAME_TRUNCATED;
    }

    /* Counted, and still used: after a repeated image the tracker's frames stay one
     * step behind the clock, so the repeat keeps the vision's timeline coherent
     * (skipping repeats measured worse on every density of the real drives). */
    if (frame_repeats_previous(e, frame, count)) {
        e->counters.frames_repeated++;
    }
    e->num_prev_obs = count;
    memcpy(e->prev_obs, frame->obs, count * sizeof(vl_stereo_obs_t));
    propagate_to(e, frame->utime);
    const double frame_dt = e->have_frame ? (double)vl_utime_diff(frame->utime, e->last_frame_utime) * 1e-6 : 0.0;
    e->last_frame_utime = frame->utime;
    e->have_frame = 1;
    e->frame_index++;
    e->counters.frames_accepted++;
    if (e->cfg.mode == VL_MODE_IMU_ONLY) {
        return guard_divergence(e, frame->utime, result);
    }

    memset(e->work_seen, VL_SEEN_NONE, sizeof(e->work_seen));
    e->num_broken = 0;
    candidates_t candidates;
    candidates.count = 0;
    const uint32_t k = classify_observations(e, frame, count, frame_dt, &candidates);
    const uint64_t reassociated_before = e->counters.frames_reassociated;
    const uint64_t used_before = e->counters.observations_used;
    const vl_status_t st = update_with_rows(e, frame, k);
    if (st != VL_OK) {
        vl_log_msg(e, VL_LOG_ERROR, frame->utime, "innovation covariance not positive definite; update refused");
        result = st;
    }
    /* A frame whose update was refused or contradicted the state extends the run;
     * one that corrected the state ends it; one with nothing to use leaves it. */
    if (st != VL_OK || e->counters.frames_reassociated != reassociated_before) {
        e->failed_frame_run++;
    } else if (e->counters.observations_used != used_before) {
        e->failed_frame_run = 0;
    }
    retire_landmarks(e);
    admit_candidates(e, frame, &candidates);
    return guard_divergence(e, frame->utime, result);
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
    /* The API reports the body-frame (right) perturbation: xi_r = Ad(T^-1) xi. */
    double P6[36], Ad[36], Rt[9], pinv[3], tmp[36];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            P6[6 * i + j] = e->P[(size_t)j * VL_LD + i];
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Rt[3 * i + j] = e->R[3 * j + i];
        }
    }
    vl_matmul(Rt, e->p, pinv, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        pinv[i] = -pinv[i];
    }
    vl_se3_adjoint(Rt, pinv, Ad);
    vl_matmul(Ad, P6, tmp, 6, 6, 6);
    vl_matmul_bt(tmp, Ad, out->covariance, 6, 6, 6);
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < i; ++j) {
            const double m = 0.5 * (out->covariance[6 * i + j] + out->covariance[6 * j + i]);
            out->covariance[6 * i + j] = out->covariance[6 * j + i] = m;
        }
    }
    for (int i = 0; i < 3; ++i) {
        out->linear_velocity[i] = e->held_linear[i] - e->offset_linear[i];
        out->angular_velocity[i] = e->held_angular[i] - e->offset_angular[i];
        out->linear_offset[i] = e->offset_linear[i];
        out->angular_offset[i] = e->offset_angular[i];
    }
    out->linear_velocity_noise = sqrt(e->linear_velocity_var);
    out->angular_velocity_noise = sqrt(e->angular_velocity_var);
    out->pixel_noise = sqrt(e->pixel_var);
    if (!vl_all_finite(out->rotation, 9) || !vl_all_finite(out->position, 3) || !vl_all_finite(out->covariance, 36) ||
        !vl_all_finite(out->linear_velocity, 3) || !vl_all_finite(out->angular_velocity, 3)) {
        return VL_ERR_NON_FINITE;
    }
    return VL_OK;
}

uint32_t vl_get_state_flags(const vl_estimator_t *e)
{
    if (e == NULL || !e->initialized) {
        return 0u;
    }
    return (e->have_imu ? 0u : VL_STATE_NO_CLOCK) | (e->imu_silent ? VL_STATE_IMU_SILENT : 0u);
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
