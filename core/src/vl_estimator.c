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
#include "vl_guard.h"
#include "vl_linalg.h"
#include "vl_noise.h"
#include "vl_predict.h"
#include "vl_se3.h"
#include "vl_stereo.h"

/* Fewer tracked observations than this never count as a re-association. */
#define VL_MIN_ROWS_FOR_REASSOCIATION 8

/* Admission score bonus per frame of track age (frames seen before this one)... */
#define VL_ADMISSION_AGE_BONUS 0.5
/* ...counted up to this age: a track already seen 4 frames ranks at 3x its disparity. */
#define VL_ADMISSION_AGE_CAP 4u

typedef char vl_assert_capacity_positive[(VL_MAX_LANDMARKS >= 1) ? 1 : -1];
typedef char vl_assert_capacity_bounded[(VL_MAX_LANDMARKS <= 4096) ? 1 : -1];
typedef char vl_assert_frame_capacity[(VL_MAX_FRAME_FEATURES >= 1) ? 1 : -1];
typedef char vl_assert_pending_capacity[(VL_MAX_PENDING >= VL_MAX_FRAME_FEATURES) ? 1 : -1];

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

/* After an input was used: a diverged estimator restarts (VL_RESET), else result stands. */
static vl_status_t guard_divergence(vl_estimator_t *e, int64_t utime, vl_status_t result)
{
    if (!vl_guard_diverged(e)) {
        return result;
    }
    reset_state(e, 1);
    e->counters.divergence_resets++;
    vl_log_msg(e, VL_LOG_ERROR, utime, "estimator diverged; re-initialized with the same configuration");
    return VL_RESET;
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
    if (!vl_guard_imu_plausible(e, imu)) {
        e->counters.imu_rejected++;
        e->counters.imu_implausible++;
        vl_log_msg(e, VL_LOG_WARN, imu->utime, "IMU sample beyond max_speed or max_rotation_rate rejected");
        return VL_ERR_IMPLAUSIBLE;
    }
    vl_status_t result = VL_OK;
    if (e->have_imu) {
        const vl_status_t st = vl_guard_check_time(e, VL_INPUT_IMU, imu->utime);
        if (st != VL_OK) {
            if (!vl_guard_note_timeline(e, VL_INPUT_IMU, imu->utime)) {
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
        if (vl_guard_imu_silent_at(e, imu->utime)) {
            /* The held velocity is trusted for max_imu_silence; the motion after that
             * is unknown, so the clock jumps over it rather than invent it. */
            if (!e->imu_silent) {
                e->counters.imu_silences++;
            }
            vl_log_msg(e, VL_LOG_WARN, imu->utime,
                       "IMU back after a silence; the motion during it is not propagated");
            vl_predict_to(e, e->last_imu_utime + vl_limit_us(e->cfg.max_imu_silence));
            e->state_utime = imu->utime;
        } else {
            vl_predict_to(e, imu->utime);
        }
        vl_guard_time_passed(e, imu->utime);
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
        if (!vl_guard_observation_valid(o)) {
            e->counters.observations_invalid++;
            continue;
        }
        if (!vl_guard_observation_plausible(e, o)) {
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
        if (e->cfg.adaptive_noise && ++e->reassociated_run >= VL_NOISE_CONTRADICTION_RUN) {
            vl_noise_widen(e);
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
        vl_noise_adapt_pixel(e, rows, k);
        vl_noise_adapt_velocity(e, prior_diag);
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
    const vl_status_t time_st = vl_guard_check_time(e, VL_INPUT_FRAME, frame->utime);
    if (time_st != VL_OK) {
        /* A frame adds to a candidate timeline; the restart waits for an IMU sample to set the clock. */
        (void)vl_guard_note_timeline(e, VL_INPUT_FRAME, frame->utime);
        e->counters.frames_rejected++;
        if (time_st == VL_ERR_TIME_JUMP) {
            e->counters.time_jumps++;
            vl_log_msg(e, VL_LOG_WARN, frame->utime, "frame jumping in time rejected");
        } else {
            vl_log_msg(e, VL_LOG_WARN, frame->utime, "frame out of time order rejected");
        }
        return time_st;
    }
    vl_guard_time_passed(e, frame->utime);
    if (vl_guard_imu_silent_at(e, frame->utime)) {
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
    if (vl_guard_frame_repeats_previous(e, frame, count)) {
        e->counters.frames_repeated++;
    }
    e->num_prev_obs = count;
    memcpy(e->prev_obs, frame->obs, count * sizeof(vl_stereo_obs_t));
    vl_predict_to(e, frame->utime);
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
