/*
 * The velocity noise of sparse frames, matched on two views. A track seen in
 * the previous frame and in this one, triangulated in the previous camera and
 * moved by the motion predicted between the two frames, predicts this frame's
 * pixels. The residuals of a frame's tracks share one error, that of the
 * predicted motion (the input noise over the interval and the offsets' error);
 * a weighted least-squares fit recovers it with its covariance, and its spread
 * against what the filter expects is covariance matching for the velocity
 * noise. Unlike the update's correction, neither the landmarks' covariance nor
 * the adapted pixel noise enters it (on a sparse frame the correction cannot
 * tell those from the velocity noise, README, Accuracy): the residuals are
 * weighed with the stereo rows' own white noise, the spread of
 * v_left - v_right, which no state error enters. The same residuals, summed
 * per track over consecutive sparse frames, show a track drifting against the
 * velocities' motion: a moving object the single frames let through.
 */
#include "vl_noise.h"

#include <math.h>
#include <string.h>

#include "vl_camera.h"
#include "vl_estimator_internal.h"
#include "vl_guard.h"
#include "vl_predict.h"
#include "vl_se3.h"
#include "vl_stereo.h"
#include "vl_work.h"

/* Observations the stereo rows' white noise averages over (its forgetting scale). */
#define VL_STEREO_ROW_MEMORY 1000.0
/* Largest stereo-row sample, in variances of the estimate: 3 sigma (a Gaussian exceeds it 0.3 % of
 * the time, which lowers the mean by under 1 %). */
#define VL_STEREO_ROW_CAP 9.0
/* Observations from which a frame's stereo rows count (a median of fewer is an outlier's own). */
#define VL_STEREO_ROW_MIN_SAMPLES 3u
/* Tracks in both views from which a frame's motion error is fitted (6 unknowns, 3 rows each). */
#define VL_TWO_VIEW_MIN_PAIRS 3u
/* Step of the velocity noise in log-variance per frame, weighted by the noise's share of the
 * expected spread: the dense frames' step (VL_VELOCITY_NOISE_GAIN in vl_noise.c). */
#define VL_TWO_VIEW_GAIN 0.05
/* A track's clipped two-view residuals summed against their summed covariance: each row clipped
 * at this many of its stds (a track's one jump counts as one std, a drift of one std a frame
 * accumulates), the frames from which the sum counts, and the chi-square with 3 degrees of freedom
 * (99.9 %) over which the track moves on its own. Clipped, a standing track's sum spreads less
 * than the summed covariance, so the test errs towards keeping it; looser clips and thresholds
 * gained more on the simulator's moving points and lost on the real drives (README, Accuracy). */
#define VL_DRIFT_CLIP 1.0
#define VL_DRIFT_MIN_FRAMES 3u
#define VL_DRIFT_CHI2 16.27
/* C99 has no _Static_assert: a negative array size stops the build instead. */
typedef char vl_assert_drift_tracks[(VL_NOISE_DENSE_FRAME <= VL_DRIFT_TRACKS) ? 1 : -1];
/* The moment estimate of each velocity variance over the two-view frames: the frames it forgets
 * over, the frames it needs before it counts, and the factor (in variance) by which it must lie
 * over the variance in use to replace it. Its neighbours (100 and 1,000 frames, 30 frames, 3x and
 * 6x) measured no better over the test bed (README, Accuracy). */
#define VL_TWO_VIEW_MOMENT_MEMORY 300.0
#define VL_TWO_VIEW_MOMENT_MIN_FRAMES 10.0
#define VL_TWO_VIEW_MOMENT_RISE 4.0

void vl_noise_observe_stereo_rows(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    double samples[VL_MAX_FRAME_FEATURES];
    uint32_t n = 0;
    vl_work_stereo_rows(e, count);
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *o = &frame->obs[i];
        if (vl_guard_observation_valid(o) && vl_guard_observation_plausible(e, o)) {
            const double d = o->v_left - o->v_right;
            samples[n++] = 0.5 * d * d; /* v_left - v_right has twice one coordinate's variance */
        }
    }
    if (n < VL_STEREO_ROW_MIN_SAMPLES) {
        return;
    }
    double sample;
    if (e->stereo_row_evidence > 0.0) {
        /* The mean of samples capped at VL_STEREO_ROW_CAP times the estimate: a mismatched
         * observation's rows can disagree by anything, and a median of a sparse frame's few
         * samples is biased (of 2, the larger; of 3, 1.5 times the variance on average). */
        const double cap = VL_STEREO_ROW_CAP * e->stereo_row_var;
        double sum = 0.0;
        for (uint32_t i = 0; i < n; ++i) {
            sum += samples[i] < cap ? samples[i] : cap;
        }
        sample = sum / (double)n;
    } else {
        sample = vl_noise_select_kth(samples, n, n / 2u) / VL_NOISE_CHI2_1_MEDIAN; /* the first estimate */
    }
    if (!(sample > 0.0)) {
        return; /* rows that agree exactly (a tracker that copies v_left) tell nothing */
    }
    /* Evidence-weighted: the first frames set the estimate, later ones refine it. */
    const double held = e->stereo_row_evidence * exp(-(double)n / VL_STEREO_ROW_MEMORY);
    const double w = (double)n / (held + (double)n);
    e->stereo_row_var = (1.0 - w) * e->stereo_row_var + w * sample;
    e->stereo_row_evidence = held + (double)n;
}

/* An observation the window would read (a valid id, finite and plausible pixels) with the
 * disparity a landmark needs. */
static int usable(const vl_estimator_t *e, const vl_stereo_obs_t *o)
{
    return vl_guard_observation_valid(o) && vl_guard_observation_plausible(e, o) &&
           o->u_left - o->u_right >= e->cfg.min_disparity;
}

/* The index of the track's observation in the previous frame, or -1. */
static int previous_observation(const vl_estimator_t *e, int32_t id)
{
    for (uint32_t j = 0; j < e->num_prev_obs; ++j) {
        if (e->prev_obs[j].id == id) {
            return (int)j;
        }
    }
    return -1;
}

/* Lower Cholesky factor L of a symmetric n x n A (row-major; L's upper part zero); -1 when A is
 * not positive definite. */
static int cholesky(const double *A, int n, double *L)
{
    for (int j = 0; j < n; ++j) {
        double d = A[(n + 1) * j];
        for (int k = 0; k < j; ++k) {
            d -= L[n * j + k] * L[n * j + k];
        }
        if (!(d > 0.0)) {
            return -1;
        }
        L[(n + 1) * j] = sqrt(d);
        for (int i = j + 1; i < n; ++i) {
            double s = A[n * i + j];
            for (int k = 0; k < j; ++k) {
                s -= L[n * i + k] * L[n * j + k];
            }
            L[n * i + j] = s / L[(n + 1) * j];
            L[n * j + i] = 0.0;
        }
    }
    return 0;
}

/* x <- L^-1 x for each of the ncols columns of the 3 x ncols row-major x. */
static void forward3(const double L[9], double *x, int ncols)
{
    for (int c = 0; c < ncols; ++c) {
        x[c] /= L[0];
        x[ncols + c] = (x[ncols + c] - L[3] * x[c]) / L[4];
        x[2 * ncols + c] = (x[2 * ncols + c] - L[6] * x[c] - L[7] * x[ncols + c]) / L[8];
    }
}

/* Inverse of a symmetric positive definite 6x6 A (row-major) by Cholesky; -1 when not. */
static int inverse6(const double A[36], double Ainv[36])
{
    double L[36];
    if (cholesky(A, 6, L) != 0) {
        return -1;
    }
    for (int c = 0; c < 6; ++c) {
        double y[6], x[6];
        for (int i = 0; i < 6; ++i) {
            double s = (i == c) ? 1.0 : 0.0;
            for (int k = 0; k < i; ++k) {
                s -= L[6 * i + k] * y[k];
            }
            y[i] = s / L[7 * i];
        }
        for (int i = 5; i >= 0; --i) {
            double s = y[i];
            for (int k = i + 1; k < 6; ++k) {
                s -= L[6 * k + i] * x[k];
            }
            x[i] = s / L[7 * i];
        }
        for (int i = 0; i < 6; ++i) {
            Ainv[6 * i + c] = x[i];
        }
    }
    return 0;
}

/* One track's two views: its terms of the normal equations and its agreement with the prior. */
typedef struct {
    double info[21]; /* H^T W^-1 H, upper triangle by rows */
    double b[6];     /* H^T W^-1 r */
    double rr;       /* r^T W^-1 r */
    double Hr[21];   /* [H | r] whitened by W, 3 x 7 */
    double chi2;     /* r^T (W + H Q H^T)^-1 r, Q the motion error the filter expects */
    double r[3];     /* y - h(predicted motion, previous triangulation), px */
    double S[9];     /* W + H Q H^T, px^2 */
} vl_two_view_track_t;

/* Index of (i, j), i <= j, in a 6x6 upper triangle stored by rows. */
static int upper6(int i, int j)
{
    return 6 * i - i * (i - 1) / 2 + (j - i);
}

/*
 * One track's residual r = y - h(predicted motion, previous triangulation)
 * = H delta + e in the motion error delta (right perturbation of the predicted
 * pose), e this observation's pixel noise and the previous one's carried through
 * its triangulation, both at the stereo rows' white noise (nv). q is the
 * diagonal of the motion error's expected covariance. 0 when the track gave terms.
 */
static int track_terms(const vl_estimator_t *e, const double nv[3], const double q[6], const vl_stereo_obs_t *prev,
                       const vl_stereo_obs_t *now, vl_two_view_track_t *t)
{
    double y0[3], y1[3], pw[3], dpw_dy[9];
    vl_stereo_compress(prev, y0);
    vl_stereo_compress(now, y1);
    vl_camera_triangulate_at(e, e->frame_R, e->frame_p, y0, pw, dpw_dy); /* at the previous frame's pose */

    double y_pred[3], H[18], dy_dpw[9];
    if (vl_camera_project_world(e, pw, y_pred, H, dy_dpw) != 0) {
        return -1;
    }
    double A[9], AN[9], W[9], S[9], L[9];
    vl_matmul(dy_dpw, dpw_dy, A, 3, 3, 3); /* this frame's pixels from the previous frame's */
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            AN[3 * i + j] = A[3 * i + j] * nv[j];
        }
    }
    vl_matmul_bt(AN, A, W, 3, 3, 3);
    for (int i = 0; i < 3; ++i) {
        W[4 * i] += nv[i];
    }
    double HQ[18], r[3];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 6; ++j) {
            HQ[6 * i + j] = H[6 * i + j] * q[j];
        }
        r[i] = y1[i] - y_pred[i];
    }
    vl_matmul_bt(HQ, H, S, 3, 6, 3);
    for (int i = 0; i < 9; ++i) {
        S[i] += W[i];
    }
    t->chi2 = vl_mahalanobis3(S, r);
    memcpy(t->r, r, sizeof(t->r));
    memcpy(t->S, S, sizeof(t->S));
    if (cholesky(W, 3, L) != 0) {
        return -1;
    }
    double Hr[21]; /* [H | r], whitened together */
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 6; ++j) {
            Hr[7 * i + j] = H[6 * i + j];
        }
        Hr[7 * i + 6] = r[i];
    }
    forward3(L, Hr, 7);
    for (int i = 0; i < 6; ++i) {
        for (int j = i; j < 6; ++j) {
            t->info[upper6(i, j)] = Hr[i] * Hr[j] + Hr[7 + i] * Hr[7 + j] + Hr[14 + i] * Hr[14 + j];
        }
        t->b[i] = Hr[i] * Hr[6] + Hr[7 + i] * Hr[13] + Hr[14 + i] * Hr[20];
    }
    t->rr = Hr[6] * Hr[6] + Hr[13] * Hr[13] + Hr[20] * Hr[20];
    for (int i = 0; i < 21; ++i) {
        t->Hr[i] = Hr[i];
    }
    return 0;
}

/*
 * The frame enters block's moment estimate of its velocity variance; 1 when the
 * estimate replaced *var. E[seen] = c + var a, with a = 3 sum tau^2 the noise's
 * part per unit variance and c the rest of the expectation (the fit's and the
 * offsets'), solved by least squares over the frames, each weighted by the
 * inverse of its spread's variance (2 tr M^2), its seen capped as the log step's
 * ratio is (a moving object's track can make one frame's anything). Unlike the
 * log step it needs no share and no bias. It replaces the variance only upwards:
 * a downward jump to an estimate made noisy by a small noise share lands under
 * the truth, and the simulator's sparse drives then leave their NEES bounds
 * (README, Accuracy).
 */
static int moment_rise(vl_estimator_t *e, int block, double seen, double expected, double spread, double *var,
                       double configured_std)
{
    const double keep = exp(-1.0 / VL_TWO_VIEW_MOMENT_MEMORY);
    const double a = 3.0 * e->step_noise_time2, w = 1.0 / (2.0 * spread);
    const double capped = fmin(seen, VL_VELOCITY_RATIO_MAX * expected);
    e->velocity_moment_num[block] = keep * e->velocity_moment_num[block] + w * a * (capped - (expected - *var * a));
    e->velocity_moment_den[block] = keep * e->velocity_moment_den[block] + w * a * a;
    e->velocity_moment_frames[block] = keep * e->velocity_moment_frames[block] + 1.0;
    const double estimate = e->velocity_moment_num[block] / e->velocity_moment_den[block];
    if (e->velocity_moment_frames[block] < VL_TWO_VIEW_MOMENT_MIN_FRAMES ||
        !(estimate > VL_TWO_VIEW_MOMENT_RISE * *var)) {
        return 0;
    }
    *var = vl_noise_clamp_var(estimate, configured_std);
    return 1;
}

/*
 * One block (linear or angular) of the fitted motion error: its spread against
 * the expected one, the fit's own covariance plus the input noise over the
 * interval (the velocity variance x sum tau^2, per axis) and the offsets' error
 * (their variance x (sum tau)^2), moves the velocity variance by a step weighted
 * by the noise's share of that expectation (a block the fit leaves uncertain, or
 * that the offsets' error dominates, says little about the noise). That weight
 * makes a prior far too small slow to leave (10x too small, its share is about a
 * tenth: 0027 given at 1 track in 20 took 500 frames to climb), which the moment
 * estimate's rise (moment_rise) answers.
 */
static void match_block(vl_estimator_t *e, int block, const double C[36], const double dx[6], const double q[6],
                        double *var, double configured_std)
{
    double M[9], seen = 0.0;
    const double noise = *var * e->step_noise_time2;
    for (int i = 0; i < 3; ++i) {
        seen += dx[3 * block + i] * dx[3 * block + i];
        for (int j = 0; j < 3; ++j) {
            M[3 * i + j] = C[6 * (3 * block + i) + 3 * block + j];
        }
        M[4 * i] += q[3 * block + i];
    }
    const double expected = M[0] + M[4] + M[8];
    double spread = 0.0;
    for (int i = 0; i < 9; ++i) {
        spread += M[i] * M[i];
    }
    if (!(expected > 0.0) || !(spread > 0.0) || !(noise > 0.0)) {
        return;
    }
    if (moment_rise(e, block, seen, expected, spread, var, configured_std)) {
        return;
    }
    const double gain = VL_TWO_VIEW_GAIN * 3.0 * noise / expected;
    *var = vl_noise_clamp_var(*var * exp(gain * vl_noise_log_ratio_step(seen / expected, expected * expected / spread)),
                              configured_std);
}

/* The normal equations of the tracks t with skip[t] == 0, the upper triangle mirrored; their count. */
static uint32_t sum_tracks(const vl_two_view_track_t *tracks, uint32_t n, const uint8_t *skip, double info[36],
                           double b[6], double *rr)
{
    uint32_t used = 0;
    for (int i = 0; i < 36; ++i) {
        info[i] = 0.0;
    }
    for (int i = 0; i < 6; ++i) {
        b[i] = 0.0;
    }
    *rr = 0.0;
    for (uint32_t t = 0; t < n; ++t) {
        if (skip[t]) {
            continue;
        }
        for (int i = 0; i < 6; ++i) {
            for (int j = i; j < 6; ++j) {
                info[6 * i + j] += tracks[t].info[upper6(i, j)];
            }
            b[i] += tracks[t].b[i];
        }
        *rr += tracks[t].rr;
        used++;
    }
    for (int i = 0; i < 6; ++i) {
        for (int j = 0; j < i; ++j) {
            info[6 * i + j] = info[6 * j + i];
        }
    }
    return used;
}

/*
 * The tracks that moved against the others (a moving object, a re-associated id):
 * each one's residual against the motion the other tracks fit, at its white noise
 * plus that fit's uncertainty, beyond the gate. The others are those the fit keeps
 * (left_out: the ones that alone contradict the expected motion, so that two
 * gross outliers do not spoil each other's reference). A track is judged against
 * the others' motion, not against the expected one, so a velocity noise set too
 * small does not make true motion look like a moving track. When half or more of
 * the frame's tracks fail, none is flagged: the frame disagrees with itself (its
 * fit residual is judged instead).
 */
static void flag_moved(vl_estimator_t *e, const vl_two_view_track_t *tracks, const uint32_t *obs, uint32_t n,
                       const uint8_t *left_out)
{
    if (n < VL_TWO_VIEW_MIN_PAIRS + 1u || e->cfg.gate_chi2 <= 0.0) {
        return;
    }
    uint8_t skip[VL_NOISE_DENSE_FRAME], moved[VL_NOISE_DENSE_FRAME] = {0};
    uint32_t flagged = 0;
    for (uint32_t t = 0; t < n; ++t) {
        skip[t] = left_out[t];
    }
    for (uint32_t t = 0; t < n; ++t) {
        double info[36], b[6], rr, C[36], dx[6];
        const uint8_t own = skip[t];
        skip[t] = 1;
        const uint32_t others = sum_tracks(tracks, n, skip, info, b, &rr);
        skip[t] = own;
        if (others < VL_TWO_VIEW_MIN_PAIRS || inverse6(info, C) != 0) {
            continue;
        }
        vl_matmul(C, b, dx, 6, 6, 1);
        const double *Hr = tracks[t].Hr;
        double r[3], HC[18], S[9];
        for (int i = 0; i < 3; ++i) {
            r[i] = Hr[7 * i + 6];
            for (int j = 0; j < 6; ++j) {
                r[i] -= Hr[7 * i + j] * dx[j];
                HC[6 * i + j] = 0.0;
                for (int k = 0; k < 6; ++k) {
                    HC[6 * i + j] += Hr[7 * i + k] * C[6 * k + j];
                }
            }
        }
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) {
                S[3 * i + j] = i == j ? 1.0 : 0.0;
                for (int k = 0; k < 6; ++k) {
                    S[3 * i + j] += HC[6 * i + k] * Hr[7 * j + k];
                }
            }
        }
        moved[t] = !(vl_mahalanobis3(S, r) <= e->cfg.gate_chi2);
        flagged += moved[t];
    }
    if (2u * flagged < n) {
        for (uint32_t t = 0; t < n; ++t) {
            if (moved[t]) {
                e->work_moved[obs[t]] = 1;
            }
        }
    }
}

/*
 * A track moving on its own can agree with each frame's expected motion within its spread while
 * it drifts against it frame after frame (a far car is a compass that turns: 3 m/s across at 50 m
 * is about one std of a frame's expected motion), and on a sparse frame it may be a third of what
 * corrects the pose. Its two-view residuals, each against the velocities' motion from the previous
 * frame (which the update does not move), are independent errors for a standing point and share
 * the drift's sign for a moving one.
 */
static void drift_step(const vl_two_view_track_t *t, const vl_track_drift_t *prev, vl_track_drift_t *d, uint8_t *moved)
{
    if (d->moving) {
        return;
    }
    *d = *prev;
    for (int i = 0; i < 3; ++i) {
        const double c = VL_DRIFT_CLIP * sqrt(t->S[4 * i]);
        d->residual[i] += fmax(-c, fmin(c, t->r[i]));
    }
    for (int i = 0; i < 9; ++i) {
        d->covariance[i] += t->S[i];
    }
    d->frames++;
    if (d->frames >= VL_DRIFT_MIN_FRAMES && !(vl_mahalanobis3(d->covariance, d->residual) <= VL_DRIFT_CHI2)) {
        memset(d, 0, sizeof(*d));
        d->moving = 1;
        *moved = 1;
    }
}

void vl_noise_carry_drift(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count)
{
    /* A dense frame's RANSAC judges its tracks; the sums start again after it. */
    e->num_work_drift = count < VL_NOISE_DENSE_FRAME ? count : 0u;
    memset(e->work_drift, 0, e->num_work_drift * sizeof(e->work_drift[0]));
    if (e->num_work_drift == 0u || e->num_prev_drift == 0u) {
        return; /* nothing to carry from a dense frame */
    }
    vl_work_drift_carry(e, e->num_work_drift, e->num_prev_obs);
    for (uint32_t i = 0; i < e->num_work_drift; ++i) {
        const int j = previous_observation(e, frame->obs[i].id);
        if (j >= 0 && (uint32_t)j < e->num_prev_drift && e->prev_drift[j].moving) {
            e->work_drift[i].moving = 1; /* broken when found: no landmark of it to break again */
        }
    }
}

void vl_noise_keep_drift(vl_estimator_t *e)
{
    e->num_prev_drift = e->num_work_drift;
    memcpy(e->prev_drift, e->work_drift, e->num_prev_drift * sizeof(e->work_drift[0]));
}

int vl_noise_track_moving(const vl_estimator_t *e, uint32_t obs)
{
    return obs < e->num_work_drift && e->work_drift[obs].moving;
}

/* The 99 % quantile of chi-square with k >= 1 degrees of freedom (Wilson and Hilferty's cube:
 * within 2 % of the exact value from k = 3 on; at k = 1 and 2 the exact 6.63 and 9.21). */
static double chi2_quantile_99(uint32_t k)
{
    if (k == 0u) {
        return 0.0;
    }
    if (k <= 2u) {
        return k == 1u ? 6.635 : 9.210;
    }
    const double h = 2.0 / (9.0 * (double)k), c = 1.0 - h + 2.3263 * sqrt(h);
    return (double)k * c * c * c;
}

/* The sensor position's share of the expected motion error (input, 6 x 6, the input rows'
 * covariance): with Js = (hat(W); 0), W = sum tau w, Js P_ss Js^T and its cross terms with the
 * offsets, t (Js P_sb + P_bs Js^T). */
static void add_sensor_motion_error(const vl_estimator_t *e, double input[36])
{
    double W[9], Ps[3 * VL_PARAM_DIM], WPs[3 * VL_PARAM_DIM], WPss[9], WPW[9];
    vl_skew(e->step_turn, W);
    for (uint32_t i = 0; i < 3; ++i) { /* the sensor's rows against the parameters: [P_sb, P_ss] */
        for (uint32_t j = 0; j < VL_PARAM_DIM; ++j) {
            Ps[VL_PARAM_DIM * i + j] = vl_P_value(e, VL_IDX_SENSOR + i, VL_IDX_PARAM + j);
        }
    }
    vl_matmul(W, Ps, WPs, 3, 3, VL_PARAM_DIM); /* [Js P_sb, W P_ss] on Js's linear rows */
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            WPss[3 * i + j] = WPs[VL_PARAM_DIM * i + 6 + j];
        }
    }
    vl_matmul_bt(WPss, W, WPW, 3, 3, 3);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            input[6 * i + j] += WPW[3 * i + j];
        }
        for (int j = 0; j < 6; ++j) {
            const double v = e->step_time * WPs[VL_PARAM_DIM * i + j];
            input[6 * i + j] += v;
            input[6 * j + i] += v;
        }
    }
}

/* The motion error the filter expects over the interval, per axis of the body frame: the input
 * noise (the velocity variance x sum tau^2) and the parameters' error, J P_tt J^T with
 * J = [sum tau I, (hat(sum tau w); 0)] (an offset error acts over the whole interval, a sensor
 * position error through the turn), both through the input map T = [I hat(p); 0 I] of a velocity
 * sensor at p, which the prediction applies: there the angular noise and offsets reach the
 * linear motion as hat(p) times them. The diagonal of T Q T^T, as the fit weighs each axis on its
 * own. */
static void expected_motion_error(const vl_estimator_t *e, double q[6])
{
    double input[36] = {0}, skew[9];
    for (int i = 0; i < 6; ++i) {
        input[7 * i] = (i < 3 ? e->linear_velocity_var : e->angular_velocity_var) * e->step_noise_time2;
    }
    if (e->cfg.estimate_input_offsets) {
        const double t2 = e->step_time * e->step_time;
        for (int i = 0; i < 6; ++i) {
            for (int j = 0; j <= i; ++j) {
                const double v = vl_P_value(e, VL_IDX_OFFSET_LIN + (uint32_t)i, VL_IDX_OFFSET_LIN + (uint32_t)j) * t2;
                input[6 * i + j] += v;
                input[6 * j + i] += i != j ? v : 0.0;
            }
        }
    }
    if (vl_predict_sensor_estimated(e)) {
        add_sensor_motion_error(e, input);
    }
    for (int i = 0; i < 6; ++i) {
        q[i] = input[7 * i];
    }
    if (!vl_predict_sensor_skew(e, skew)) {
        return;
    }
    /* (T Q T^T)_ii on the linear rows: Q_ii + 2 (hat(p) Q_al)_ii + (hat(p) Q_aa hat(p)^T)_ii. */
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            q[i] += 2.0 * skew[3 * i + j] * input[6 * (3 + j) + i];
            for (int k = 0; k < 3; ++k) {
                q[i] += skew[3 * i + j] * input[6 * (3 + j) + 3 + k] * skew[3 * i + k];
            }
        }
    }
}

int vl_noise_adapt_velocity_two_view(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count,
                                     uint8_t *contradicted)
{
    if (count >= VL_NOISE_DENSE_FRAME || !(e->stereo_row_var > 0.0) || !(e->step_noise_time2 > 0.0)) {
        return 0;
    }
    double nv[3], q[6];
    vl_stereo_noise_var(e->stereo_row_var, nv);
    expected_motion_error(e, q);
    static const vl_track_drift_t none = {{0.0}, {0.0}, 0u, 0u}; /* a track the previous frame did not sum */
    vl_two_view_track_t tracks[VL_NOISE_DENSE_FRAME];
    uint32_t obs[VL_NOISE_DENSE_FRAME], prev_index[VL_NOISE_DENSE_FRAME];
    uint32_t n = 0, contradicting = 0;
    for (uint32_t i = 0; i < count; ++i) {
        const vl_stereo_obs_t *now = &frame->obs[i];
        if (!usable(e, now)) {
            continue;
        }
        const int j = previous_observation(e, now->id);
        if (j < 0 || !usable(e, &e->prev_obs[j])) {
            continue;
        }
        if (track_terms(e, nv, q, &e->prev_obs[j], now, &tracks[n]) == 0) {
            contradicting += !(tracks[n].chi2 <= e->cfg.gate_chi2);
            drift_step(&tracks[n], (uint32_t)j < e->num_prev_drift ? &e->prev_drift[j] : &none, &e->work_drift[i],
                       &e->work_moved[i]);
            prev_index[n] = (uint32_t)j;
            obs[n++] = i;
        }
    }
    vl_work_two_view(e, count, e->num_prev_obs, n);
    /* A track that alone contradicts the expected motion is left out of the fit (a moving
     * object, a re-association); when most do, the motion was off, and all count. A track
     * that does so in two frames in a row moves on its own: a frame's motion error is
     * independent of the next's, so a static track seldom repeats it (README, Accuracy). */
    const int drop = 2u * contradicting < n && e->cfg.gate_chi2 > 0.0;
    uint8_t skip[VL_NOISE_DENSE_FRAME];
    for (uint32_t t = 0; t < n; ++t) {
        skip[t] = drop && !(tracks[t].chi2 <= e->cfg.gate_chi2);
        contradicted[obs[t]] = skip[t];
        if (skip[t] && e->prev_contradicted[prev_index[t]]) {
            e->work_moved[obs[t]] = 1;
        }
    }
    flag_moved(e, tracks, obs, n, skip);
    double info[36], b[6], rr, C[36], dx[6];
    const uint32_t used = sum_tracks(tracks, n, skip, info, b, &rr);
    if (used < VL_TWO_VIEW_MIN_PAIRS || inverse6(info, C) != 0) {
        return 0;
    }
    vl_matmul(C, b, dx, 6, 6, 1);
    /* Tracks that do not agree on one motion at the white noise (a moving object's among
     * static ones, a re-associated id) would make the fit's error anything: the frame says
     * nothing about the velocity noise. The fit's residual is chi-square with 3 used - 6
     * degrees of freedom when they agree. */
    double fit = rr;
    for (int i = 0; i < 6; ++i) {
        fit -= b[i] * dx[i];
    }
    if (!(fit <= chi2_quantile_99(3u * used - 6u))) {
        return 1;
    }
    match_block(e, 0, C, dx, q, &e->linear_velocity_var, e->cfg.linear_velocity_noise);
    match_block(e, 1, C, dx, q, &e->angular_velocity_var, e->cfg.angular_velocity_noise);
    vl_noise_reopen_angular_offset(e);
    return 1;
}
