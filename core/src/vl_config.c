/* Configuration presets, validation and status strings. */
#include "vislam/vislam.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

/* Identity rotation part of a 4x4, used until a calibration arrives. */
static const double identity4[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

void vl_config_default(vl_config_t *cfg)
{
    if (cfg == NULL) {
        return;
    }
    memset(cfg, 0, sizeof(*cfg));
    /* Every plain value from its row of the schema (the reasons for the values are there). */
#define VL_CONFIG_SET_DEFAULT_(section, key, field, type, def, min, max, min_open, units, meaning) cfg->field = (def);
    VL_CONFIG_KEYS(VL_CONFIG_SET_DEFAULT_)
#undef VL_CONFIG_SET_DEFAULT_

    memcpy(cfg->calibration.cam_T_imu, identity4, sizeof(identity4));
}

void vl_config_preset_seed(vl_config_t *cfg)
{
    if (cfg == NULL) {
        return;
    }
    vl_config_default(cfg);
    cfg->estimate_input_offsets = 0;
    cfg->interpolate_velocities = 0;  /* the seed held each sample until the next */
    cfg->velocity_sensor_std_x = 0.0; /* and took them at the body origin */
    /* W = diag(1e-5 I3, 1e-4 I3) per step; the estimator scales per-sample
     * velocity noise by the step, so at the nominal 0.1 s step these are W. */
    cfg->linear_velocity_noise = sqrt(1e-5) / 0.1;
    cfg->angular_velocity_noise = sqrt(1e-4) / 0.1;
    cfg->pixel_noise = sqrt(3500.0); /* V = 3500 I4 */
    cfg->gate_chi2 = 0.0;
    cfg->ransac_hypotheses = 0;
    cfg->max_broken_fraction = 1.0;
    cfg->max_update_observations = 0;
    cfg->max_update_work = 0.0;
    cfg->adaptive_noise = 0;
    cfg->repeat_anchor_noise = 0.0; /* the seed used repeated images as any other */
    cfg->repeat_track_walk = 0.0;
    cfg->min_track_length = 1;
    cfg->min_disparity = 1e-6;
    cfg->max_depth = 1e9;
}

static int positive_finite(double x)
{
    return isfinite(x) && x > 0.0;
}

/* One value against its schema row's range; doubles must also be finite. */
static int in_range(vl_config_type_t type, double v, double min, double max, int min_open)
{
    if (type == VL_CONFIG_BOOL) {
        return 1; /* any int is a truth value */
    }
    if (type == VL_CONFIG_DOUBLE && !isfinite(v)) {
        return 0;
    }
    return (min_open ? v > min : v >= min) && v <= max;
}

vl_status_t vl_config_check(const vl_config_t *cfg)
{
    if (cfg == NULL) {
        return VL_ERR_NULL;
    }
    /* Every plain value against its schema row. A RANSAC threshold is unused while RANSAC is
       off (ransac_hypotheses = 0), so it is only checked with hypotheses to use it: the one
       range that depends on another value. */
#define VL_CONFIG_CHECK_KEY_(section, key, field, type, def, min, max, min_open, units, meaning)                     \
    if (!in_range(VL_CONFIG_##type, (double)cfg->field, (double)(min), (double)(max), (min_open)) &&                 \
        !(offsetof(vl_config_t, field) == offsetof(vl_config_t, ransac_threshold) && cfg->ransac_hypotheses == 0)) { \
        return VL_ERR_CONFIG;                                                                                        \
    }
    VL_CONFIG_KEYS(VL_CONFIG_CHECK_KEY_)
#undef VL_CONFIG_CHECK_KEY_

    const vl_calibration_t *cal = &cfg->calibration;
    if (!positive_finite(cal->fx) || !positive_finite(cal->fy) || !isfinite(cal->cx) || !isfinite(cal->cy) ||
        !positive_finite(cal->baseline)) {
        return VL_ERR_CONFIG;
    }
    for (int i = 0; i < 16; ++i) {
        if (!isfinite(cal->cam_T_imu[i])) {
            return VL_ERR_CONFIG;
        }
    }
    /* cam_T_imu must be a rigid transform: orthonormal rotation, last row 0 0 0 1. */
    const double *T = cal->cam_T_imu;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            double dot = T[4 * 0 + i] * T[4 * 0 + j] + T[4 * 1 + i] * T[4 * 1 + j] + T[4 * 2 + i] * T[4 * 2 + j];
            if (fabs(dot - (i == j ? 1.0 : 0.0)) > 1e-6) {
                return VL_ERR_CONFIG;
            }
        }
    }
    double det =
        T[0] * (T[5] * T[10] - T[6] * T[9]) - T[1] * (T[4] * T[10] - T[6] * T[8]) + T[2] * (T[4] * T[9] - T[5] * T[8]);
    if (det < 0.0 || T[12] != 0.0 || T[13] != 0.0 || T[14] != 0.0 || T[15] != 1.0) {
        return VL_ERR_CONFIG;
    }
    return VL_OK;
}

const char *vl_status_str(vl_status_t status)
{
    switch (status) {
    case VL_OK:
        return "ok";
    case VL_FRAME_TRUNCATED:
        return "frame truncated to VL_MAX_FRAME_FEATURES observations";
    case VL_ERR_NULL:
        return "null pointer argument";
    case VL_ERR_CONFIG:
        return "configuration value out of range";
    case VL_ERR_NOT_READY:
        return "frame before the first IMU sample";
    case VL_ERR_NON_FINITE:
        return "input holds NaN or infinity";
    case VL_ERR_TIME_ORDER:
        return "input time not after the previous input";
    case VL_ERR_NOT_POSITIVE_DEFINITE:
        return "innovation covariance not positive definite; update refused";
    case VL_ERR_CAPACITY:
        return "output buffer too small";
    case VL_ERR_MISALIGNED:
        return "estimator not aligned to VL_ESTIMATOR_ALIGN bytes";
    case VL_RESET:
        return "estimator re-initialized (new timeline or divergence)";
    case VL_ERR_TIME_JUMP:
        return "input time jumps more than max_time_jump from the clock";
    case VL_ERR_IMPLAUSIBLE:
        return "IMU sample beyond max_speed or max_rotation_rate";
    case VL_ERR_IMU_SILENT:
        return "frame refused: IMU silent longer than max_imu_silence";
    case VL_ERR_ABI_MISMATCH:
        return "caller compiled with other capacities or another vislam.h than the library";
    }
    return "unknown status";
}
