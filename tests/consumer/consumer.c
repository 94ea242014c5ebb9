/*
 * A program built on vislam the way a user builds one: only the installed (or
 * subproject) header and library, nothing from vislam's tree. It drives the
 * estimator along a straight line at 1 m/s past a few fixed points and checks
 * the pose. Also compiled as C++ (consumer.cpp).
 *
 * Exit status: 0 the pose is right; 1 something else failed; 3 vl_init refused
 * the build with VL_ERR_ABI_MISMATCH (expected of a build with another
 * VL_MAX_LANDMARKS or another vislam.h than the library's).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
#define CONSUMER_LANGUAGE "C++"
#else
#define CONSUMER_LANGUAGE "C"
#endif

#define SPEED 1.0      /* m/s, along the IMU's x axis */
#define STEP_US 100000 /* us between samples and frames */
#define STEPS 5
#define POINTS 12

static vl_estimator_t est;

/* A KITTI-like rig; the camera looks along the IMU's x axis (z forward, x right, y down). */
static void set_calibration(vl_calibration_t *c)
{
    static const double cam_T_imu[16] = {0, -1, 0, 0, 0, 0, -1, 0, 1, 0, 0, 0, 0, 0, 0, 1};
    c->fx = 718.856;
    c->fy = 718.856;
    c->cx = 607.1928;
    c->cy = 185.2157;
    c->baseline = 0.537;
    memcpy(c->cam_T_imu, cam_T_imu, sizeof(cam_T_imu));
}

/* The frame seen from x = position (m) on the line: fixed world points, projected exactly. */
static void make_frame(const vl_calibration_t *c, int64_t utime, double position, vl_stereo_frame_t *f)
{
    f->utime = utime;
    f->count = POINTS;
    for (int i = 0; i < POINTS; ++i) {
        const double ahead = 10.0 + 2.0 * i - position; /* m, along the camera's z */
        const double right = -3.0 + 0.5 * i;            /* m, along the camera's x */
        const double down = 1.0 - 0.2 * (i % 5);        /* m, along the camera's y */
        f->obs[i].id = i;
        f->obs[i].u_left = c->fx * right / ahead + c->cx;
        f->obs[i].u_right = c->fx * (right - c->baseline) / ahead + c->cx;
        f->obs[i].v_left = c->fy * down / ahead + c->cy;
        f->obs[i].v_right = f->obs[i].v_left;
    }
}

int main(void)
{
    vl_config_t cfg;
    vl_config_default(&cfg);
    set_calibration(&cfg.calibration);
    const vl_status_t init = vl_init(&est, &cfg);
    printf("%s consumer, VL_MAX_LANDMARKS %d: vl_init: %s\n", CONSUMER_LANGUAGE, VL_MAX_LANDMARKS, vl_status_str(init));
    if (init == VL_ERR_ABI_MISMATCH) {
        return 3;
    }
    if (init != VL_OK) {
        return 1;
    }

    static vl_stereo_frame_t frame;
    for (int k = 0; k <= STEPS; ++k) {
        const int64_t utime = (int64_t)k * STEP_US;
        vl_imu_sample_t imu;
        memset(&imu, 0, sizeof(imu));
        imu.utime = utime;
        imu.linear_velocity[0] = SPEED;
        vl_status_t st = vl_propagate(&est, &imu);
        if (st == VL_OK && k > 0) {
            make_frame(&cfg.calibration, utime, SPEED * 1e-6 * (double)utime, &frame);
            st = vl_update(&est, &frame);
            /* the pose is ready here; then what the update's time bound deferred */
            if (st == VL_OK) {
                st = vl_update_deferred(&est);
            }
        }
        if (st != VL_OK) {
            printf("step %d: %s\n", k, vl_status_str(st));
            return 1;
        }
    }

    vl_pose_t pose;
    if (vl_get_pose(&est, &pose) != VL_OK) {
        return 1;
    }
    const double expected = SPEED * STEPS * STEP_US * 1e-6;
    printf("pose after %d steps: %.6f %.6f %.6f m (expected %.6f 0 0), %u landmarks, %llu observations used\n", STEPS,
           pose.position[0], pose.position[1], pose.position[2], expected, vl_window_size(&est),
           (unsigned long long)vl_get_counters(&est)->observations_used);
    const int ok = fabs(pose.position[0] - expected) < 1e-3 && fabs(pose.position[1]) < 1e-3 &&
                   fabs(pose.position[2]) < 1e-3 && vl_window_size(&est) == POINTS &&
                   vl_get_counters(&est)->observations_used > 0;
    return ok ? 0 : 1;
}
