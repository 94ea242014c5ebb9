/**
 * @file vl_predict.h
 * @brief Prediction: the held IMU velocities carry the pose forward, the input
 *        noise widens the covariance (internal to core/).
 */
#ifndef VISLAM_VL_PREDICT_H
#define VISLAM_VL_PREDICT_H

#include "vislam/vislam.h"

/**
 * Propagates the state from state_utime to utime with the held velocities
 * (minus the estimated offsets); nothing when utime is not later. A gap over
 * max_propagation_dt is counted (time_gaps) and still propagated.
 */
void vl_predict_to(vl_estimator_t *e, int64_t utime);

/**
 * Propagates the state to the new sample's time across the interval from the
 * last sample (the state may already be part of the way, at a frame). With
 * interpolate_velocities the velocity is linear between the two samples,
 * otherwise the held sample applies (as vl_predict_to).
 */
void vl_predict_to_sample(vl_estimator_t *e, const vl_imu_sample_t *imu);

#endif /* VISLAM_VL_PREDICT_H */
