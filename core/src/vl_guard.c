/*
 * Guards on inputs and on the state. The defaults refuse nothing on the seed
 * drives or the sample log; each rule refuses or acts deterministically.
 */
#include "vl_guard.h"

#include <math.h>

#include "vl_estimator_internal.h"

/* Relative slack on |P_ij|^2 <= P_ii P_jj, for rounding in a valid covariance. */
#define VL_DIVERGENCE_CORRELATION_SLACK 1e-6

vl_status_t vl_guard_check_time(const vl_estimator_t *e, vl_input_kind_t kind, int64_t utime)
{
    const int64_t limit = vl_limit_us(e->cfg.max_time_jump);
    const int64_t d = vl_utime_diff(utime, e->clock_utime);
    if (d > limit || d < -limit) {
        return VL_ERR_TIME_JUMP;
    }
    if (kind == VL_INPUT_IMU) {
        return (utime <= e->last_imu_utime || utime < e->state_utime) ? VL_ERR_TIME_ORDER : VL_OK;
    }
    return (utime < e->state_utime || (e->have_frame && utime <= e->last_frame_utime)) ? VL_ERR_TIME_ORDER : VL_OK;
}

void vl_guard_time_passed(vl_estimator_t *e, int64_t utime)
{
    if (utime > e->clock_utime) {
        e->clock_utime = utime;
    }
    e->timeline_count = 0;
}

/*
 * Consecutive time-refused inputs that follow one another (each within
 * max_time_jump of the previous, each kind strictly forward, so a stuck clock
 * never qualifies) are a candidate timeline; any input that passes the policy
 * ends it.
 */
int vl_guard_note_timeline(vl_estimator_t *e, vl_input_kind_t kind, int64_t utime)
{
    int follows = e->timeline_count > 0;
    if (follows) {
        const int64_t limit = vl_limit_us(e->cfg.max_time_jump);
        const int64_t d = vl_utime_diff(utime, e->timeline_last_utime);
        follows = d <= limit && d >= -limit;
        if (kind == VL_INPUT_IMU && e->timeline_have_imu && utime <= e->timeline_last_imu_utime) {
            follows = 0;
        }
        if (kind == VL_INPUT_FRAME && e->timeline_have_frame && utime <= e->timeline_last_frame_utime) {
            follows = 0;
        }
    }
    if (!follows) {
        e->timeline_count = 0;
        e->timeline_have_imu = 0;
        e->timeline_have_frame = 0;
    }
    e->timeline_count++;
    e->timeline_last_utime = utime;
    if (kind == VL_INPUT_IMU) {
        e->timeline_have_imu = 1;
        e->timeline_last_imu_utime = utime;
    } else {
        e->timeline_have_frame = 1;
        e->timeline_last_frame_utime = utime;
    }
    return e->timeline_count >= e->cfg.new_timeline_samples;
}

int vl_guard_imu_silent_at(const vl_estimator_t *e, int64_t utime)
{
    return vl_utime_diff(utime, e->last_imu_utime) > vl_limit_us(e->cfg.max_imu_silence);
}

/* Euclidean length of a finite 3-vector, scaled so that squaring cannot overflow. */
static double norm3(const double v[3])
{
    const double m = fmax(fabs(v[0]), fmax(fabs(v[1]), fabs(v[2])));
    if (m == 0.0) {
        return 0.0;
    }
    const double a = v[0] / m, b = v[1] / m, c = v[2] / m;
    return m * sqrt(a * a + b * b + c * c);
}

int vl_guard_imu_plausible(const vl_estimator_t *e, const vl_imu_sample_t *imu)
{
    return norm3(imu->linear_velocity) <= e->cfg.max_speed && norm3(imu->angular_velocity) <= e->cfg.max_rotation_rate;
}

int vl_guard_observation_valid(const vl_stereo_obs_t *o)
{
    return o->id >= 0 && isfinite(o->u_left) && isfinite(o->v_left) && isfinite(o->u_right) && isfinite(o->v_right);
}

/* The image is image_width x image_height, or 2 cx x 2 cy when those are 0. */
int vl_guard_observation_plausible(const vl_estimator_t *e, const vl_stereo_obs_t *o)
{
    const vl_config_t *c = &e->cfg;
    const double m = c->image_margin;
    const double w = (c->image_width > 0.0 ? c->image_width : 2.0 * c->calibration.cx) + m;
    const double h = (c->image_height > 0.0 ? c->image_height : 2.0 * c->calibration.cy) + m;
    return o->u_left >= -m && o->u_left <= w && o->u_right >= -m && o->u_right <= w && o->v_left >= -m &&
           o->v_left <= h && o->v_right >= -m && o->v_right <= h && o->u_left - o->u_right <= c->max_disparity;
}

/*
 * A frame that repeats the previous frame's pixels exactly, for every id the two
 * share, is the same image delivered twice: the vehicle moved on, the image did not.
 */
int vl_guard_frame_repeats_previous(const vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    uint32_t common = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        for (uint32_t j = 0; j < e->num_prev_obs; ++j) {
            const vl_stereo_obs_t *q = &e->prev_obs[j];
            if (q->id != o->id) {
                continue;
            }
            if (q->u_left != o->u_left || q->v_left != o->v_left || q->u_right != o->u_right ||
                q->v_right != o->v_right) {
                return 0;
            }
            common++;
            break;
        }
    }
    return common > 0;
}

int vl_guard_block_sound(const double *B, uint32_t n, size_t ld)
{
    for (uint32_t j = 0; j < n; ++j) {
        const double b_jj = B[(size_t)j * ld + j];
        if (!(b_jj >= 0.0) || !isfinite(b_jj)) {
            return 0;
        }
        for (uint32_t i = 0; i < j; ++i) {
            const double bij = B[(size_t)j * ld + i];
            const double bound = B[(size_t)i * ld + i] * b_jj;
            if (!isfinite(bij) || bij * bij > bound * (1.0 + VL_DIVERGENCE_CORRELATION_SLACK)) {
                return 0;
            }
        }
    }
    return 1;
}

/*
 * A non-finite state, a covariance with a negative or non-finite diagonal (or
 * non-finite deferred prediction accumulators) or a core block that is not
 * sound (vl_guard_block_sound), or, in SLAM, divergence_frames failed updates
 * in a row.
 */
int vl_guard_diverged(const vl_estimator_t *e)
{
    if (!vl_all_finite(e->R, 9) || !vl_all_finite(e->p, 3) || !vl_all_finite(e->offset_linear, 3) ||
        !vl_all_finite(e->offset_angular, 3) || !vl_all_finite(e->sensor_position, 3) ||
        !vl_all_finite(e->landmark_state, 3 * (int)e->num_landmarks)) {
        return 1;
    }
    /* With a prediction deferred, the landmark diagonal is the last settled one (checked
     * then) and what the steps add to it is in the accumulators. */
    const vl_deferred_prediction_t *d = &e->deferred;
    if (d->steps > 0 && (!vl_all_finite(d->noise, VL_CORE_DIM * VL_CORE_DIM) ||
                         !vl_all_finite(d->transition, VL_CORE_DIM * VL_PARAM_DIM))) {
        return 1;
    }
    if (!vl_guard_block_sound(e->P, VL_CORE_DIM, VL_LD)) { /* the core block: current at any time */
        return 1;
    }
    const uint32_t n = d->steps == 0 ? vl_state_dim(e) : VL_CORE_DIM;
    for (uint32_t i = VL_CORE_DIM; i < n; ++i) {
        const double d_ii = vl_P_value(e, i, i);
        if (!(d_ii >= 0.0) || !isfinite(d_ii)) {
            return 1;
        }
    }
    return e->cfg.mode == VL_MODE_SLAM && e->cfg.divergence_frames > 0 &&
           e->failed_frame_run >= e->cfg.divergence_frames;
}
