/*
 * Covariance matching, one bounded step per frame: the pixel noise from the
 * post-fit residuals, the velocity noise from the pose correction, a widening
 * when frame after frame contradicts the prior, and the angular offsets'
 * covariance reopened as the angular noise climbs. Bounded work, no
 * allocation, deterministic.
 */
#include "vl_noise.h"

#include <math.h>

#include "vl_estimator_internal.h"
#include "vl_se3.h"
#include "vl_update.h"

/* Observations the pixel noise estimate averages over (its forgetting scale). */
#define VL_PIXEL_NOISE_MEMORY 1000.0
/* The same while the estimate's std is over VL_PIXEL_FAR_FROM_ROWS times the stereo rows' white
 * noise: over what a tracker's errors reach (0027's adapted 0.8 px against rows of 0.27 px, 3x), so
 * a prior far too large, which at the slow memory a sparse drive takes hundreds of frames to shed.
 * Measured at 6, 10 and 15 and at 100 and 200 (README, Accuracy). */
#define VL_PIXEL_NOISE_FAST_MEMORY 100.0
#define VL_PIXEL_FAR_FROM_ROWS 15.0
/* Largest pixel variance sample, in variances in use: 10 sigma (lower caps cost the sparsest noisy cells). */
#define VL_PIXEL_SAMPLE_CAP 100.0
/* Observations under which a frame's pixel rows count against their expected post-fit variance
 * (pixel_samples). Measured from 8 to 24: the real drives' frames of 12 to 15 did better with the
 * dense frames' rule, the simulated ones were level (README, Accuracy). */
#define VL_PIXEL_SPARSE_FRAME 12u
/* A sparse frame's fitted row whose expected post-fit variance is under this share of its noise
 * (the fit absorbed nearly all of it) gives no sample: its ratio would multiply its own noise. */
#define VL_PIXEL_MIN_RESIDUAL_SHARE 0.05
/* Weight of a dense frame in the fast average of its pixel sample's log-ratio to the estimate,
 * and the ratio (a ninth of the variance, a third of the std) under which that average makes the
 * estimate leave its slow average for the frames' own level (README, Accuracy). */
#define VL_PIXEL_DROP_GAIN 0.2
#define VL_PIXEL_DROP_RATIO 9.0
/* Step of the velocity noise in log-variance per dense frame (README, Accuracy). */
#define VL_VELOCITY_NOISE_GAIN 0.05
/* Step of a sparse frame that removed all of the block's prior variance. */
#define VL_VELOCITY_SPARSE_GAIN 0.1
/* A block the frame informed less than this (relative to its prior variance) is left alone. */
#define VL_VELOCITY_MIN_INFORMATION 1e-12
/* Variance factor applied when frame after frame contradicts the prior. */
#define VL_NOISE_WIDEN_ON_CONTRADICTION 4.0
/* The widening stops at this factor of the configured std: enough for a prior 10x too small
 * (the sweep's worst), while frames that keep contradicting beyond it are distrusted until the
 * divergence rule restarts the filter. Unbounded, a burst of frames whose tracks all jump by a
 * few degrees' worth of pixels widened the noise 30x until the pose followed them (README,
 * Robustness). The matching adaptation itself stays bounded by VL_NOISE_ADAPT_RANGE. */
#define VL_NOISE_WIDEN_RANGE 20.0

double vl_noise_clamp_var(double var, double configured_std)
{
    const double f = VL_NOISE_ADAPT_RANGE;
    const double lo = configured_std * configured_std / (f * f), hi = configured_std * configured_std * f * f;
    return var < lo ? lo : (var > hi ? hi : var);
}

/* Quickselect with a middle pivot: deterministic. */
double vl_noise_select_kth(double *v, uint32_t n, uint32_t k)
{
    uint32_t lo = 0, hi = n - 1u;
    while (lo < hi) {
        const double pivot = v[lo + (hi - lo) / 2u];
        uint32_t i = lo, j = hi;
        while (i <= j) {
            while (v[i] < pivot) {
                ++i;
            }
            while (v[j] > pivot) {
                --j;
            }
            if (i <= j) {
                const double t = v[i];
                v[i] = v[j];
                v[j] = t;
                ++i;
                if (j == 0u) {
                    break;
                }
                --j;
            }
        }
        if (k <= j) {
            hi = j;
        } else if (k >= i) {
            lo = i;
        } else {
            return v[k];
        }
    }
    return v[k];
}

/*
 * Appends each row's pixel variance sample of rows[from, to) to samples[*n ...),
 * one per coordinate (w_r its share of the pixel variance: 1, 1/2, 1). A row the
 * update fitted has a post-fit residual with E[e e^T] = R - H P+ H^T; a row it
 * left out (deferred by the time bound, or rejected) keeps an error independent
 * of the correction, E[e e^T] = R + H P+ H^T. fitted is +1 or -1 accordingly.
 *
 * A dense frame's sample is e^2 +- (H P+ H^T)_rr, whose mean is R. But the median
 * taken of them scales that deterministic term by 1 / 0.455 as well, which lifts
 * the estimate by about 1.2 (H P+ H^T)_rr: little where a frame's many rows leave
 * each little of the fit, and measured better on the real drives than without it.
 * A sparse frame's fit absorbs a large share of each row (0.3 to 0.6 of R at 3
 * observations), where that lift ran the estimate to 4 to 11 times the truth. So
 * there a row counts as R e^2 / E[e^2], its squared residual against what the
 * filter expects of it, which the median's scaling leaves unbiased (README,
 * Accuracy).
 */
static void pixel_samples(const vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t from, uint32_t to, double fitted,
                          int sparse, double *samples, uint32_t *n)
{
    static const double share[3] = {1.0, 0.5, 1.0};
    const vl_la_pending_t pending = vl_update_pending(e);
    for (uint32_t i = from; i < to; ++i) {
        double S[9];
        vl_la_obs_covariance(vl_P_const(e), VL_LD, &rows[i], &pending, S); /* H P+ H^T + R */
        for (int r = 0; r < 3; ++r) {
            double res = rows[i].residual[r];
            for (int j = 0; j < 6; ++j) {
                res -= rows[i].H_pose[6 * r + j] * e->work_dx[j];
            }
            for (int j = 0; j < 3; ++j) {
                res -= rows[i].H_landmark[3 * r + j] * e->work_dx[rows[i].landmark_col + j];
            }
            const double R = rows[i].noise_var[r], fit = S[4 * r] - R; /* (H P+ H^T)_rr */
            if (!sparse) {
                samples[(*n)++] = (res * res + fitted * fit) / share[r];
                continue;
            }
            const double expected = R - fitted * fit;
            if (expected > VL_PIXEL_MIN_RESIDUAL_SHARE * R) {
                samples[(*n)++] = R * (res * res / expected) / share[r];
            }
        }
    }
}

/*
 * Residual-based covariance matching for the pixel noise, made robust: each row
 * the update used and each row it rejected (outliers included) gives a sample of
 * the pixel variance; their median, scaled to a variance, is blind to a minority
 * of outliers and is not truncated by the inlier selection. It enters an average
 * that forgets faster the more rows a frame has. Inliers the time bound deferred
 * are left out: on the seed drives and the simulator they measured no better
 * than without them, and worse on 0027 (README, Accuracy).
 *
 * That average moves by a share of the difference, so from an estimate far too
 * large it falls by only that share a frame (from a prior 10x too large, 0027
 * took 80 frames to 2.8 px, against its 0.8): the vision counts for little all
 * that time. A dense frame's sample also enters a fast average of its log-ratio
 * to the estimate; where that average shows the estimate over VL_PIXEL_DROP_RATIO
 * times the recent frames', the estimate goes to their level at once. At the
 * default prior it fires on none of 0027's or 0022's frames and on one of 0034's.
 */
void vl_noise_adapt_pixel(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t used, uint32_t first_rejected,
                          uint32_t k, uint32_t frame_observations)
{
    double samples[VL_OBS_DIM * VL_MAX_LANDMARKS];
    uint32_t n = 0;
    const int sparse = frame_observations < VL_PIXEL_SPARSE_FRAME;
    pixel_samples(e, rows, 0, used, 1.0, sparse, samples, &n);
    pixel_samples(e, rows, first_rejected, k, -1.0, sparse, samples, &n);
    if (n < 3u) {
        return;
    }
    /* The median outvotes a minority of outliers only where a frame has rows enough;
     * on a frame of one or two rows it is an outlier's own sample, which at once can
     * multiply the variance by a hundred. So a sample counts for at most what no
     * Gaussian pixel gives: VL_PIXEL_SAMPLE_CAP times the variance in use. */
    const double cap = VL_PIXEL_SAMPLE_CAP * e->pixel_var;
    for (uint32_t i = 0; i < n; ++i) {
        samples[i] = samples[i] > cap ? cap : samples[i];
    }
    /* A dense frame's median is at or under zero when most of its rows are rejected ones that
     * kept less than the fit's spread (after a burst of bad frames widened the velocity noise, the
     * pose's uncertainty dwarfs the pixels'): it says the pixel noise is small against that spread,
     * not what it is. The floor mirrors the cap, for every frame; unfloored, one such frame took the
     * average under zero, to the clamp 100x under the configured noise (README, Robustness). */
    const double median = vl_noise_select_kth(samples, n, n / 2u) / VL_NOISE_CHI2_1_MEDIAN;
    const double floor = e->pixel_var / VL_PIXEL_SAMPLE_CAP;
    const double sample = median > floor ? median : floor;
    if (!sparse) {
        const double r = log(sample / e->pixel_var);
        e->pixel_log_ratio = (1.0 - VL_PIXEL_DROP_GAIN) * e->pixel_log_ratio + VL_PIXEL_DROP_GAIN * r;
        if (e->pixel_log_ratio < -log(VL_PIXEL_DROP_RATIO)) {
            e->pixel_var = vl_noise_clamp_var(e->pixel_var * exp(e->pixel_log_ratio), e->cfg.pixel_noise);
            e->pixel_log_ratio = 0.0;
            return;
        }
    }
    const double far = VL_PIXEL_FAR_FROM_ROWS * VL_PIXEL_FAR_FROM_ROWS * e->stereo_row_var;
    const double memory =
        e->stereo_row_var > 0.0 && e->pixel_var > far ? VL_PIXEL_NOISE_FAST_MEMORY : VL_PIXEL_NOISE_MEMORY;
    const double w = 1.0 - exp(-(double)(n / VL_OBS_DIM) / memory);
    e->pixel_var = vl_noise_clamp_var((1.0 - w) * e->pixel_var + w * sample, e->cfg.pixel_noise);
}

/*
 * -E[log clamp(q / k, VL_VELOCITY_RATIO_MIN, VL_VELOCITY_RATIO_MAX)] for q ~
 * chi-square(k), at k = 1, 1.5, 2, 2.5, 3 (numerical integration; the NumPy
 * reference holds the same table and tests/python/test_reference.py recomputes it):
 * how far the logarithm of a seen-to-expected ratio falls short of zero on average
 * when the filter is right. Without it the variance settles where that logarithm
 * averages zero, too low by this much (from a prior 10x too small, the simulator's
 * linear velocity noise settled at 0.215 against 0.5 m/s).
 */
static const double vl_log_ratio_bias[5] = {0.768765, 0.593114, 0.479665, 0.400083, 0.341355};

/* The bias at k degrees of freedom, the correction block's effective dimension
 * (tr M)^2 / tr(M^2) (within [1, 3]): linear between the tabulated points. */
static double log_ratio_bias(double k)
{
    const double t = 2.0 * ((k < 1.0 ? 1.0 : (k > 3.0 ? 3.0 : k)) - 1.0);
    const int i = t >= 3.0 ? 3 : (int)t;
    const double f = t - (double)i;
    return (1.0 - f) * vl_log_ratio_bias[i] + f * vl_log_ratio_bias[i + 1];
}

double vl_noise_log_ratio_step(double ratio, double k)
{
    ratio = ratio < VL_VELOCITY_RATIO_MIN ? VL_VELOCITY_RATIO_MIN
                                          : (ratio > VL_VELOCITY_RATIO_MAX ? VL_VELOCITY_RATIO_MAX : ratio);
    return log(ratio) + log_ratio_bias(k);
}

/*
 * Covariance matching for the velocity noise on the pose correction: for a
 * consistent filter E[dx dx^T] = P- - P+ = M on the pose block. More correction
 * than the filter expected means its prediction was too confident (noise too
 * small), less means too timid. Each variance moves by a fraction of log(ratio)
 * plus that logarithm's bias (zero on average when the filter is right).
 *
 * A dense frame (VL_NOISE_DENSE_FRAME observations used) determines the pose
 * by itself, so its correction samples the pose error whatever the prior. It is
 * matched in the body frame, where the velocity noise enters (the pose error's
 * coordinates are the world's, in which a turn about the vehicle shows as a
 * translation p x phi: the linear block would take up angular corrections
 * scaled by the distance from the origin), at a fixed gain. A sparse frame's
 * correction depends as much on the pixel noise it was weighed with; it keeps
 * the world coordinates and a step weighted by the share of the block's prior
 * variance it removed, which is large early in a drive and small once the
 * unobservable drift dominates the prior: sparse frames set the noise early and
 * then hold it. Both measured best of the variants tried (README, Accuracy). A
 * sparse frame matched on its two views before the update
 * (vl_noise_adapt_velocity_two_view) is left alone here; the world-frame rule
 * remains for frames that fused few of many observations (a drive's first frames).
 */
void vl_noise_adapt_velocity(vl_estimator_t *e, const double prior_pose[36], uint32_t used)
{
    double M[36], dx[6];
    double removed[2] = {0.0, 0.0}, prior[2] = {0.0, 0.0};
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < 6; ++j) {
            M[6 * i + j] = prior_pose[6 * i + j] - *vl_P_at(e, (uint32_t)i, (uint32_t)j);
        }
        removed[i / 3] += M[7 * i];
        prior[i / 3] += prior_pose[7 * i];
        dx[i] = e->work_dx[i];
    }
    const int dense = used >= VL_NOISE_DENSE_FRAME;
    if (!dense && e->velocity_matched) {
        return; /* matched on the frame's two views before the update */
    }
    if (dense) {
        double Ad_inv[36], AM[36];
        vl_se3_adjoint_inverse(e->R, e->p, Ad_inv);
        vl_matmul(Ad_inv, M, AM, 6, 6, 6);
        vl_matmul_bt(AM, Ad_inv, M, 6, 6, 6);
        vl_matmul(Ad_inv, e->work_dx, dx, 6, 6, 1);
    }

    double *var[2] = {&e->linear_velocity_var, &e->angular_velocity_var};
    const double configured[2] = {e->cfg.linear_velocity_noise, e->cfg.angular_velocity_noise};
    for (int b = 0; b < 2; ++b) {
        double expected = 0.0, seen = 0.0, spread = 0.0;
        for (int i = 3 * b; i < 3 * b + 3; ++i) {
            expected += M[7 * i];
            seen += dx[i] * dx[i];
            for (int j = 3 * b; j < 3 * b + 3; ++j) {
                spread += M[6 * i + j] * M[6 * i + j];
            }
        }
        if (!(prior[b] > 0.0) || !(removed[b] > VL_VELOCITY_MIN_INFORMATION * prior[b]) || !(expected > 0.0) ||
            !(spread > 0.0)) {
            continue;
        }
        const double gain = dense ? VL_VELOCITY_NOISE_GAIN : VL_VELOCITY_SPARSE_GAIN * (removed[b] / prior[b]);
        *var[b] = vl_noise_clamp_var(
            *var[b] * exp(gain * vl_noise_log_ratio_step(seen / expected, expected * expected / spread)),
            configured[b]);
    }
    vl_noise_reopen_angular_offset(e);
}

/* One variance widened, up to VL_NOISE_WIDEN_RANGE of the configured std (never lowered by it). */
static double widen(double var, double configured_std)
{
    const double top = VL_NOISE_WIDEN_RANGE * VL_NOISE_WIDEN_RANGE * configured_std * configured_std;
    return vl_noise_clamp_var(fmax(var, fmin(var * VL_NOISE_WIDEN_ON_CONTRADICTION, top)), configured_std);
}

/* A tracker re-associates on single frames; frame after frame contradicting the
 * prior means the prior is overconfident. */
void vl_noise_widen(vl_estimator_t *e)
{
    e->linear_velocity_var = widen(e->linear_velocity_var, e->cfg.linear_velocity_noise);
    e->angular_velocity_var = widen(e->angular_velocity_var, e->cfg.angular_velocity_noise);
    e->pixel_var = widen(e->pixel_var, e->cfg.pixel_noise);
    vl_noise_reopen_angular_offset(e);
}

void vl_noise_reopen_angular_offset(vl_estimator_t *e)
{
    if (!e->cfg.estimate_input_offsets || !(e->angular_velocity_var > e->angular_velocity_var_reopened)) {
        return;
    }
    const double rise = e->angular_velocity_var / e->angular_velocity_var_reopened;
    const double prior = e->cfg.angular_offset_prior * e->cfg.angular_offset_prior;
    e->angular_velocity_var_reopened = e->angular_velocity_var;
    const uint32_t n = vl_state_dim(e);
    double *P = vl_P(e);
    for (uint32_t i = VL_IDX_OFFSET_ANG; i < VL_IDX_OFFSET_ANG + 3u; ++i) {
        const double var = P[(size_t)i * VL_LD + i];
        const double f2 = var * rise > prior ? prior / var : rise;
        if (!(f2 > 1.0)) {
            continue; /* at its prior already (or above it, by the offset's walk) */
        }
        const double f = sqrt(f2);
        for (uint32_t j = 0; j < n; ++j) {
            P[(size_t)j * VL_LD + i] *= f; /* row i */
            P[(size_t)i * VL_LD + j] *= f; /* column i; P_ii takes both */
        }
    }
}
