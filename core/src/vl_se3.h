/**
 * @file vl_se3.h
 * @brief SO(3)/SE(3) operations on small row-major arrays (internal to core/).
 *
 * Tangent vectors of SE(3) are xi = [rho; phi] (translation first, 6 entries).
 * 3x3 and 6x6 matrices are row-major double[9] / double[36]; poses are given
 * as a rotation R (double[9]) and translation p (double[3]).
 */
#ifndef VISLAM_VL_SE3_H
#define VISLAM_VL_SE3_H

#ifdef __cplusplus
extern "C" {
#endif

/** S = hat(v): the skew matrix with S w = v x w. */
void vl_skew(const double v[3], double S[9]);

/** R = exp(hat(phi)) (Rodrigues; exact Taylor form for small angles). */
void vl_so3_exp(const double phi[3], double R[9]);

/** phi = log(R), |phi| in [0, pi]. */
void vl_so3_log(const double R[9], double phi[3]);

/** Left Jacobian of SO(3): exp(hat(phi + d)) ~ exp(hat(J_l d)) exp(hat(phi)). */
void vl_so3_left_jacobian(const double phi[3], double J[9]);

/** (R, p) = exp(hat(xi)) for xi = [rho; phi]. */
void vl_se3_exp(const double xi[6], double R[9], double p[3]);

/** xi = log(R, p). */
void vl_se3_log(const double R[9], const double p[3], double xi[6]);

/** 6x6 adjoint of T = (R, p): Ad = [[R, hat(p) R], [0, R]]. */
void vl_se3_adjoint(const double R[9], const double p[3], double Ad[36]);

/** 6x6 adjoint of T^-1 = (R^T, -R^T p): takes a world-frame (left) perturbation to the
 * body-frame (right) one, xi_r = Ad(T^-1) xi_l. */
void vl_se3_adjoint_inverse(const double R[9], const double p[3], double Ad_inv[36]);

/** 6x6 curly hat (small adjoint) of xi: [[hat(phi), hat(rho)], [0, hat(phi)]]. */
void vl_se3_curly_hat(const double xi[6], double ad[36]);

/** Left Jacobian of SE(3): exp(hat(xi + d)) ~ exp(hat(J_l d)) exp(hat(xi)). */
void vl_se3_left_jacobian(const double xi[6], double J[36]);

/** Right Jacobian of SE(3): exp(hat(xi + d)) ~ exp(hat(xi)) exp(hat(J_r d)); J_r(xi) = J_l(-xi). */
void vl_se3_right_jacobian(const double xi[6], double J[36]);

/** 3x6 circle-dot of a point s: hat(xi) [s; 1] = s_odot xi, s_odot = [I, -hat(s)]. */
void vl_circle_dot(const double s[3], double D[18]);

/** Euclidean norm of a 3-vector. */
double vl_norm3(const double v[3]);

/** C = A B for row-major A (r x k), B (k x c). C must not alias A or B. */
void vl_matmul(const double *A, const double *B, double *C, int r, int k, int c);

/** C = A B^T for row-major A (r x k), B (c x k). C must not alias A or B. */
void vl_matmul_bt(const double *A, const double *B, double *C, int r, int k, int c);

/** C = A^T B for row-major A (k x r), B (k x c). C must not alias A or B. */
void vl_matmul_at(const double *A, const double *B, double *C, int r, int k, int c);

/** Rotation matrix of a unit quaternion [w, x, y, z]. */
void vl_quaternion_to_rotation(const double q[4], double R[9]);

/** Projects R onto SO(3) (re-orthonormalization after many compositions). */
void vl_so3_normalize(double R[9]);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_VL_SE3_H */
