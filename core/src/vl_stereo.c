/**
 * @file vl_stereo.c
 * @brief Rectified stereo pinhole model in compressed form y = [u_left, v, u_right].
 *
 * u_left = fx x / z + cx, v = fy y / z + cy, u_right = fx (x - b) / z + cx.
 * The callers check z > 0 and disparity > 0 before calling; a violation here
 * only yields meaningless or non-finite outputs (IEEE division, never a trap).
 */
#include "vl_stereo.h"

void vl_stereo_project(const vl_calibration_t *cal, const double c[3], double y[3], double dy_dc[9])
{
    const double fx = cal->fx;
    const double fy = cal->fy;
    const double b = cal->baseline;
    const double iz = 1.0 / c[2];
    const double xn = c[0] * iz;
    const double yn = c[1] * iz;
    const double xr = (c[0] - b) * iz;

    y[0] = fx * xn + cal->cx;
    y[1] = fy * yn + cal->cy;
    y[2] = fx * xr + cal->cx;
    if (dy_dc != 0) {
        dy_dc[0] = fx * iz;
        dy_dc[1] = 0.0;
        dy_dc[2] = -fx * xn * iz;
        dy_dc[3] = 0.0;
        dy_dc[4] = fy * iz;
        dy_dc[5] = -fy * yn * iz;
        dy_dc[6] = fx * iz;
        dy_dc[7] = 0.0;
        dy_dc[8] = -fx * xr * iz;
    }
}

void vl_stereo_compress(const vl_stereo_obs_t *obs, double y[3])
{
    y[0] = obs->u_left;
    y[1] = 0.5 * (obs->v_left + obs->v_right);
    y[2] = obs->u_right;
}

void vl_stereo_triangulate(const vl_calibration_t *cal, const double y[3], double c[3], double dc_dy[9])
{
    const double fx = cal->fx;
    const double fy = cal->fy;
    const double b = cal->baseline;
    const double d = y[0] - y[2];
    const double id = 1.0 / d;
    /* z = fx b / d; x = (u_l - cx) b / d; y = (v - cy) (fx / fy) b / d. */
    const double du = y[0] - cal->cx;
    const double dv = (y[1] - cal->cy) * fx / fy;

    c[0] = du * b * id;
    c[1] = dv * b * id;
    c[2] = fx * b * id;
    if (dc_dy != 0) {
        const double bid2 = b * id * id;
        /* d/d(u_l) of k / d is -k / d^2 and d/d(u_r) is +k / d^2. */
        dc_dy[0] = b * id - du * bid2;
        dc_dy[1] = 0.0;
        dc_dy[2] = du * bid2;
        dc_dy[3] = -dv * bid2;
        dc_dy[4] = b * id * fx / fy;
        dc_dy[5] = dv * bid2;
        dc_dy[6] = -fx * bid2;
        dc_dy[7] = 0.0;
        dc_dy[8] = fx * bid2;
    }
}

void vl_stereo_noise_var(double pixel_var, double noise_var[3])
{
    noise_var[0] = pixel_var;
    noise_var[1] = 0.5 * pixel_var;
    noise_var[2] = pixel_var;
}

void vl_stereo_matrix(const vl_calibration_t *cal, double M[16])
{
    int i;
    for (i = 0; i < 16; ++i) {
        M[i] = 0.0;
    }
    M[0] = cal->fx;
    M[2] = cal->cx;
    M[5] = cal->fy;
    M[6] = cal->cy;
    M[8] = cal->fx;
    M[10] = cal->cx;
    M[11] = -cal->fx * cal->baseline;
    M[13] = cal->fy;
    M[14] = cal->cy;
}
