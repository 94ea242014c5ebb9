/**
 * @file vl_guard.h
 * @brief The checks that keep bad inputs and a diverged state from ending the
 *        estimator's usefulness: the time policy and new timelines, IMU silence,
 *        plausibility, repeated frames, divergence (internal to core/).
 *
 * Every function here decides or records; the counters and the reactions stay
 * with the caller.
 */
#ifndef VISLAM_VL_GUARD_H
#define VISLAM_VL_GUARD_H

#include "vislam/vislam.h"

/** Which kind of input the time policy judges. */
typedef enum { VL_INPUT_IMU, VL_INPUT_FRAME } vl_input_kind_t;

/**
 * The time policy (the first IMU sample sets the clock without it): an input
 * farther than max_time_jump from the clock, either way, is VL_ERR_TIME_JUMP;
 * otherwise each kind must move forward (VL_ERR_TIME_ORDER).
 */
vl_status_t vl_guard_check_time(const vl_estimator_t *e, vl_input_kind_t kind, int64_t utime);

/** An input passed the time policy: the clock follows it and no new timeline is pending. */
void vl_guard_time_passed(vl_estimator_t *e, int64_t utime);

/**
 * Records a time-refused input in the candidate new timeline.
 * @return nonzero when the candidate has new_timeline_samples inputs
 */
int vl_guard_note_timeline(vl_estimator_t *e, vl_input_kind_t kind, int64_t utime);

/** Is utime more than max_imu_silence after the last IMU sample? */
int vl_guard_imu_silent_at(const vl_estimator_t *e, int64_t utime);

/** Speed and rotation rate within max_speed and max_rotation_rate. */
int vl_guard_imu_plausible(const vl_estimator_t *e, const vl_imu_sample_t *imu);

/** Valid before any use: finite pixels and a non-negative id. */
int vl_guard_observation_valid(const vl_stereo_obs_t *o);

/** Physically possible: inside the image widened by image_margin, disparity within max_disparity. */
int vl_guard_observation_plausible(const vl_estimator_t *e, const vl_stereo_obs_t *o);

/** Does the frame (its first count observations) repeat the previous frame's pixels exactly? */
int vl_guard_frame_repeats_previous(const vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count);

/** Is the state diverged (non-finite, an impossible covariance, or too many failed updates in a row)? */
int vl_guard_diverged(const vl_estimator_t *e);

/**
 * Whether the symmetric n x n block B (column-major, leading dimension ld) passes the
 * divergence check's covariance conditions: a finite, non-negative diagonal and
 * |B_ij| <= sqrt(B_ii B_jj) (necessary for positive semi-definiteness).
 */
int vl_guard_block_sound(const double *B, uint32_t n, size_t ld);

#endif /* VISLAM_VL_GUARD_H */
