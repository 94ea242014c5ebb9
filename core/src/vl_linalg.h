/**
 * @file vl_linalg.h
 * @brief The dense linear algebra of the filter: a thin C API over Eigen (internal to core/).
 *
 * The joint covariance P is column-major with a fixed leading dimension ld
 * (VL_COV_LD), so adding or dropping a landmark never moves the rest.
 * Every function works in the caller's buffers and never allocates: in the
 * checked build (EIGEN_RUNTIME_NO_MALLOC) any heap use inside Eigen aborts.
 */
#ifndef VISLAM_VL_LINALG_H
#define VISLAM_VL_LINALG_H

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** One observation's Jacobian blocks, residual and noise (declared in vislam.h). */
typedef vl_obs_row_t vl_la_obs_t;

/** Buffers the joint update may use; sizes in doubles. */
typedef struct {
    double *PHt;                     /**< >= n4 * m (n4: see vl_la_update) */
    double *S;                       /**< >= m * m */
    double *dx;                      /**< >= n4: the state correction on success (zero past n) */
    vl_parallel_for_fn parallel_for; /**< optional (vl_config_t::parallel_for); NULL = serial */
    void *parallel_ctx;              /**< passed to parallel_for */
} vl_la_workspace_t;

/**
 * Fixes Eigen's cache-blocking sizes (process-wide) so that products block the
 * same way, and round the same way, on every host. Idempotent; vl_init calls it.
 */
void vl_la_configure(void);

/**
 * Prediction step of the core block (VL_CORE_DIM states) in invariant error coordinates, where the
 * error only moves through the inputs: with G the input noise's Jacobian and Gt the parameters'
 * (offsets, sensor position), both nonzero on the pose rows only and given as those rows (Gp
 * 6 x 6 and Gt 6 x VL_PARAM_DIM, row-major),
 *   P <- Phi P Phi^T + G diag(noise_var) G^T + (1 - a^2) E_b R E_b^T (+ diag(offset_var) on
 *   the offsets' states 6..11),
 *   Phi = [I Gt; 0 D] with E selecting the parameter states 6..VL_CORE_DIM-1 and D = diag(a I6, I3):
 *   the offsets decay by a per step (their correlations with the rest fade) and their block is
 *   refilled from R, the offsets' 6 x 6 block of the estimator's P before the step (column-major),
 *   so that P keeps it. Gt NULL when no parameter is estimated (Phi = I; a and R unused).
 */
void vl_la_propagate(double *P, int ld, const double Gp[36], const double *Gt, const double noise_var[6],
                     const double offset_var[6], double a, const double R[36]);

/**
 * Applies a deferred prediction (vl_deferred_prediction_t: K steps whose core
 * block is already in P) to the landmark rows and columns of P. With
 * U = [B, E] (n x VL_CORE_DIM: identity on the core rows, hat(l_s) times the rotation
 * rows' selector on landmark s's rows), Y and A the steps' transition and noise
 * in core coordinates and P0 the core block before them,
 *   P <- P + U Z^T + Z U^T,  Z = M Y^T + U A / 2,  M = P E + U Y Pbb0 / 2:
 * for each landmark its rows against the core (O(1) each), then one symmetric
 * rank-6 product on the landmark block.
 * @param points the landmarks' world points (3 each), or NULL when B's landmark
 *               rows are zero (mapping: the trajectory is taken as known)
 * @param work   >= 12 (n - VL_CORE_DIM) doubles
 */
void vl_la_settle(double *P, int ld, int n, const vl_deferred_prediction_t *d, const double *points, double *work);

/**
 * One landmark's rows as vl_la_settle leaves them, P untouched: against the
 * core (3 x VL_CORE_DIM, column-major) and its own 3 x 3 block.
 * @param col   the landmark's first state index
 * @param point its world point, or NULL as in vl_la_settle
 */
void vl_la_settled_landmark(const double *P, int ld, int col, const vl_deferred_prediction_t *d, const double *point,
                            double cross[3 * VL_CORE_DIM], double block[9]);

/**
 * A downdate of P's landmark block (rows and columns from VL_CORE_DIM on) not
 * applied yet: there P stands for P - W W^T, W the first cols columns of a
 * column-major buffer of `rows` rows (vl_la_padded_rows). Outside that block P
 * is current.
 */
typedef struct {
    const double *W;
    int rows;
    int cols;
} vl_la_pending_t;

/** The rows the update's products run on for n states: n rounded up to a multiple of 4, at most ld. */
int vl_la_padded_rows(int n, int ld);

/**
 * Joint EKF update with k stereo observations (m = 3k rows), touching only the
 * observed columns to form P H^T, one Cholesky factorization of S = H P H^T + R
 * and a symmetric rank-m downdate P -= (P H^T L^-T)(P H^T L^-T)^T.
 * The whitening W = P H^T L^-T (by blocks of rows) and the downdate (by panels
 * of columns) go through ws->parallel_for when set and the loop is costly
 * (8 Mflop in its blocks): the blocks are fixed by the dimensions alone and written
 * by disjoint tasks, so P and dx are bit-identical however many threads run them.
 * They run on n4 = min(n rounded up to a multiple of 4, ld) rows: P's rows n..n4-1,
 * which belong to no state, are overwritten with zeros.
 * @param nis optional (NULL: not wanted): on success the normalized innovation
 *        squared r^T S^-1 r, the whitened innovation's squared norm (the
 *        factorization's by-product; chi-square with m degrees of freedom when the
 *        noise model fits).
 * @return 0 on success with ws->dx holding the correction; -1 when S is not
 *         positive definite (P is then unchanged).
 */
int vl_la_update(double *P, int ld, int n, const vl_la_obs_t *obs, int k, const vl_la_workspace_t *ws, double *nis);

/**
 * vl_la_update up to the landmark block's downdate, against P with the downdate of
 * ws->PHt's first `pending` columns still to come (vl_la_pending_t): the update's W
 * goes to ws->PHt's columns [pending, pending + 3k) (rows as vl_la_padded_rows), the
 * core's rows and columns of P are downdated now, and the landmark block's downdate
 * by all pending + 3k columns is left to vl_la_downdate_landmarks. The correction
 * is the full update's. ws->S must hold m (m + pending) doubles (m = 3k).
 * @return 0 on success with ws->dx holding the correction; -1 when S is not
 *         positive definite (P and the pending columns are then unchanged).
 */
int vl_la_update_core(double *P, int ld, int n, const vl_la_obs_t *obs, int k, const vl_la_workspace_t *ws, int pending,
                      double *nis);

/** The landmark block's downdate by ws->PHt's first cols columns (vl_la_update_core), mirrored. */
void vl_la_downdate_landmarks(double *P, int ld, int n, const vl_la_workspace_t *ws, int cols);

/** W_l W_l^T for the landmark whose first state is col (column-major 3x3): what its block of P
 * still owes the pending downdate (zero when nothing is pending or col is in the core). */
void vl_la_pending_share(const vl_la_pending_t *pending, int col, double block[9]);

/**
 * Appends a landmark block at state index n (P grows to n + 3):
 * P_new,j = J_pose P_pose,j for j < n, and
 * P_new,new = J_pose P_pose,pose J_pose^T + J_obs diag(noise_var) J_obs^T.
 * @param J_pose 3x6 row-major (may be all zero: pose treated as known);
 * @param J_obs 3x3 row-major.
 */
void vl_la_append_landmark(double *P, int ld, int n, const double J_pose[18], const double J_obs[9],
                           const double noise_var[3]);

/** Moves the 3-state block at src onto dst (rows and columns): exact marginalization of dst's old block. */
void vl_la_move_block(double *P, int ld, int n, int dst, int src);

/**
 * The correction one observation alone would make: dx = P H^T S^-1 r (n entries),
 * using work (>= 3 n doubles). Drives the 1-point RANSAC hypotheses.
 * @return 0, or -1 when S is not positive definite.
 */
int vl_la_single_correction(const double *P, int ld, int n, const vl_la_obs_t *obs, double *work, double *dx);

/** 3x3 innovation covariance of one observation: H P H^T + R over its pose and landmark blocks,
 * with the pending downdate applied to its landmark block (pending NULL: none). */
void vl_la_obs_covariance(const double *P, int ld, const vl_la_obs_t *obs, const vl_la_pending_t *pending, double S[9]);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_VL_LINALG_H */
