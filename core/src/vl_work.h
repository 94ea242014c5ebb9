/**
 * @file vl_work.h
 * @brief Counting the arithmetic of each stage of a step from the dimensions it
 *        used (vl_work_t; internal to core/). One call per stage, made where the
 *        stage runs; the formulas live in vl_work.c only.
 */
#ifndef VISLAM_VL_WORK_H
#define VISLAM_VL_WORK_H

#include "vislam/vislam.h"

/**
 * Flops of the joint update with k observations (m = 3k rows) on n states, as
 * vl_la_update does it; also what max_update_work bounds.
 */
uint64_t vl_work_joint_update(uint32_t n_states, uint32_t k_obs);

/**
 * The part of it that runs before the pose (vl_la_update_core): all but the landmark block's
 * downdate, plus the share of `pending` rows whose downdate is still to come.
 */
uint64_t vl_work_joint_update_core(uint32_t n_states, uint32_t k_obs, uint32_t pending);

/** The landmark block's downdate by `rows` pending rows on n states (counted as update). */
void vl_work_downdate(vl_estimator_t *e, uint32_t n, uint32_t rows);

/** Starts a vl_propagate or vl_update call: its work so far is zero. */
void vl_work_begin(vl_estimator_t *e);

/** A prediction step: the pose, P's core block and the deferred noise (O(1) in the state dimension);
 * coupled: the parameters (offsets, sensor position) couple in; decaying: the offsets' correlations fade. */
void vl_work_predict(vl_estimator_t *e, int coupled, int decaying);

/** The deferred prediction applied to an n-state P (moving: the landmark block changes, not mapping). */
void vl_work_settle(vl_estimator_t *e, uint32_t n, int moving);

/** The process noise of a repeated image shared by the carried landmarks (counted as prediction). */
void vl_work_repeat_noise(vl_estimator_t *e, uint32_t carried);

/** The carried landmarks' walk on n landmarks (vl_window_carried_walk). */
void vl_work_carried_walk(vl_estimator_t *e, uint32_t n);

/** The innovation gate of k observations. */
void vl_work_gate(vl_estimator_t *e, uint32_t k);

/** RANSAC over k observations with the given hypotheses, on an n-state joint covariance. */
void vl_work_ransac(vl_estimator_t *e, uint32_t n, uint32_t k, uint32_t hypotheses);

/** The joint update with k observations on n states up to the landmark block's downdate, then (adapted) the noise
 * adaptation over the k_frame rows it reads. */
void vl_work_update(vl_estimator_t *e, uint32_t n, uint32_t k, int adapted, uint32_t k_frame);

/** The stereo rows' white noise: a sample per observation and their capped mean (or median). */
void vl_work_stereo_rows(vl_estimator_t *e, uint32_t count);

/** The sparse frames' two-view velocity noise matching: the track lookup and the fit of pairs tracks. */
void vl_work_two_view(vl_estimator_t *e, uint32_t count, uint32_t previous, uint32_t pairs);

/** A sparse frame's tracks found moving on their own, carried over from the previous frame: the id lookup. */
void vl_work_drift_carry(vl_estimator_t *e, uint32_t count, uint32_t previous);

/** The rescue pass: checked observations re-linearized and gated, then the joint update of the rescued ones up to
 * the landmark block's downdate, against `pending` rows whose downdate is still to come. */
void vl_work_rescue(vl_estimator_t *e, uint32_t n, uint32_t checked, uint32_t rescued, uint32_t pending);

/** The deferred observations after the pose: checked re-linearized and gated, then the joint update of the used. */
void vl_work_deferred(vl_estimator_t *e, uint32_t n, uint32_t checked, uint32_t used);

/** The window: rows made for the frame's observations, marginalizations and admissions, on n states. */
void vl_work_window(vl_estimator_t *e, uint32_t n, uint32_t observations, uint32_t marginalized, uint32_t admitted);

#endif /* VISLAM_VL_WORK_H */
