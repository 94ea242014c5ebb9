/**
 * @file vl_stereo.h
 * @brief Stereo camera model: projection, its Jacobian and triangulation (internal to core/).
 *
 * The seed's model is z = M pi(q) with q a homogeneous point in the left camera's
 * optical frame, pi(q) = q / q_z and
 *     M = [[fx, 0, cx, 0], [0, fy, cy, 0], [fx, 0, cx, -fx b], [0, fy, cy, 0]].
 * Rows 2 and 4 of M are equal, so v_left and v_right carry the same function
 * of the state: the estimator uses the compressed observation
 * y = [u_left, (v_left + v_right) / 2, u_right] whose noise is diag(s^2, s^2/2, s^2).
 * This is exactly the information of the four-row update with V = s^2 I4 (the dropped
 * difference v_left - v_right holds no information on the state).
 */
#ifndef VISLAM_VL_STEREO_H
#define VISLAM_VL_STEREO_H

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/**
 * Compressed projection y = [u_left, v, u_right] of a point c (camera frame, m, c[2] > 0)
 * and its 3x3 row-major Jacobian dy/dc (may be NULL).
 */
void vl_stereo_project(const vl_calibration_t *cal, const double c[3], double y[3], double dy_dc[9]);

/** Compressed observation of a raw one: [u_left, (v_left + v_right) / 2, u_right]. */
void vl_stereo_compress(const vl_stereo_obs_t *obs, double y[3]);

/**
 * Triangulates the camera-frame point of a compressed observation y and gives
 * dc/dy (3x3 row-major, may be NULL). Needs disparity y[0] - y[2] > 0.
 */
void vl_stereo_triangulate(const vl_calibration_t *cal, const double y[3], double c[3], double dc_dy[9]);

/**
 * Noise variances of the compressed observation, diag(s^2, s^2/2, s^2), from the
 * variance s^2 of one pixel coordinate: the mean of v_left and v_right halves it.
 */
void vl_stereo_noise_var(double pixel_var, double noise_var[3]);

/** The full 4x4 stereo matrix M, row-major (for reference and tests). */
void vl_stereo_matrix(const vl_calibration_t *cal, double M[16]);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_VL_STEREO_H */
