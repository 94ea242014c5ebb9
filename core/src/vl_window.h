/**
 * @file vl_window.h
 * @brief The landmark window: slots, pending tracks, admission, eviction,
 *        marginalization and landmark output (internal to core/).
 *
 * During a frame, work_seen[slot] (a vl_seen_t) says what the frame did to each
 * window landmark, and work_broken lists the frame observations whose tracks
 * broke; both are reset at the start of the frame.
 */
#ifndef VISLAM_VL_WINDOW_H
#define VISLAM_VL_WINDOW_H

#include "vislam/vislam.h"

/**
 * Sorts a frame's observations: those of window landmarks become update rows in
 * e->work_rows (with work_slot, work_frame_obs) and mark their slot seen; the
 * others feed the pending tracks and, once old and consistent enough, become
 * admission candidates. frame_dt is the time since the previous frame, s.
 * @return the number of update rows
 */
uint32_t vl_window_classify(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count, double frame_dt,
                            vl_candidates_t *candidates);

/** The window slot of track id, or -1 when it is not in the window. */
int vl_window_find_slot(const vl_estimator_t *e, int32_t id);

/** Tracks that ended (unseen too long) or broke leave the window for the map. */
void vl_window_retire(vl_estimator_t *e);

/**
 * Admits the candidates and the restarts of broken tracks (indices into the
 * frame's observations obs), best first, evicting unobserved landmarks when the
 * window is full; then drops the pending tracks this frame did not continue.
 */
void vl_window_admit(vl_estimator_t *e, const vl_stereo_obs_t *obs, vl_candidates_t *candidates);

/** A window landmark as the API hands it out: world position and 3x3 covariance. */
void vl_window_landmark(const vl_estimator_t *e, uint32_t slot, vl_landmark_t *out);

/** Hands a landmark to the map sink and drops its rows and columns (exact marginal). */
void vl_window_marginalize(vl_estimator_t *e, uint32_t slot);

/**
 * At a repeated image: the process noise of the tracker re-anchoring the tracks the
 * frame carries, one rigid motion of repeat_anchor_noise times the step from the
 * previous frame's pose (frame_R, frame_p) shared by every window landmark the
 * frame observes, added to their blocks of P (the pose and offset blocks and their
 * cross-covariances unchanged). Returns how many landmarks it moved (work:
 * O(carried^2), no allocation).
 */
uint32_t vl_window_repeat_noise(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count);

/** At a repeated image: flags the window landmarks the frame observes as carried over it. */
void vl_window_mark_carried(vl_estimator_t *e, const vl_stereo_frame_t *frame, uint32_t count);

/**
 * Once a frame, for every landmark carried over a repeated image (vl_window_mark_carried)
 * before this frame: process noise of repeat_track_walk pixels in its camera's x, y and
 * disparity at the current pose, on its own 3x3 block of P. Returns how many landmarks
 * it widened (work: O(landmarks), no allocation).
 */
uint32_t vl_window_carried_walk(vl_estimator_t *e);

#endif /* VISLAM_VL_WINDOW_H */
