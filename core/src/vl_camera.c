/*
 * The stereo rig at the current pose: projection of a world point with its
 * Jacobians, triangulation of an observation into the world, and the innovation
 * length every gate uses.
 */
#include "vl_camera.h"

#include <math.h>

#include "vl_se3.h"
#include "vl_stereo.h"

void vl_camera_extrinsics(const vl_calibration_t *cal, double Rc[9], double tc[3])
{
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            Rc[3 * i + j] = cal->cam_T_imu[4 * i + j];
        }
        tc[i] = cal->cam_T_imu[4 * i + 3];
    }
}

int vl_camera_point(const vl_estimator_t *e, const double Rc[9], const double tc[3], const double pw[3], double b[3],
                    double c[3])
{
    const double d[3] = {pw[0] - e->p[0], pw[1] - e->p[1], pw[2] - e->p[2]};
    vl_matmul_at(e->R, d, b, 3, 3, 1);
    vl_matmul(Rc, b, c, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        c[i] += tc[i];
    }
    return (c[2] > VL_MIN_CAMERA_DEPTH) ? 0 : -1;
}

int vl_camera_project_world(const vl_estimator_t *e, const double pw[3], double y[3], double H_pose[18],
                            double dy_dpw[9])
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3], b[3], c[3];
    vl_camera_extrinsics(cal, Rc, tc);
    if (vl_camera_point(e, Rc, tc, pw, b, c) != 0) {
        return -1;
    }
    double dy_dc[9];
    vl_stereo_project(cal, c, y, dy_dc);

    /* d b / d xi = -odot(b) (right perturbation of the world-from-IMU pose) */
    double odot[18], dy_db[9];
    vl_circle_dot(b, odot);
    vl_matmul(dy_dc, Rc, dy_db, 3, 3, 3);
    vl_matmul(dy_db, odot, H_pose, 3, 3, 6);
    for (int i = 0; i < 18; ++i) {
        H_pose[i] = -H_pose[i];
    }
    /* d b / d p_w = R^T */
    vl_matmul_bt(dy_db, e->R, dy_dpw, 3, 3, 3);
    return 0;
}

void vl_camera_triangulate_at(const vl_estimator_t *e, const double R[9], const double p[3], const double y[3],
                              double pw[3], double dpw_dy[9])
{
    const vl_calibration_t *cal = &e->cfg.calibration;
    double Rc[9], tc[3], c[3], dc_dy[9], d[3], b[3], Rb[3], RRc[9];
    vl_camera_extrinsics(cal, Rc, tc);
    vl_stereo_triangulate(cal, y, c, dc_dy);
    for (int i = 0; i < 3; ++i) {
        d[i] = c[i] - tc[i];
    }
    vl_matmul_at(Rc, d, b, 3, 3, 1); /* b = Rc^T (c - tc), the point in the IMU frame */
    vl_matmul(R, b, Rb, 3, 3, 1);
    for (int i = 0; i < 3; ++i) {
        pw[i] = Rb[i] + p[i];
    }
    vl_matmul_bt(R, Rc, RRc, 3, 3, 3); /* R Rc^T */
    vl_matmul(RRc, dc_dy, dpw_dy, 3, 3, 3);
}

void vl_camera_triangulate_world(const vl_estimator_t *e, const double y[3], double pw[3], double dpw_dy[9])
{
    vl_camera_triangulate_at(e, e->R, e->p, y, pw, dpw_dy);
}

double vl_mahalanobis3(const double S[9], const double r[3])
{
    const double d00 = S[0];
    if (!(d00 > 0.0)) {
        return INFINITY;
    }
    const double l00 = sqrt(d00);
    const double l10 = S[3] / l00, l20 = S[6] / l00;
    const double d11 = S[4] - l10 * l10;
    if (!(d11 > 0.0)) {
        return INFINITY;
    }
    const double l11 = sqrt(d11);
    const double l21 = (S[7] - l20 * l10) / l11;
    const double d22 = S[8] - l20 * l20 - l21 * l21;
    if (!(d22 > 0.0)) {
        return INFINITY;
    }
    const double l22 = sqrt(d22);
    const double w0 = r[0] / l00;
    const double w1 = (r[1] - l10 * w0) / l11;
    const double w2 = (r[2] - l20 * w0 - l21 * w1) / l22;
    return w0 * w0 + w1 * w1 + w2 * w2;
}
