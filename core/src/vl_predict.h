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

/** Whether the velocity sensor's position is estimated (a velocity_sensor_std_* above 0). */
int vl_predict_sensor_estimated(const vl_estimator_t *e);

/**
 * hat(p) of the velocity sensor's position p (its estimate, from velocity_sensor_x, _y, _z) in
 * @p skew: the body twist is T u with T = [I hat(p); 0 I], so the angular noise and offsets
 * reach the linear velocity through it. Returns 0, and leaves @p skew alone, when the sensor is
 * at the origin.
 */
int vl_predict_sensor_skew(const vl_estimator_t *e, double skew[9]);

/**
 * The velocity sensor's lever arm term p x w (p the sensor's estimated position in the body
 * frame): the body origin's velocity is the sensor's plus it (v_body = v - w x p); hat(p) in
 * @p skew when it is not NULL. @p out is zero, and the return 0, when the sensor is at the
 * origin.
 */
int vl_predict_lever_term(const vl_estimator_t *e, const double w[3], double out[3], double skew[9]);

/**
 * Propagates the state to utime across an IMU silence: with the held
 * velocities up to max_imu_silence after the last sample (vl_predict_to), and
 * from there, in slam mode, at the velocity between the last two frames
 * (e->frame_velocity), with 3 times the sensor's noise stds per axis plus the
 * turn rate on the angular ones, so that the frames carry the pose; without
 * that velocity the mean stays and the stds also take the held sample's speed
 * and turn rate. Sets e->unknown_motion and its variances.
 */
void vl_predict_silence_to(vl_estimator_t *e, int64_t utime);

/**
 * One prediction step's covariance: P's core block and the deferred
 * accumulators (e->deferred) move by the step with pose input Jacobian Gp
 * (6 x 6 row-major: G = -tau Ad(T) J_r, times T for a sensor off the origin)
 * and the parameters' pose rows Gt (6 x VL_PARAM_DIM row-major: the offsets'
 * columns, then the sensor position's; NULL when no parameter is estimated);
 * the landmark rows wait for vl_predict_settle. offset_var, the offsets' walk,
 * is NULL when the offsets are not estimated; decay (1: none) is the factor by
 * which the offsets' correlations with every other state fade over the step.
 */
void vl_predict_defer(vl_estimator_t *e, const double Gp[36], const double Gt[6 * VL_PARAM_DIM],
                      const double noise_var[6], const double offset_var[6], double decay);

/**
 * Applies the deferred prediction to the whole of P, which then equals the
 * step-by-step propagation (to rounding). Every entry point calls it once,
 * before anything beyond P's core block is read or written (vl_P asserts it);
 * nothing when no step is pending.
 */
void vl_predict_settle(vl_estimator_t *e);

/**
 * The covariance of a window landmark with the rotation error, settled or not:
 * the 6 x 6 row-major block over [phi, landmark], as vl_predict_settle would leave it.
 */
void vl_predict_landmark_block(const vl_estimator_t *e, uint32_t slot, double B[36]);

#endif /* VISLAM_VL_PREDICT_H */
