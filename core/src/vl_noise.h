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
 * Pixel noise from the post-fit residuals of every row of the frame (rows[0 .. k),
 * outliers included), after an update that left its correction in e->work_dx.
 */
void vl_noise_adapt_pixel(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k);

/**
 * Velocity noise from the pose correction in e->work_dx against the pose
 * block's variance before the update (prior_diag, the first six diagonal entries).
 */
void vl_noise_adapt_velocity(vl_estimator_t *e, const double prior_diag[6]);

/** A frame that contradicts the prior after others did: widens all three noise levels. */
void vl_noise_widen(vl_estimator_t *e);

#endif /* VISLAM_VL_NOISE_H */
