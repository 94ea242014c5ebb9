/**
 * @file vl_warm.h
 * @brief A predictive wake: have the CPU busy and the estimator's memory in cache when the next
 *        frame comes, not idle since the last one.
 *
 * At a camera's rate (10 Hz) the estimation thread idles about 100 ms between frames, and the
 * first step after that runs slower than back to back. A program that knows when the next frame
 * is due sleeps until warm_us before it, reads the estimator's memory once (vl_warm_touch) and
 * then polls for the input without sleeping until it comes or warm_us after it was due: the input
 * finds it awake, on a busy CPU, with the data in cache (on the machine measured this did not make
 * the step itself faster; README, Latency). The cost is the spin: up to 2 warm_us of one CPU per
 * frame period. The prediction is the last frame's arrival plus the frame period, the median of
 * the last VL_WARM_INTERVALS intervals of the frames' own times; none until two frames were seen,
 * and no window while the period is under 4 warm_us (the spin would be most of the period).
 * vl_warm_frame_due uses the same period to tell whether an input's time is a frame's.
 *
 * Plain data, no allocation, no clock read: the caller passes its CLOCK_MONOTONIC times.
 */
#ifndef VISLAM_PLATFORM_VL_WARM_H
#define VISLAM_PLATFORM_VL_WARM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define VL_WARM_INTERVALS 16 /**< frame intervals the period is the median of */
#define VL_WARM_MAX_US 50000 /**< the largest warm_us accepted, us */

/** The predictor and what warming cost. */
typedef struct {
    int64_t warm_us;                      /**< how long before a frame is due to start, us; 0 = off */
    int64_t intervals[VL_WARM_INTERVALS]; /**< the last frame intervals, us (a ring) */
    unsigned num_intervals, next_interval;
    int64_t period_us;       /**< median frame interval, us; 0 unknown */
    int64_t last_utime;      /**< the last frame's own time, us */
    int64_t last_arrival_us; /**< when it arrived, CLOCK_MONOTONIC us; 0 none yet */
    int64_t warmed_for;      /**< the caller's: the start of the last window it warmed, us */
    uint64_t windows;        /**< frame periods warmed (the memory touched once in each) */
    uint64_t touch_us;       /**< time reading the estimator's memory, in all, us */
    uint64_t spin_us;        /**< time polling without sleeping, in all, us */
    uint64_t inputs_in_spin; /**< inputs that came while polling (the rest came after the window) */
} vl_warm_t;

/** A predictor warming @p warm_us before each frame (0: off). */
void vl_warm_init(vl_warm_t *w, int64_t warm_us);

/**
 * A frame arrived: its own time (us) and its arrival (CLOCK_MONOTONIC us). A frame whose time
 * does not advance (a restarted sensor, a new log) restarts the period's estimate.
 */
void vl_warm_note_frame(vl_warm_t *w, int64_t utime, int64_t arrival_us);

/**
 * The window around the next frame: warm from *from_us to *until_us (CLOCK_MONOTONIC us). 0 when
 * off or nothing is predicted yet (too few frames, the period under 4 warm_us, or the window
 * already over at @p now_us), else 1.
 */
int vl_warm_window(const vl_warm_t *w, int64_t now_us, int64_t *from_us, int64_t *until_us);

/**
 * 1 when a frame is expected at @p utime (us, the inputs' own time): the period is known and
 * @p utime is no more than an eighth of it before the last frame's time plus the period (an IMU
 * sample of a frame's instant, whose frame is about to come). 0 otherwise.
 */
int vl_warm_frame_due(const vl_warm_t *w, int64_t utime);

/**
 * Reads @p bytes from @p p, one load per 64-byte line, from the last line to the first, so that
 * they are in the cache and the TLB when the step comes, the first bytes the most recently read. Returns a value computed from them (so that the reads are not optimized
 * out).
 */
uint64_t vl_warm_touch(const void *p, size_t bytes);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_WARM_H */
