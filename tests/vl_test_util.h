/**
 * @file vl_test_util.h
 * @brief Small helpers shared by the Unity tests.
 */
#ifndef VISLAM_TESTS_VL_TEST_UTIL_H
#define VISLAM_TESTS_VL_TEST_UTIL_H

#include <math.h>
#include <string.h>

#include "vislam/vislam.h"
#include "vl_sim.h"
#include "vl_stereo.h"

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

/** Unity assertion that every |a[i] - b[i]| <= tol (expands where Unity is included). */
#define VL_TEST_ASSERT_CLOSE(a, b, n, tol) TEST_ASSERT_DOUBLE_WITHIN((tol), 0.0, vl_test_max_abs_diff((a), (b), (n)))

/** The i-th of a fixed set of points ahead of a vehicle at the identity pose (IMU x forward), m. */
static inline void vl_test_point_ahead(uint32_t i, double pw[3])
{
    pw[0] = 8.0 + 1.5 * (double)i;
    pw[1] = -4.0 + 0.7 * (double)(i % 11);
    pw[2] = -1.0 + 0.3 * (double)(i % 7);
}

/** The stereo observation of world point pw seen from the identity pose through cal. */
static inline void vl_test_observe(const vl_calibration_t *cal, const double pw[3], int32_t id, vl_stereo_obs_t *o)
{
    const double *T = cal->cam_T_imu;
    double c[3], y[3];
    for (int i = 0; i < 3; ++i) {
        c[i] = T[4 * i] * pw[0] + T[4 * i + 1] * pw[1] + T[4 * i + 2] * pw[2] + T[4 * i + 3];
    }
    vl_stereo_project(cal, c, y, NULL);
    o->id = id;
    o->u_left = y[0];
    o->v_left = y[1];
    o->u_right = y[2];
    o->v_right = y[1];
}

/** An IMU sample: forward speed vx (m/s) and yaw rate wz (rad/s), the rest zero. */
static inline vl_imu_sample_t vl_test_imu_at(int64_t utime, double vx, double wz)
{
    vl_imu_sample_t s;
    memset(&s, 0, sizeof(s));
    s.utime = utime;
    s.linear_velocity[0] = vx;
    s.angular_velocity[2] = wz;
    return s;
}

/** The KITTI 0027 stereo rig (the simulator's), with its real cam_T_imu or (with_extrinsics 0) identity. */
static inline void vl_test_kitti_calibration(vl_calibration_t *cal, int with_extrinsics)
{
    vl_sim_kitti_calibration(cal);
    if (!with_extrinsics) {
        static const double identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
        memcpy(cal->cam_T_imu, identity, sizeof(identity));
    }
}

/** The default configuration with the KITTI 0027 rig and its real cam_T_imu. */
static inline void vl_test_kitti_config(vl_config_t *cfg)
{
    vl_config_default(cfg);
    vl_test_kitti_calibration(&cfg->calibration, 1);
}

/** A frame at utime of a vehicle at the identity pose seeing the first n of the points ahead
 * (vl_test_point_ahead), with ids first_id, first_id + 1, ... */
static inline void vl_test_frame_ahead(const vl_calibration_t *cal, vl_stereo_frame_t *f, int64_t utime, uint32_t n,
                                       int32_t first_id)
{
    f->utime = utime;
    f->count = n;
    for (uint32_t i = 0; i < n; ++i) {
        double pw[3];
        vl_test_point_ahead(i, pw);
        vl_test_observe(cal, pw, first_id + (int32_t)i, &f->obs[i]);
    }
}

/** A frame as the programs apply it (vl_session_input, then vl_session_finish): vl_update, then
 * vl_update_deferred, its work after the pose. Returns vl_update's status, or the second's when
 * only that one failed. */
static inline vl_status_t vl_test_update(vl_estimator_t *e, const vl_stereo_frame_t *f)
{
    const vl_status_t st = vl_update(e, f);
    const vl_status_t after = vl_update_deferred(e);
    return (st == VL_OK && after != VL_OK) ? after : st;
}

/** A real drive's start and the seed data's frame period, us. */
#define VL_TEST_T0_US 1317386436000000LL
#define VL_TEST_STEP_US 100000LL

#endif /* VISLAM_TESTS_VL_TEST_UTIL_H */
