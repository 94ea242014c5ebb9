/*
 * The estimator: the public API, and the algorithm as a sequence of steps whose
 * parts live beside this file: prediction (vl_predict), the landmark window
 * (vl_window), outlier handling (vl_outliers), the update (vl_update), the noise
 * adaptation (vl_noise) and the guards on inputs and state (vl_guard), with the
 * stereo rig at the current pose in vl_camera.
 *
 * An IMU sample: checks, prediction to its time (P's core block only: the rest
 * waits, vl_predict.c), then it is held. A frame: checks, prediction to its
 * time and the waiting prediction applied to all of P, its observations sorted
 * into update rows and admission candidates, the rows fused (gate, re-association, RANSAC, the joint
 * update, noise adaptation, rescue), ended and broken tracks retired to the map,
 * the candidates admitted. After every used input, the divergence guard.
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

#include "vl_estimator_internal.h"
#include "vl_guard.h"
#include "vl_linalg.h"
#include "vl_noise.h"
#include "vl_outliers.h"
#include "vl_predict.h"
#include "vl_se3.h"
#include "vl_update.h"
#include "vl_window.h"
#include "vl_work.h"

typedef char vl_assert_capacity_positive[(VL_MAX_LANDMARKS >= 1) ? 1 : -1];
typedef char vl_assert_capacity_bounded[(VL_MAX_LANDMARKS <= 4096) ? 1 : -1];
typedef char vl_assert_frame_capacity[(VL_MAX_FRAME_FEATURES >= 1) ? 1 : -1];
typedef char vl_assert_pending_capacity[(VL_MAX_PENDING >= VL_MAX_FRAME_FEATURES) ? 1 : -1];

/* ---------------------------------------------------------------- life cycle */

/*
 * The last vl_update's work after its pose: the landmark block's downdate, then the
 * window's upkeep (tracks that ended or broke leave for the map, then admissions,
 * best first), which read P current. Neither moves the pose nor its covariance.
 */
static void complete_frame(vl_estimator_t *e)
{
    if (!e->frame_open) {
        return;
    }
    e->frame_open = 0;
    vl_work_downdate(e, vl_state_dim(e), e->pending_cols);
    vl_update_downdate(e);
    const uint64_t marginalized_before = e->counters.landmarks_marginalized;
    const uint64_t admitted_before = e->counters.landmarks_initialized;
    vl_window_retire(e);
    vl_window_admit(e, e->prev_obs, &e->work_candidates);
    vl_work_window(e, vl_state_dim(e), 0u, (uint32_t)(e->counters.landmarks_marginalized - marginalized_before),
                   (uint32_t)(e->counters.landmarks_initialized - admitted_before));
}

/* The pose, the parameters and the core block of P now become what a divergence goes back to. */
static void keep_sound(vl_estimator_t *e)
{
    memcpy(e->sound_R, e->R, sizeof(e->sound_R));
    memcpy(e->sound_p, e->p, sizeof(e->sound_p));
    memcpy(&e->sound_param[0], e->offset_linear, 3 * sizeof(double));
    memcpy(&e->sound_param[3], e->offset_angular, 3 * sizeof(double));
    memcpy(&e->sound_param[6], e->sensor_position, 3 * sizeof(double));
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        memcpy(&e->sound_P[VL_CORE_DIM * j], vl_P_at(e, 0, j), VL_CORE_DIM * sizeof(double));
    }
}

/* The state vl_init gives: identity pose, empty window, configured noise; counters zero. */
static void init_state(vl_estimator_t *e, const vl_config_t *cfg)
{
    memset(e, 0, offsetof(vl_estimator_t, P));
    e->num_held = 0; /* past P, with the workspaces */
    e->frame_open = 0;
    e->pending_cols = 0;
    e->work_candidates.count = 0;
    e->cfg = *cfg;
    static const double I3[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(e->R, I3, sizeof(I3));
    /* Only the leading core block is live at start; the rest is written as landmarks arrive. */
    for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
        memset(&vl_P(e)[(size_t)j * VL_LD], 0, VL_CORE_DIM * sizeof(double));
    }
    if (cfg->estimate_input_offsets) {
        for (int i = 0; i < 3; ++i) {
            *vl_P_at(e, VL_IDX_OFFSET_LIN + i, VL_IDX_OFFSET_LIN + i) =
                cfg->linear_offset_prior * cfg->linear_offset_prior;
            *vl_P_at(e, VL_IDX_OFFSET_ANG + i, VL_IDX_OFFSET_ANG + i) =
                cfg->angular_offset_prior * cfg->angular_offset_prior;
        }
    }
    const double sensor[3] = {cfg->velocity_sensor_x, cfg->velocity_sensor_y, cfg->velocity_sensor_z};
    const double sensor_std[3] = {cfg->velocity_sensor_std_x, cfg->velocity_sensor_std_y, cfg->velocity_sensor_std_z};
    for (int i = 0; i < 3; ++i) {
        e->sensor_position[i] = sensor[i];
        *vl_P_at(e, VL_IDX_SENSOR + i, VL_IDX_SENSOR + i) = sensor_std[i] * sensor_std[i];
    }
    e->linear_velocity_var = cfg->linear_velocity_noise * cfg->linear_velocity_noise;
    e->angular_velocity_var = cfg->angular_velocity_noise * cfg->angular_velocity_noise;
    e->pixel_var = cfg->pixel_noise * cfg->pixel_noise;
    e->angular_velocity_var_reopened = VL_NOISE_REOPEN_RATIO * e->angular_velocity_var;
    keep_sound(e); /* a divergence before any input passed goes back here */
    e->initialized = 1;
}

/*
 * Back to vl_init's state with the same configuration, counters kept. A new
 * timeline (and vl_reset) ends the world the window's landmarks were estimated
 * in: they go to the sink first, in that world, as at the end of a run. After a
 * divergence they are corrupt and are dropped (landmarks_discarded), not mapped.
 * After a divergence (keep_world) the inputs that follow continue
 * as before: the time bookkeeping and the held IMU sample are kept, and so is
 * the world frame, the estimator starting at the last sound pose (before the
 * input that diverged; that input's motion is lost) with the input offsets
 * and the velocity sensor's position then, and the core block of P then when
 * the saved copy still passes the check (else the pose certain and those at
 * their prior, as at vl_init). They are the sensor's and outlast the divergence; the adapted noise
 * restarts from the configured values, since it may be what let the estimate
 * go. A new timeline (and vl_reset) starts a new world at the identity and the
 * clock afresh.
 */
static void reset_state(vl_estimator_t *e, int keep_world)
{
    if (!keep_world) {
        (void)vl_flush_landmarks(e);
    }
    vl_rows_drop_held(e);          /* they measure the pose this reset leaves */
    const vl_estimator_t *old = e; /* the fields are copied out before init_state clears them */
    const vl_config_t cfg = old->cfg;
    vl_counters_t counters = old->counters;
    const vl_work_t work = old->work; /* a reset inside a call keeps what the call did */
    counters.landmarks_discarded += old->num_landmarks;
    counters.resets++;
    const int have_imu = old->have_imu, have_frame = old->have_frame, imu_silent = old->imu_silent;
    const int64_t state_utime = old->state_utime, last_imu = old->last_imu_utime;
    const int64_t last_frame = old->last_frame_utime, clock = old->clock_utime;
    double held_linear[3], held_angular[3];
    memcpy(held_linear, old->held_linear, sizeof(held_linear));
    memcpy(held_angular, old->held_angular, sizeof(held_angular));
    const int held_trusted = old->held_trusted;
    double sound_R[9], sound_p[3], sound_param[VL_PARAM_DIM], sound_P[VL_CORE_DIM * VL_CORE_DIM];
    memcpy(sound_R, old->sound_R, sizeof(sound_R));
    memcpy(sound_p, old->sound_p, sizeof(sound_p));
    memcpy(sound_param, old->sound_param, sizeof(sound_param));
    memcpy(sound_P, old->sound_P, sizeof(sound_P));
    init_state(e, &cfg);
    e->counters = counters;
    e->work = work;
    if (keep_world) {
        e->have_imu = have_imu;
        e->have_frame = have_frame;
        e->imu_silent = imu_silent;
        e->state_utime = state_utime;
        e->last_imu_utime = last_imu;
        e->last_frame_utime = last_frame;
        e->clock_utime = clock;
        memcpy(e->held_linear, held_linear, sizeof(held_linear));
        memcpy(e->held_angular, held_angular, sizeof(held_angular));
        e->held_trusted = held_trusted;
        memcpy(e->R, sound_R, sizeof(sound_R));
        memcpy(e->p, sound_p, sizeof(sound_p));
        if (vl_guard_block_sound(sound_P, VL_CORE_DIM, VL_CORE_DIM) && vl_all_finite(sound_param, VL_PARAM_DIM)) {
            memcpy(e->offset_linear, &sound_param[0], 3 * sizeof(double));
            memcpy(e->offset_angular, &sound_param[3], 3 * sizeof(double));
            memcpy(e->sensor_position, &sound_param[6], 3 * sizeof(double));
            for (uint32_t j = 0; j < VL_CORE_DIM; ++j) {
                memcpy(vl_P_at(e, 0, j), &sound_P[VL_CORE_DIM * j], VL_CORE_DIM * sizeof(double));
            }
        }
        keep_sound(e);
    }
}

vl_status_t vl_init_checked(vl_estimator_t *e, const vl_config_t *cfg, size_t estimator_size, size_t config_size,
                            size_t frame_size, uint32_t max_landmarks, uint32_t layout)
{
    if (e == NULL || cfg == NULL) {
        return VL_ERR_NULL;
    }
    /* Before anything reads cfg or writes e: the caller's copies may be smaller than ours. */
    if (estimator_size != sizeof(vl_estimator_t) || config_size != sizeof(vl_config_t) ||
        frame_size != sizeof(vl_stereo_frame_t) || max_landmarks != VL_MAX_LANDMARKS || layout != vl_abi_layout()) {
        return VL_ERR_ABI_MISMATCH;
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

/*
 * After an input was used: a diverged estimator restarts in its world (VL_RESET,
 * see reset_state), else result stands and the pose with its covariance is the
 * sound one a later divergence goes back to. When an IMU sample led there, the
 * sample does not carry the motion on: the motion restarts at the next sample.
 */
static vl_status_t guard_divergence(vl_estimator_t *e, vl_input_kind_t kind, int64_t utime, vl_status_t result)
{
    if (!vl_guard_diverged(e)) {
        keep_sound(e);
        return result;
    }
    reset_state(e, 1);
    if (kind == VL_INPUT_IMU) {
        e->held_trusted = 0;
    }
    e->counters.divergence_resets++;
    vl_log_msg(e, VL_LOG_ERROR, utime,
               "estimator diverged; re-initialized with the same configuration at the pose before this input");
    return VL_RESET;
}

/* An input the time policy refused (st): counted and logged, and st returned. */
static vl_status_t refuse_time(vl_estimator_t *e, vl_input_kind_t kind, int64_t utime, vl_status_t st)
{
    const int imu = kind == VL_INPUT_IMU;
    if (imu) {
        e->counters.imu_rejected++;
    } else {
        e->counters.frames_rejected++;
    }
    if (st == VL_ERR_TIME_JUMP) {
        e->counters.time_jumps++;
        vl_log_msg(e, VL_LOG_WARN, utime,
                   imu ? "IMU sample jumping in time rejected" : "frame jumping in time rejected");
    } else {
        vl_log_msg(e, VL_LOG_WARN, utime,
                   imu ? "IMU sample out of time order rejected" : "frame out of time order rejected");
    }
    return st;
}

/* ---------------------------------------------------------------- prediction */

vl_status_t vl_propagate(vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    if (e == NULL || imu == NULL) {
        return VL_ERR_NULL;
    }
    vl_work_begin(e);
    complete_frame(e);
    vl_rows_drop_held(e); /* rows of the previous frame's pose, which this input moves on from */
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
                return refuse_time(e, VL_INPUT_IMU, imu->utime, st);
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
            /* The held velocity is trusted for max_imu_silence; after that no stale
             * velocity is integrated: in slam mode the frames' own motion carries on,
             * and the covariance takes what is not known. */
            if (!e->imu_silent) {
                e->counters.imu_silences++;
            }
            vl_log_msg(e, VL_LOG_WARN, imu->utime,
                       "IMU back after a silence; no stale velocity integrated, the covariance took the motion");
            vl_predict_silence_to(e, imu->utime);
        } else {
            vl_predict_to_sample(e, imu);
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
    e->held_trusted = 1;
    e->last_imu_utime = imu->utime;
    e->counters.imu_accepted++;
    return guard_divergence(e, VL_INPUT_IMU, imu->utime, result);
}

/* ---------------------------------------------------------------- update */

/*
 * The joint update on rows[0, used), then the noise adaptation from it: the used
 * rows and the rejected ones, rows[partitioned, k) (the inliers between were
 * deferred by the time bound); count is the frame's observations.
 */
static vl_status_t update_and_adapt(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t used, uint32_t partitioned,
                                    uint32_t k, uint32_t count)
{
    double prior_pose[36]; /* read by the adaptation only */
    for (uint32_t i = 0; i < 6 && e->cfg.adaptive_noise; ++i) {
        for (uint32_t j = 0; j < 6; ++j) {
            prior_pose[6 * i + j] = *vl_P_at(e, i, j);
        }
    }
    const vl_status_t st = vl_update_apply(e, rows, used);
    const int adapt = st == VL_OK && used > 0 && e->cfg.adaptive_noise;
    vl_work_update(e, vl_state_dim(e), used, adapt, used + (k - partitioned));
    if (adapt) {
        vl_noise_adapt_pixel(e, rows, used, partitioned, k, count);
        if (!e->unknown_motion) { /* across an IMU silence the correction is not the sensor's noise */
            vl_noise_adapt_velocity(e, prior_pose, used);
        }
    }
    return st;
}

/*
 * Fuses the frame's k update rows (of its count observations): the gate; a
 * re-associated frame is distrusted as a whole; otherwise RANSAC picks the
 * inliers, the joint update runs on them (at most max_update_observations), the
 * noise adapts, and the rejected rows that agree with the corrected state are
 * rescued in a second update.
 */
static vl_status_t fuse_rows(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count, uint32_t k)
{
    vl_la_obs_t *rows = e->work_rows;
    if (k == 0) {
        return VL_OK;
    }
    const uint32_t n = vl_state_dim(e);
    if (e->cfg.gate_chi2 <= 0.0) {
        return update_and_adapt(e, rows, k, k, k, count); /* no outlier rejection at all (the seed's plain EKF) */
    }
    const uint32_t contradicting = vl_outliers_gate(e, rows, k);
    vl_work_gate(e, k);
    /* Across an IMU silence the predicted motion is a guess: a frame that contradicts it
     * says the guess was wrong, and RANSAC finds what the frame does say. */
    if (!e->unknown_motion && vl_outliers_reassociated(e, k, contradicting)) {
        /* Most tracks contradict the state at once: the tracker re-associated its
         * ids (it does so when it detects new features). None of these
         * observations is trusted; every observed landmark restarts. */
        e->counters.frames_reassociated++;
        e->counters.observations_gated += k;
        vl_outliers_break_all(e, k);
        if (e->cfg.adaptive_noise && ++e->reassociated_run >= VL_NOISE_CONTRADICTION_RUN) {
            vl_noise_widen(e);
        }
        return VL_OK;
    }
    e->reassociated_run = 0;
    if (e->cfg.ransac_hypotheses > 0 && k >= 2) {
        vl_outliers_ransac(e, rows, k);
        vl_work_ransac(e, n, k, e->cfg.ransac_hypotheses < k ? e->cfg.ransac_hypotheses : k);
    }
    const uint32_t partitioned = vl_outliers_partition(e, rows, k);
    const uint32_t rest = k - partitioned;
    /* One cap for both updates: the state size does not change between them. */
    const uint32_t cap = vl_rows_cap(e);
    const uint32_t inliers = vl_rows_limit(e, rows, partitioned, cap);
    vl_rows_hold(e, inliers, partitioned);
    vl_status_t st = update_and_adapt(e, rows, inliers, partitioned, k, count);
    if (st != VL_OK || rest == 0) {
        e->counters.observations_gated += rest;
        return st;
    }
    uint32_t rescued = vl_outliers_rescue(e, frame, rows, partitioned, rest);
    e->counters.observations_rescued += rescued;
    e->counters.observations_gated += rest - rescued;
    if (cap > 0 && inliers + rescued > cap) {
        e->counters.observations_deferred += inliers + rescued - cap;
        vl_rows_hold(e, cap - inliers, rescued);
        rescued = cap - inliers;
    }
    vl_work_rescue(e, n, rest, rescued, e->pending_cols);
    return vl_update_apply(e, rows, rescued);
}

/* The body-frame velocity from the previous frame's pose to this one's, over dt seconds; only
 * in slam mode do the frames move the pose (elsewhere it would be the prediction's own). */
static void note_frame_velocity(vl_estimator_t *e, double dt, int had_frame)
{
    e->have_frame_velocity = 0;
    if (!had_frame || e->cfg.mode != VL_MODE_SLAM || !(dt > 0.0)) {
        return;
    }
    double dR[9], d[3], t[3], xi[6];
    vl_matmul_at(e->frame_R, e->R, dR, 3, 3, 3);
    for (int i = 0; i < 3; ++i) {
        d[i] = e->p[i] - e->frame_p[i];
    }
    vl_matmul_at(e->frame_R, d, t, 3, 3, 1);
    vl_se3_log(dR, t, xi);
    for (int i = 0; i < 6; ++i) {
        e->frame_velocity[i] = xi[i] / dt;
    }
    e->have_frame_velocity = 1;
}

vl_status_t vl_update(vl_estimator_t *e, const vl_stereo_frame_t *frame)
{
    if (e == NULL || frame == NULL) {
        return VL_ERR_NULL;
    }
    vl_work_begin(e);
    complete_frame(e);
    vl_rows_drop_held(e);
    if (!e->initialized || !e->have_imu) {
        if (e->initialized) {
            e->counters.frames_rejected++;
        }
        return VL_ERR_NOT_READY;
    }
    e->innovation_nis = 0.0; /* until this frame's updates add theirs */
    e->innovation_rows = 0;
    const vl_status_t time_st = vl_guard_check_time(e, VL_INPUT_FRAME, frame->utime);
    if (time_st != VL_OK) {
        /* A frame adds to a candidate timeline; the restart waits for an IMU sample to set the clock. */
        (void)vl_guard_note_timeline(e, VL_INPUT_FRAME, frame->utime);
        return refuse_time(e, VL_INPUT_FRAME, frame->utime, time_st);
    }
    vl_guard_time_passed(e, frame->utime);
    /* Past max_imu_silence no velocity moves the pose: in slam mode the frames carry it
     * (their landmarks against the widened covariance); the other modes have nothing
     * else to move it with, and refuse them. Degraded either way until the IMU returns. */
    const int silent = vl_guard_imu_silent_at(e, frame->utime);
    if (silent) {
        e->counters.frames_imu_silent++;
        if (!e->imu_silent) {
            e->imu_silent = 1;
            e->counters.imu_silences++;
            vl_log_msg(e, VL_LOG_WARN, frame->utime,
                       e->cfg.mode == VL_MODE_SLAM ? "IMU silent longer than max_imu_silence; the frames carry the pose"
                                                   : "IMU silent longer than max_imu_silence; frames refused");
        }
        if (e->cfg.mode != VL_MODE_SLAM) {
            e->counters.frames_rejected++;
            return VL_ERR_IMU_SILENT;
        }
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

    /* Counted, and still used: a repeated image is the tracker's detection frame. Its
     * new tracks are seen where the vehicle is; its carried ones resume at points the
     * step displaced (vl_window_repeat_noise). Skipping repeated frames measured worse
     * on every density of the real drives. */
    const int repeated = vl_guard_frame_repeats_previous(e, frame, count);
    if (repeated) {
        e->counters.frames_repeated++;
    }
    const int had_frame = e->have_frame;

    /* 1. Predict to the frame; the steps since the last frame reach the whole of P. */
    if (silent) {
        vl_predict_silence_to(e, frame->utime);
    } else {
        vl_predict_to(e, frame->utime);
    }
    vl_predict_settle(e);
    /* A sparse frame's velocity noise is matched on its tracks' two views before the update;
     * a repeated image, or one after it, shows one step of motion where the clock shows two. */
    e->velocity_matched = 0;
    memset(e->work_moved, 0, count);
    uint8_t contradicted[VL_MAX_FRAME_FEATURES];
    memset(contradicted, 0, count);
    vl_noise_carry_drift(e, frame, count);
    if (e->cfg.adaptive_noise && e->cfg.mode == VL_MODE_SLAM) {
        vl_noise_observe_stereo_rows(e, frame, count);
        if (had_frame && !repeated && !e->prev_frame_repeated && !e->unknown_motion) {
            e->velocity_matched = vl_noise_adapt_velocity_two_view(e, frame, count, contradicted);
        }
    }
    e->step_noise_time2 = 0.0;
    e->step_time = 0.0;
    memset(e->step_turn, 0, sizeof(e->step_turn));
    e->prev_frame_repeated = repeated;
    e->num_prev_obs = count;
    memcpy(e->prev_obs, frame->obs, count * sizeof(vl_stereo_obs_t));
    memcpy(e->prev_contradicted, contradicted, count);
    vl_noise_keep_drift(e);
    const double frame_dt = e->have_frame ? (double)vl_utime_diff(frame->utime, e->last_frame_utime) * 1e-6 : 0.0;
    e->last_frame_utime = frame->utime;
    e->have_frame = 1;
    e->frame_index++;
    e->counters.frames_accepted++;
    if (e->cfg.mode == VL_MODE_IMU_ONLY) {
        e->unknown_motion = 0;
        return guard_divergence(e, VL_INPUT_FRAME, frame->utime, result);
    }

    /* 2. Observations of window landmarks become rows; the others feed the candidates. */
    memset(e->work_seen, VL_SEEN_NONE, sizeof(e->work_seen));
    e->num_broken = 0;
    e->work_candidates.count = 0;
    if (e->cfg.repeat_track_walk > 0.0) {
        vl_work_carried_walk(e, vl_window_carried_walk(e));
        if (repeated && had_frame) {
            vl_window_mark_carried(e, frame, count);
        }
    }
    if (repeated && had_frame && e->cfg.repeat_anchor_noise > 0.0) {
        vl_work_repeat_noise(e, vl_window_repeat_noise(e, frame, count));
    }
    const uint32_t k = vl_window_classify(e, frame, count, frame_dt, &e->work_candidates);
    vl_work_window(e, vl_state_dim(e), count, 0u, 0u);

    /* 3. Outlier rejection and the joint update. */
    const uint64_t reassociated_before = e->counters.frames_reassociated;
    const uint64_t used_before = e->counters.observations_used;
    const vl_status_t st = fuse_rows(e, frame, count, k);
    if (st != VL_OK) {
        vl_log_msg(e, VL_LOG_ERROR, frame->utime, "innovation covariance not positive definite; update refused");
        result = st;
        vl_rows_drop_held(e); /* nothing after a refused update */
    }
    /* A frame whose update was refused or contradicted the state extends the run;
     * one that corrected the state ends it; one with nothing to use leaves it. */
    if (st != VL_OK || e->counters.frames_reassociated != reassociated_before) {
        e->failed_frame_run++;
    } else if (e->counters.observations_used != used_before) {
        e->failed_frame_run = 0;
    }

    /* 4. The pose is final. The landmark block's downdate and the window's upkeep (tracks
     * that ended or broke leave for the map, admissions) come after it: complete_frame. */
    e->frame_open = 1;
    note_frame_velocity(e, frame_dt, had_frame);
    memcpy(e->frame_R, e->R, sizeof(e->R));
    memcpy(e->frame_p, e->p, sizeof(e->p));
    e->unknown_motion = 0; /* the frame's adaptation has seen it */
    return guard_divergence(e, VL_INPUT_FRAME, frame->utime, result);
}

vl_status_t vl_update_deferred(vl_estimator_t *e)
{
    if (e == NULL) {
        return VL_ERR_NULL;
    }
    if (!vl_deferred_due(e)) {
        return VL_OK; /* the last step's work stays readable */
    }
    vl_work_begin(e);
    complete_frame(e);
    if (e->num_held == 0) {
        return VL_OK;
    }
    const uint32_t n = vl_state_dim(e);
    const uint32_t checked = e->num_held;
    const uint32_t k = vl_rows_from_held(e);
    e->num_held = 0;
    vl_work_deferred(e, n, checked, k);
    /* The innovation ratio stays the frame's own, as its pose carried it. */
    const double nis = e->innovation_nis;
    const uint32_t rows = e->innovation_rows;
    const vl_status_t st = vl_update_apply(e, e->work_rows, k);
    vl_update_downdate(e);
    e->innovation_nis = nis;
    e->innovation_rows = rows;
    if (st != VL_OK) {
        vl_log_msg(e, VL_LOG_ERROR, e->last_frame_utime,
                   "innovation covariance not positive definite; deferred update refused");
        e->counters.observations_deferred_dropped += k;
    } else {
        e->counters.observations_deferred_used += k;
    }
    return guard_divergence(e, VL_INPUT_FRAME, e->last_frame_utime, st);
}

uint32_t vl_deferred_pending(const vl_estimator_t *e)
{
    return e == NULL ? 0u : e->num_held;
}

int vl_deferred_due(const vl_estimator_t *e)
{
    return e != NULL && (e->frame_open || e->num_held > 0);
}

/* ---------------------------------------------------------------- output */

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
    double P6[36], Ad[36], tmp[36];
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            P6[6 * i + j] = vl_P_value(e, (uint32_t)i, (uint32_t)j);
        }
    }
    vl_se3_adjoint_inverse(e->R, e->p, Ad);
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
        out->velocity_sensor[i] = e->sensor_position[i];
    }
    double turn[3];
    if (vl_predict_lever_term(e, out->angular_velocity, turn, NULL)) { /* the body origin's velocity */
        for (int i = 0; i < 3; ++i) {
            out->linear_velocity[i] += turn[i];
        }
    }
    out->linear_velocity_noise = sqrt(e->linear_velocity_var);
    out->angular_velocity_noise = sqrt(e->angular_velocity_var);
    out->pixel_noise = sqrt(e->pixel_var);
    out->innovation_ratio = e->innovation_rows > 0 ? e->innovation_nis / (double)e->innovation_rows : 0.0;
    out->innovation_rows = e->innovation_rows;
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
        vl_window_landmark(e, (uint32_t)s, &out[s]);
    }
    return (capacity < e->num_landmarks) ? VL_ERR_CAPACITY : VL_OK;
}

vl_status_t vl_flush_landmarks(vl_estimator_t *e)
{
    if (e == NULL) {
        return VL_ERR_NULL;
    }
    complete_frame(e);
    vl_predict_settle(e);
    /* Marginalize from the end so no block moves. */
    while (e->num_landmarks > 0) {
        vl_window_marginalize(e, e->num_landmarks - 1u);
    }
    return VL_OK;
}

void vl_get_work(const vl_estimator_t *e, vl_work_t *out)
{
    if (out == NULL) {
        return;
    }
    if (e == NULL) {
        memset(out, 0, sizeof(*out));
        return;
    }
    *out = e->work;
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
