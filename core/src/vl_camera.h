/**
 * @file vl_camera.h
 * @brief The stereo rig at the current pose: world points into the camera and
 *        back, and the length of a 3-row innovation (internal to core/).
 */
#ifndef VISLAM_VL_CAMERA_H
#define VISLAM_VL_CAMERA_H

#include "vislam/vislam.h"

/** A point nearer the camera plane than this, m, counts as behind the camera. */
#define VL_MIN_CAMERA_DEPTH 1e-3

/** cam_T_imu as rotation Rc (row-major) and translation tc. */
void vl_camera_extrinsics(const vl_calibration_t *cal, double Rc[9], double tc[3]);

/**
 * A world point in the IMU frame (b = R^T (p_w - p)) and the left camera frame
 * (c = Rc b + tc). Returns 0 when it is in front of the camera, -1 otherwise.
 */
int vl_camera_point(const vl_estimator_t *e, const double Rc[9], const double tc[3], const double pw[3], double b[3],
                    double c[3]);

/**
 * Predicted compressed observation y of a world point, d y / d xi (pose, 3x6
 * row-major, right perturbation) and d y / d p_w (3x3). Returns 0 when the point
 * is in front of the camera, -1 otherwise.
 */
int vl_camera_project_world(const vl_estimator_t *e, const double pw[3], double y[3], double H_pose[18],
                            double dy_dpw[9]);

/**
 * Triangulates a compressed observation y (disparity > 0) at the pose (R, p):
 * the world point pw = R b + p with b the point in the IMU frame, and
 * d pw / d y = R Rc^T dc/dy (3x3 row-major).
 */
void vl_camera_triangulate_at(const vl_estimator_t *e, const double R[9], const double p[3], const double y[3],
                              double pw[3], double dpw_dy[9]);

/** vl_camera_triangulate_at the current pose. */
void vl_camera_triangulate_world(const vl_estimator_t *e, const double y[3], double pw[3], double dpw_dy[9]);

/** Squared Mahalanobis length r^T S^-1 r of a 3-vector; a non-SPD S gives infinity. */
double vl_mahalanobis3(const double S[9], const double r[3]);

#endif /* VISLAM_VL_CAMERA_H */
