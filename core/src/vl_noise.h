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

/**
 * Pixel noise from the post-fit residuals of the frame's rows after an update
 * that left its correction in e->work_dx: the rows it used (rows[0 .. used)) and
 * the rejected ones (rows[first_rejected .. k), outliers included). Inliers the
 * update deferred (rows[used .. first_rejected)) were not fitted, so their
 * residuals say nothing about the pixel noise.
 */
void vl_noise_adapt_pixel(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t used, uint32_t first_rejected,
                          uint32_t k);

/**
 * Velocity noise from the pose correction in e->work_dx against the pose
 * block's covariance before the update (prior_pose, the leading 6x6 block of P,
 * row-major); used is the number of observations the update fused (a dense
 * frame is matched in the body frame at a fixed gain, a sparse one in the world
 * frame at a gain weighted by what it told).
 */
void vl_noise_adapt_velocity(vl_estimator_t *e, const double prior_pose[36], uint32_t used);

/** A frame that contradicts the prior after others did: widens all three noise levels. */
void vl_noise_widen(vl_estimator_t *e);

#endif /* VISLAM_VL_NOISE_H */
