/*
 * Outliers. Each frame the tracked observations are gated on their innovation;
 * a frame where most fail is a re-association (the seed data's tracker, when it
 * detects new features, hands existing ids to other points, whose pixels jump
 * tens of pixels from the point's history and agree with its future).
 * Otherwise 1-point RANSAC picks the consensus set for the joint update, and
 * the rest are rescued if they agree with the corrected state.
 */
#include "vl_outliers.h"

#include <string.h>

#include "vl_camera.h"
#include "vl_estimator_internal.h"
#include "vl_update.h"

/* Squared pixel length of a row's residual after a correction dx. */
static double residual_after(const vl_la_obs_t *row, const double *dx)
{
    double acc = 0.0;
    const double *dl = &dx[row->landmark_col];
    for (int r = 0; r < 3; ++r) {
        double v = row->residual[r];
        for (int j = 0; j < 6; ++j) {
            v -= row->H_pose[6 * r + j] * dx[j];
        }
        for (int j = 0; j < 3; ++j) {
            v -= row->H_landmark[3 * r + j] * dl[j];
        }
        acc += v * v;
    }
    return acc;
}

/*
 * A hypothesis always explains its own observation: its support says something
 * only when it holds another one too. A frame without such a consensus (a sparse
 * frame whose few observations disagree pairwise) keeps the gate's verdict on each
 * observation against the predicted state instead of trusting one at random.
 */
#define VL_RANSAC_MIN_CONSENSUS 2u

/* splitmix64: hypotheses drawn from the frame index, so a replay draws the same ones. */
static uint64_t next_random(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

uint32_t vl_outliers_gate(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k)
{
    uint32_t failed = 0;
    for (uint32_t i = 0; i < k; ++i) {
        double S[9];
        vl_la_obs_covariance(vl_P(e), VL_LD, &rows[i], NULL, S); /* before the frame's updates */
        e->work_inlier[i] = vl_mahalanobis3(S, rows[i].residual) <= e->cfg.gate_chi2;
        failed += !e->work_inlier[i];
    }
    return failed;
}

int vl_outliers_reassociated(const vl_estimator_t *e, uint32_t k, uint32_t contradicting)
{
    return k >= VL_MIN_ROWS_FOR_REASSOCIATION && (double)contradicting > e->cfg.max_broken_fraction * (double)k;
}

void vl_outliers_break_all(vl_estimator_t *e, uint32_t k)
{
    for (uint32_t i = 0; i < k; ++i) {
        vl_track_break(e, e->work_slot[i], e->work_frame_obs[i]);
    }
}

/*
 * Each hypothesis is the state one observation alone would give; the
 * observations it explains to within ransac_threshold pixels are its support.
 * The best supported set of at least VL_RANSAC_MIN_CONSENSUS replaces the gate's
 * flags in work_inlier; without one the gate's flags stay.
 */
void vl_outliers_ransac(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k)
{
    uint8_t *inlier = e->work_inlier;
    const int n = (int)vl_state_dim(e);
    const double thr2 = e->cfg.ransac_threshold * e->cfg.ransac_threshold;
    const uint32_t hypotheses = e->cfg.ransac_hypotheses < k ? e->cfg.ransac_hypotheses : k;
    uint32_t best_support = 0;
    uint64_t rng = e->frame_index;
    for (uint32_t h = 0; h < hypotheses; ++h) {
        const uint32_t pick = (uint32_t)(next_random(&rng) % k);
        if (vl_la_single_correction(vl_P(e), VL_LD, n, &rows[pick], e->work_PHt, e->work_dx) != 0) {
            continue;
        }
        uint8_t *flags = e->work_support;
        uint32_t support = 0;
        for (uint32_t i = 0; i < k; ++i) {
            flags[i] = residual_after(&rows[i], e->work_dx) <= thr2;
            support += flags[i];
        }
        if (support > best_support && support >= VL_RANSAC_MIN_CONSENSUS) {
            best_support = support;
            memcpy(inlier, flags, k);
        }
    }
}

uint32_t vl_outliers_partition(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t k)
{
    uint8_t *inlier = e->work_inlier;
    uint32_t m = 0;
    for (uint32_t i = 0; i < k; ++i) {
        if (inlier[i]) {
            vl_rows_swap(e, rows, m, i);
            uint8_t t = inlier[m];
            inlier[m] = inlier[i];
            inlier[i] = t;
            m++;
        }
    }
    return m;
}

uint32_t vl_outliers_rescue(vl_estimator_t *e, const vl_stereo_frame_t *frame, vl_la_obs_t *rows, uint32_t first,
                            uint32_t count)
{
    const vl_la_pending_t pending = vl_update_pending(e); /* the inliers' update's */
    uint32_t m = 0;
    for (uint32_t i = first; i < first + count; ++i) {
        const uint32_t slot = e->work_slot[i];
        vl_la_obs_t row;
        if (vl_update_make_row(e, slot, &frame->obs[e->work_frame_obs[i]], &row) != 0) {
            continue;
        }
        double S[9];
        vl_la_obs_covariance(vl_P(e), VL_LD, &row, &pending, S);
        if (vl_mahalanobis3(S, row.residual) <= e->cfg.gate_chi2) {
            rows[m] = row;
            e->work_frame_obs[m] = e->work_frame_obs[i]; /* m <= i: nothing yet to read is overwritten */
            e->work_slot[m] = slot;
            m++;
        } else {
            vl_track_break(e, slot, e->work_frame_obs[i]);
        }
    }
    return m;
}
