/**
 * @file vl_estimator_internal.h
 * @brief What every part of the estimator shares: the state layout, the
 *        per-frame landmark marks and a few small helpers (internal to core/).
 *
 * State order: [rho, phi (pose), linear offset, angular offset, velocity sensor
 * position, landmark 0, ...]. Offsets and sensor position are always present in
 * the layout; with estimate_input_offsets off, or a velocity_sensor_std_* at 0,
 * their covariance stays zero, so they never move. The covariance P is
 * column-major with leading dimension VL_LD; outside vl_predict.c it is
 * accessed through vl_P and vl_P_at only.
 */
#ifndef VISLAM_VL_ESTIMATOR_INTERNAL_H
#define VISLAM_VL_ESTIMATOR_INTERNAL_H

#include "vislam/vislam.h"

#include <assert.h>
#include <math.h>

/** Leading dimension of P and of the update workspaces. */
#define VL_LD VL_COV_LD

/** First state index of the pose translation error rho. */
#define VL_IDX_RHO 0
/** First state index of the pose rotation error phi. */
#define VL_IDX_PHI 3
/** First state index of the linear velocity offset. */
#define VL_IDX_OFFSET_LIN 6
/** First state index of the angular velocity offset. */
#define VL_IDX_OFFSET_ANG 9
/** First state index of the velocity sensor's position. */
#define VL_IDX_SENSOR 12
/** First state index of the parameters (offsets, then the sensor position). */
#define VL_IDX_PARAM VL_IDX_OFFSET_LIN

typedef char
    vl_assert_core_layout[(VL_IDX_SENSOR + 3 == VL_CORE_DIM && VL_IDX_PARAM + VL_PARAM_DIM == VL_CORE_DIM) ? 1 : -1];

/** What the current frame did to a window landmark (work_seen). */
typedef enum {
    VL_SEEN_NONE = 0,  /**< not observed in this frame */
    VL_SEEN = 1,       /**< observed (or admitted) in this frame */
    VL_SEEN_BROKEN = 2 /**< observed, contradicting it: a broken track, mapped and restarted */
} vl_seen_t;

/*
 * P is read and written through these. Between updates the prediction is
 * deferred (vl_predict.c): only the core block (pose and offsets) is current,
 * and the rest of P is stale until vl_predict_settle. The asserts (on in the
 * checked core the tests link) make a stale read fail where it happens.
 */

/** P, settled: for any reader or writer beyond the core block. */
static inline double *vl_P(vl_estimator_t *e)
{
    assert(e->deferred.steps == 0);
    return e->P;
}

/** vl_P for a reader. */
static inline const double *vl_P_const(const vl_estimator_t *e)
{
    assert(e->deferred.steps == 0);
    return e->P;
}

/** Element (row, col) of P: the core block at any time, the rest once settled. */
static inline double *vl_P_at(vl_estimator_t *e, uint32_t row, uint32_t col)
{
    assert((row < VL_CORE_DIM && col < VL_CORE_DIM) || e->deferred.steps == 0);
    return &e->P[(size_t)col * VL_LD + row];
}

/** vl_P_at for a reader. */
static inline double vl_P_value(const vl_estimator_t *e, uint32_t row, uint32_t col)
{
    assert((row < VL_CORE_DIM && col < VL_CORE_DIM) || e->deferred.steps == 0);
    return e->P[(size_t)col * VL_LD + row];
}

/** First state index of a window slot's landmark. */
static inline uint32_t vl_landmark_col(uint32_t slot)
{
    return VL_CORE_DIM + 3u * slot;
}

/** Window slot of the landmark whose block starts at state index col (vl_landmark_col's inverse). */
static inline uint32_t vl_landmark_slot_at(int col)
{
    return ((uint32_t)col - VL_CORE_DIM) / 3u;
}

/** World point of a window landmark, m. */
static inline const double *vl_landmark_point(const vl_estimator_t *e, uint32_t slot)
{
    return &e->landmark_state[3 * slot];
}

/** The frame's observation obs contradicts the landmark in slot: the landmark goes to the map
 * when the window retires it, and obs restarts its track (vl_window_admit). */
static inline void vl_track_break(vl_estimator_t *e, uint32_t slot, uint32_t obs)
{
    e->work_seen[slot] = VL_SEEN_BROKEN;
    e->work_broken[e->num_broken++] = obs;
}

/**
 * The velocity variance per axis, linear (m/s)^2 and angular (rad/s)^2, that moved the
 * pose since the last frame: the sensor's, or the unknown motion's across an IMU
 * silence (vl_predict_silence_to), which the checks of a track's motion then allow for.
 */
static inline void vl_step_velocity_var(const vl_estimator_t *e, double *linear, double *angular)
{
    *linear = e->unknown_motion ? e->unknown_motion_var[0] : e->linear_velocity_var;
    *angular = e->unknown_motion ? e->unknown_motion_var[1] : e->angular_velocity_var;
}

/** Hands a fixed message to the injected logger, if any. */
static inline void vl_log_msg(const vl_estimator_t *e, vl_log_level_t level, int64_t utime, const char *msg)
{
    if (e->cfg.log != NULL) {
        e->cfg.log(e->cfg.log_user, level, utime, msg);
    }
}

/** Nonzero when all n values are finite. */
static inline int vl_all_finite(const double *v, int n)
{
    for (int i = 0; i < n; ++i) {
        if (!isfinite(v[i])) {
            return 0;
        }
    }
    return 1;
}

/**
 * a - b in microseconds, saturated to the int64 range: input times come from
 * outside, and INT64_MIN or INT64_MAX must not overflow the subtraction.
 */
static inline int64_t vl_utime_diff(int64_t a, int64_t b)
{
    if (b < 0 && a > INT64_MAX + b) {
        return INT64_MAX;
    }
    if (b > 0 && a < INT64_MIN + b) {
        return INT64_MIN;
    }
    return a - b;
}

/** A configured time limit in microseconds (vl_config_check bounds it by VL_MAX_TIME_LIMIT s). */
static inline int64_t vl_limit_us(double seconds)
{
    return (int64_t)(seconds * 1e6);
}

#endif /* VISLAM_VL_ESTIMATOR_INTERNAL_H */
