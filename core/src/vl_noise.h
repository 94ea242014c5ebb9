/**
 * @file vl_noise.h
 * @brief Online adaptation of the velocity and pixel noise (internal to core/).
 *
 * The configured noise values are priors. Each adapted variance stays within
 * VL_NOISE_ADAPT_RANGE (of the std) of its configured value, either way.
 */
#ifndef VISLAM_VL_NOISE_H
#define VISLAM_VL_NOISE_H

#include "vislam/vislam.h"

#include "vl_linalg.h"

/** Adapted noise stays within this factor (of the std) of its configured value, either way. */
#define VL_NOISE_ADAPT_RANGE 100.0
/** Distrusted frames in a row from which the prior counts as overconfident. */
#define VL_NOISE_CONTRADICTION_RUN 2u
/** Observations from which a frame determines the pose on its own (48 rows for 6 unknowns): its
 * correction is then a sample of the pose error whatever the prior and the pixel noise say. */
#define VL_NOISE_DENSE_FRAME 16u
/** Rise of the adapted angular variance over its configured value (2x the std) from which the
 * angular offsets' covariance is reopened (vl_noise_reopen_angular_offset): above the adaptation's
 * own spread around a right prior (0.8 to 1.2x the std on 0027). */
#define VL_NOISE_REOPEN_RATIO 4.0
/** Bounds on what one frame's seen-to-expected correction ratio counts as. */
#define VL_VELOCITY_RATIO_MIN 0.1
#define VL_VELOCITY_RATIO_MAX 10.0
/** Median of the chi-square distribution with one degree of freedom: a median of squares to a variance. */
#define VL_NOISE_CHI2_1_MEDIAN 0.455

/**
 * Pixel noise from the post-fit residuals of the frame's rows after an update
 * that left its correction in e->work_dx: the rows it used (rows[0 .. used)) and
 * the rejected ones (rows[first_rejected .. k), outliers included). Inliers the
 * update deferred (rows[used .. first_rejected)) were not fitted, so their
 * residuals say nothing about the pixel noise. A sparse frame (by
 * frame_observations, the frame's own count) weighs each row against its
 * expected post-fit variance.
 */
void vl_noise_adapt_pixel(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t used, uint32_t first_rejected,
                          uint32_t k, uint32_t frame_observations);

/**
 * Velocity noise from the pose correction in e->work_dx against the pose
 * block's covariance before the update (prior_pose, the leading 6x6 block of P,
 * row-major); used is the number of observations the update fused (a dense
 * frame is matched in the body frame at a fixed gain, a sparse one in the world
 * frame at a gain weighted by what it told).
 */
void vl_noise_adapt_velocity(vl_estimator_t *e, const double prior_pose[36], uint32_t used);

/** A frame that contradicts the prior after others did: widens all three noise levels (x4 in
 * variance, up to 20x the configured std; a level already above that stays). */
void vl_noise_widen(vl_estimator_t *e);

/**
 * The angular offsets were learned at the angular noise of their time: under a noise too small,
 * each frame's rotation error counted as the offset's, and their variance shrank for it. When
 * the adapted angular variance rises past the highest it has been (at first
 * VL_NOISE_REOPEN_RATIO x the configured one) by a factor g, the angular offsets' rows and
 * columns of P scale by sqrt(g), each offset's variance up to its prior: the certainty earned
 * at the smaller noise is given back, and the correlations stay. Nothing without offset states.
 * The linear offsets are left alone: reopened alike they took up the vision's scale errors
 * again (README, Accuracy). Called after each change of the velocity noise; P settled.
 */
void vl_noise_reopen_angular_offset(vl_estimator_t *e);

/**
 * The stereo rows' white pixel noise (e->stereo_row_var, per coordinate) from the
 * frame's v_left - v_right: a rectified pair's two rows agree whatever the pose,
 * so their difference is pixel noise alone. Each frame's samples capped at 3
 * sigma of the estimate and averaged (the first frame's median starts it),
 * weighted by the evidence over VL_STEREO_ROW_MEMORY observations
 * (vl_noise_two_view.c).
 */
void vl_noise_observe_stereo_rows(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count);

/**
 * Velocity noise of a sparse frame (fewer than VL_NOISE_DENSE_FRAME
 * observations) from its tracks' two views, the previous frame's (e->prev_obs,
 * at the pose e->frame_R, e->frame_p) and this one's at the predicted pose,
 * before the update. Returns 1 when it matched (vl_noise_adapt_velocity then
 * leaves the frame alone), 0 when the frame is dense or gave too little. Sets
 * contradicted[i] (zeroed by the caller for the frame's count) for the
 * observations whose track alone contradicted the expected motion, and flags in
 * e->work_moved (zeroed likewise) those whose track moved against the others or
 * did so in the previous frame too (e->prev_contradicted).
 */
int vl_noise_adapt_velocity_two_view(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count,
                                     uint8_t *contradicted);

/**
 * Starts a sparse frame's drift sums (e->work_drift) empty, except that a track the previous
 * (sparse) frame found moving on its own stays so: it is not admitted again (so never used)
 * while its id lasts on sparse frames in a row. After the frame, vl_noise_keep_drift hands the
 * sums to the next one.
 */
void vl_noise_carry_drift(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count);

/** Keeps the frame's drift sums for the next frame (none after a dense frame). */
void vl_noise_keep_drift(vl_estimator_t *e);

/** Nonzero when the frame's observation obs is on a track found moving on its own (not to admit). */
int vl_noise_track_moving(const vl_estimator_t *e, uint32_t obs);

/* Shared by the adaptation rules. */

/** A variance kept within VL_NOISE_ADAPT_RANGE of its configured std, either way. */
double vl_noise_clamp_var(double var, double configured_std);

/** The k-th smallest of v[0..n) (0-based); reorders v. */
double vl_noise_select_kth(double *v, uint32_t n, uint32_t k);

/**
 * Step of a log-variance matched on a seen-to-expected spread ratio at k
 * effective degrees of freedom: log(ratio), ratio bounded, plus that logarithm's
 * bias, so that it averages zero when the filter is right.
 */
double vl_noise_log_ratio_step(double ratio, double k);

#endif /* VISLAM_VL_NOISE_H */
