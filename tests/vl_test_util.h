/**
 * @file vl_test_util.h
 * @brief Small helpers shared by the Unity tests.
 */
#ifndef VISLAM_TESTS_VL_TEST_UTIL_H
#define VISLAM_TESTS_VL_TEST_UTIL_H

#include <math.h>
#include <string.h>

#include "vislam/vislam.h"

/** Largest |a[i] - b[i]|; NaN anywhere gives NaN, so a comparison against it fails. */
static inline double vl_test_max_abs_diff(const double *a, const double *b, int n)
{
    double m = 0.0;
    for (int i = 0; i < n; ++i) {
        const double d = fabs(a[i] - b[i]);
        if (d > m || d != d) {
            m = d;
        }
    }
    return m;
}

/** The KITTI 0027 stereo rig: intrinsics, baseline, and (with_extrinsics) the real cam_T_imu, else identity. */
static inline void vl_test_kitti_calibration(vl_calibration_t *cal, int with_extrinsics)
{
    static const double cam_T_imu[16] = {
        -1.08863514e-03, -9.99976347e-01, 6.78718180e-03,  1.14389871e+00,  -8.51207214e-03, -6.77767115e-03,
        -9.99940872e-01, -3.12718471e-01, 9.99963177e-01,  -1.14634293e-03, -8.50449310e-03, 7.26546045e-01,
        0.0,             0.0,             0.0,             1.0};
    memset(cal, 0, sizeof(*cal));
    cal->fx = 707.0912;
    cal->fy = 707.0912;
    cal->cx = 601.8873;
    cal->cy = 183.1104;
    cal->baseline = 0.5371506;
    if (with_extrinsics) {
        memcpy(cal->cam_T_imu, cam_T_imu, sizeof(cam_T_imu));
    } else {
        cal->cam_T_imu[0] = cal->cam_T_imu[5] = cal->cam_T_imu[10] = cal->cam_T_imu[15] = 1.0;
    }
}

#endif /* VISLAM_TESTS_VL_TEST_UTIL_H */
