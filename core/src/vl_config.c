/* Configuration presets, validation and status strings. */
#include "vislam/vislam.h"

#include <math.h>
#include <string.h>

/* Identity rotation part of a 4x4, used until a calibration arrives. */
static const double identity4[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

void vl_config_default(vl_config_t *cfg)
{
    if (cfg == NULL) {
        return;
    }
    memset(cfg, 0, sizeof(*cfg));
    cfg->mode = VL_MODE_SLAM;
    cfg->estimate_input_offsets = 1;

    /* The seed data's velocities carry about 0.5 m/s and 0.05 rad/s of noise per
     * sample (shared/data/README.md): model that, do not hide it. */
    cfg->linear_velocity_noise = 0.5;
    cfg->angular_velocity_noise = 0.05;
    cfg->linear_offset_prior = 0.1;
    cfg->angular_offset_prior = 0.01;
    cfg->linear_offset_walk = 1e-3;
    cfg->angular_offset_walk = 1e-4;

    cfg->pixel_noise = 1.5;
    cfg->min_disparity = 1.0;
    cfg->max_depth = 150.0;
    cfg->gate_chi2 = 11.34; /* chi-square, 3 dof, 0.99 */
    cfg->max_broken_fraction = 0.3;
    cfg->ransac_hypotheses = 32;
    cfg->ransac_threshold = 3.0;
    /* 64 observations (192 rows) keep an update at a full window of 128 under
     * 2 ms at p99.9 on 0034 here, for a few decimetres of ATE on 0027 (README). */
    cfg->max_update_observations = 64;
    cfg->adaptive_noise = 1;

    cfg->max_landmarks = VL_MAX_LANDMARKS;
    cfg->min_track_length = 2;
    cfg->max_unseen_frames = 0; /* the seed's tracks have no gaps: an unseen track has ended */
    cfg->max_propagation_dt = 0.5;

    /* Robustness limits: far outside anything a clean drive shows (the seed drives:
     * steps of 0.1 s, at most 16 m/s and 0.8 rad/s, disparities up to 190 px, pixels
     * up to 30 px beyond 2 cx and 2 cy), so clean data is never refused. */
    cfg->max_time_jump = 10.0;
    cfg->new_timeline_samples = 5;   /* at 10 Hz IMU and camera: a new timeline within 0.3 s */
    cfg->max_speed = 100.0;          /* 360 km/h */
    cfg->max_rotation_rate = 35.0;   /* 2000 deg/s, a common gyro full scale */
    cfg->image_width = 0.0;          /* 2 cx */
    cfg->image_height = 0.0;         /* 2 cy */
    cfg->image_margin = 64.0;
    cfg->max_disparity = 400.0;      /* about 1 m away on the KITTI rig (fx b = 380 px m) */
    cfg->max_imu_silence = 0.5;      /* five missed samples at 10 Hz */
    cfg->divergence_frames = 20;     /* 2 s at 10 Hz */

    memcpy(cfg->calibration.cam_T_imu, identity4, sizeof(identity4));
}

void vl_config_preset_seed(vl_config_t *cfg)
{
    if (cfg == NULL) {
        return;
    }
    vl_config_default(cfg);
    cfg->estimate_input_offsets = 0;
    /* W = diag(1e-5 I3, 1e-4 I3) per step; the estimator scales per-sample
     * velocity noise by the step, so at the nominal 0.1 s step these are W. */
    cfg->linear_velocity_noise = sqrt(1e-5) / 0.1;
    cfg->angular_velocity_noise = sqrt(1e-4) / 0.1;
    cfg->pixel_noise = sqrt(3500.0); /* V = 3500 I4 */
    cfg->gate_chi2 = 0.0;
    cfg->ransac_hypotheses = 0;
    cfg->max_broken_fraction = 1.0;
    cfg->max_update_observations = 0;
    cfg->adaptive_noise = 0;
    cfg->min_track_length = 1;
    cfg->min_disparity = 1e-6;
    cfg->max_depth = 1e9;
}

static int positive_finite(double x)
{
    return isfinite(x) && x > 0.0;
}

static int non_negative_finite(double x)
{
    return isfinite(x) && x >= 0.0;
}

vl_status_t vl_config_check(const vl_config_t *cfg)
{
    if (cfg == NULL) {
        return VL_ERR_NULL;
    }
    if (cfg->mode != VL_MODE_IMU_ONLY && cfg->mode != VL_MODE_MAPPING && cfg->mode != VL_MODE_SLAM) {
        return VL_ERR_CONFIG;
    }
    if (!positive_finite(cfg->linear_velocity_noise) || !positive_finite(cfg->angular_velocity_noise) ||
        !positive_finite(cfg->pixel_noise)) {
        return VL_ERR_CONFIG;
    }
    if (!non_negative_finite(cfg->linear_offset_prior) || !non_negative_finite(cfg->angular_offset_prior) ||
        !non_negative_finite(cfg->linear_offset_walk) || !non_negative_finite(cfg->angular_offset_walk)) {
        return VL_ERR_CONFIG;
    }
    if (cfg->ransac_hypotheses > 0 && !positive_finite(cfg->ransac_threshold)) {
        return VL_ERR_CONFIG;
    }
    if (!positive_finite(cfg->min_disparity) || !positive_finite(cfg->max_depth) ||
        !non_negative_finite(cfg->gate_chi2) || !positive_finite(cfg->max_propagation_dt)) {
        return VL_ERR_CONFIG;
    }
    if (cfg->min_track_length < 1 || cfg->ransac_hypotheses > 4096 || !(cfg->max_broken_fraction > 0.0) ||
        !(cfg->max_broken_fraction <= 1.0)) {
        return VL_ERR_CONFIG;
    }
    if (cfg->max_landmarks < 1 || cfg->max_landmarks > VL_MAX_LANDMARKS) {
        return VL_ERR_CONFIG;
    }
    /* Time limits become int64 microseconds: 1e9 s keeps them far inside the range. */
    if (!positive_finite(cfg->max_time_jump) || !(cfg->max_time_jump <= VL_MAX_TIME_LIMIT) ||
        !positive_finite(cfg->max_imu_silence) || !(cfg->max_imu_silence <= VL_MAX_TIME_LIMIT) ||
        cfg->new_timeline_samples < 2) {
        return VL_ERR_CONFIG;
    }
    if (!positive_finite(cfg->max_speed) || !positive_finite(cfg->max_rotation_rate) ||
        !non_negative_finite(cfg->image_width) || !non_negative_finite(cfg->image_height) ||
        !non_negative_finite(cfg->image_margin) || !positive_finite(cfg->max_disparity)) {
        return VL_ERR_CONFIG;
    }
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
    double det = T[0] * (T[5] * T[10] - T[6] * T[9]) - T[1] * (T[4] * T[10] - T[6] * T[8]) +
                 T[2] * (T[4] * T[9] - T[5] * T[8]);
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
    }
    return "unknown status";
}
