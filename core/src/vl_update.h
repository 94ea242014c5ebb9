/**
 * @file vl_update.h
 * @brief The update: one observation's rows, the joint update and the state
 *        correction (internal to core/).
 *
 * The rows of a frame live in e->work_rows[0 .. k); work_slot and work_frame_obs
 * hold, for each row, its window slot and its index in the frame. Every
 * reordering of the rows goes through vl_rows_swap, which keeps the three together.
 */
#ifndef VISLAM_VL_UPDATE_H
#define VISLAM_VL_UPDATE_H

#include "vislam/vislam.h"

#include "vl_linalg.h"

/**
 * Update rows of one window landmark's observation at the current state.
 * @return 0, or -1 when the landmark is predicted behind the camera (row unset).
 */
int vl_update_make_row(const vl_estimator_t *e, uint32_t slot, const vl_stereo_obs_t *o, vl_la_obs_t *row);

/** Swaps rows a and b together with their slot and frame index. */
void vl_rows_swap(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t a, uint32_t b);

/**
 * Most observations one frame's updates may use now: max_update_observations,
 * lowered by max_update_work at the current state size (at least 1); 0 = all.
 */
uint32_t vl_rows_cap(const vl_estimator_t *e);

/**
 * The time bound: when more than cap rows (vl_rows_cap; 0 = all) are given,
 * an evenly spread subset of that many (rotate_deferred: those of the landmarks
 * the updates used least, then longest ago) moves to the front and the others
 * are counted as deferred. Returns how many rows the update uses.
 */
uint32_t vl_rows_limit(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t m, uint32_t cap);

/**
 * Holds rows [first, end) (the inliers the time bound deferred) for vl_update_deferred, by
 * their frame observation (apply_deferred on; none otherwise).
 */
void vl_rows_hold(vl_estimator_t *e, uint32_t first, uint32_t end);

/** The held observations not applied: counted in observations_deferred_dropped, then forgotten. */
void vl_rows_drop_held(vl_estimator_t *e);

/**
 * The held observations as rows at the current state, in e->work_rows: those whose landmark
 * is still in the window and that pass the gate again (the others counted in
 * observations_gated, or observations_deferred_dropped when the landmark is gone), at most
 * what max_deferred_work allows (the rest dropped). Returns how many.
 */
uint32_t vl_rows_from_held(vl_estimator_t *e);

/**
 * Joint update with the first m rows, then the state correction it gives
 * (left in e->work_dx). The downdate of P's landmark block is left pending
 * (e->pending_cols; vl_update_pending, vl_update_downdate): the core's rows and
 * columns are current at once. Counts observations_used, or numerical_failures.
 * @return VL_OK, or VL_ERR_NOT_POSITIVE_DEFINITE with P and the state untouched.
 */
vl_status_t vl_update_apply(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t m);

/** The downdate of P's landmark block the updates left pending (none: cols 0). */
vl_la_pending_t vl_update_pending(const vl_estimator_t *e);

/** Applies the pending downdate (vl_update_apply): P is then current everywhere. */
void vl_update_downdate(vl_estimator_t *e);

#endif /* VISLAM_VL_UPDATE_H */
