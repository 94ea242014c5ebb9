/**
 * @file vl_outliers.h
 * @brief Outlier handling: the innovation gate, 1-point RANSAC, re-association
 *        detection and the rescue of rejected rows (internal to core/).
 *
 * Flags live in e->work_inlier, one per row of e->work_rows. A landmark whose
 * observation contradicts it is marked VL_SEEN_BROKEN in work_seen and its
 * frame observation listed in work_broken: it leaves the window for the map
 * and its id starts a new landmark.
 */
#ifndef VISLAM_VL_OUTLIERS_H
#define VISLAM_VL_OUTLIERS_H

#include "vislam/vislam.h"

#include "vl_linalg.h"

/** Fewer tracked observations than this never count as a re-association. */
#define VL_MIN_ROWS_FOR_REASSOCIATION 8u

/** Flags the rows whose prior innovation passes gate_chi2; returns how many fail. */
uint32_t vl_outliers_gate(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k);

/**
 * Is the frame a tracker re-association: more than max_broken_fraction of its
 * k rows (and at least VL_MIN_ROWS_FOR_REASSOCIATION) contradicting the state?
 */
int vl_outliers_reassociated(const vl_estimator_t *e, uint32_t k, uint32_t contradicting);

/** Marks every row's landmark as a broken track (a re-associated frame). */
void vl_outliers_break_all(vl_estimator_t *e, uint32_t k);

/**
 * 1-point RANSAC: replaces the inlier flags (the gate's) with the support of the
 * best of ransac_hypotheses single-observation corrections, when that support
 * holds at least two observations; otherwise the gate's flags stay.
 */
void vl_outliers_ransac(vl_estimator_t *e, const vl_la_obs_t *rows, uint32_t k);

/** Moves the flagged rows to the front; returns how many there are. */
uint32_t vl_outliers_partition(vl_estimator_t *e, vl_la_obs_t *rows, uint32_t k);

/**
 * Re-linearizes the rejected rows (rows[first .. first + count)) at the corrected
 * state, keeps those within gate_chi2 of their posterior innovation covariance
 * and moves them to the front of rows; the others are broken tracks.
 * @return how many were kept
 */
uint32_t vl_outliers_rescue(vl_estimator_t *e, const vl_stereo_frame_t *frame, vl_la_obs_t *rows, uint32_t first,
                            uint32_t count);

#endif /* VISLAM_VL_OUTLIERS_H */
