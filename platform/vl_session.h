/**
 * @file vl_session.h
 * @brief Everything between an input event and the estimator core, for every program.
 *
 * A session takes decoded input events (vl_log_event_t: calibration, IMU
 * sample, stereo frame, or a payload that did not decode) and owns:
 *
 *  - the calibration policy: the configuration file's [calibration] is used
 *    from the start when it has one; a calibration message replaces it unless
 *    override_log, as long as no input reached the core; a different
 *    calibration after inputs is ignored and counted; an equal one is a no-op;
 *  - vl_init, and the re-initializations the core reports (VL_RESET);
 *  - the run counters (VL_SESSION_COUNTERS, named once) and the core's
 *    status counts per call;
 *  - the health bits (vislam.status_t HEALTH_*), from the counters and the
 *    core's state, "since the last mark";
 *  - the core logger, rate limited by count (so what it prints is reproducible);
 *  - the outputs, through callbacks: on_pose after every input the core used,
 *    on_landmark for each landmark leaving the window, on_event for
 *    calibrations taking effect and re-initializations.
 *
 * vislam-run (a log reader in front, TUM/PLY sinks behind) and vislamd (LCM in
 * front, publishers behind) are adapters over the same session, so the same
 * inputs give the same poses offline and through the daemon: the same code runs.
 *
 * Real time: the session is plain data owned by the caller (keep it static);
 * vl_session_input never allocates and never reads a clock. Warnings go to
 * stderr, each kind once (the first occurrence) or through the rate limit.
 */
#ifndef VISLAM_PLATFORM_VL_SESSION_H
#define VISLAM_PLATFORM_VL_SESSION_H

#include <stddef.h>
#include <stdint.h>

#include "vislam/vislam.h"
#include "vl_log_reader.h"
#include "vl_worker.h"

#include "vislam_status_t.h"

#ifdef __cplusplus
extern "C" {
#endif

/**
 * The run counters, X(name, meaning). Every list, JSON key and status field
 * that shows them comes from here.
 */
#define VL_SESSION_COUNTERS(X)                                                                      \
    X(imu_in, "IMU messages received, decoded or not")                                              \
    X(frames_in, "frame messages received, decoded or not")                                         \
    X(calibrations_in, "calibration messages received, decoded or not")                             \
    X(decode_errors, "inputs whose payload did not decode (also counted as received)")              \
    X(imu_waiting, "IMU samples refused: no calibration yet")                                       \
    X(frames_waiting, "frames refused: no calibration yet")                                         \
    X(imu_used, "IMU samples the core used")                                                        \
    X(frames_used, "frames the core used")                                                          \
    X(imu_rejected, "IMU samples the core refused")                                                 \
    X(frames_rejected, "frames the core refused")                                                   \
    X(time_refused, "of the refusals, those for their time (order or jump)")                        \
    X(reinitializations, "re-initializations the core reported (VL_RESET)")                         \
    X(calibrations_used, "calibration messages that (re)initialized the estimator or confirmed it") \
    X(calibrations_ignored, "repeats, or the configuration file overrides the log")                 \
    X(calibrations_changed, "a different calibration after inputs: ignored")                        \
    X(calibrations_invalid, "refused by vl_config_check")                                           \
    X(poses_out, "poses handed to on_pose")                                                         \
    X(poses_withheld, "non-finite poses the core would not hand out: nothing sent")

/** The run counters, one uint64_t per VL_SESSION_COUNTERS entry. */
typedef struct {
#define VL_SESSION_COUNTER_MEMBER(name, meaning) uint64_t name;
    VL_SESSION_COUNTERS(VL_SESSION_COUNTER_MEMBER)
#undef VL_SESSION_COUNTER_MEMBER
} vl_session_counters_t;

/** Number of run counters. */
#define VL_SESSION_NUM_COUNTERS (sizeof(vl_session_counters_t) / sizeof(uint64_t))

/** Slots of a table indexed by vl_status_t (VL_STATUS_MIN..VL_STATUS_MAX). */
#define VL_SESSION_STATUS_SLOTS ((int)VL_STATUS_MAX - (int)VL_STATUS_MIN + 1)

/** Which core call an input led to. */
typedef enum {
    VL_SESSION_STEP_NONE = 0,      /**< none: a calibration, a decode error, or no calibration yet */
    VL_SESSION_STEP_PROPAGATE = 1, /**< vl_propagate ran */
    VL_SESSION_STEP_UPDATE = 2     /**< vl_update ran */
} vl_session_step_t;

/** What on_event reports. */
typedef enum {
    VL_SESSION_EVENT_CALIBRATED = 1,   /**< a calibration message took effect (vl_init ran with it) */
    VL_SESSION_EVENT_REINITIALIZED = 2 /**< the core re-initialized (new timeline or divergence) */
} vl_session_event_t;

/** Output callbacks; any may be NULL. They run inside vl_session_input. */
typedef struct {
    /**
     * After every input the core used (status >= 0) whose pose is finite.
     * @param step     VL_SESSION_STEP_PROPAGATE or VL_SESSION_STEP_UPDATE
     * @param utime    the input's time, us
     * @param sequence poses handed out before this one
     */
    void (*on_pose)(void *user, vl_session_step_t step, int64_t utime, uint64_t sequence, const vl_pose_t *pose);
    /** Each landmark leaving the window (the map). */
    void (*on_landmark)(void *user, const vl_landmark_t *landmark);
    /** A calibration took effect or the core re-initialized, at input time @p utime (us). */
    void (*on_event)(void *user, vl_session_event_t event, int64_t utime);
    void *user; /**< passed to every callback */
} vl_session_callbacks_t;

/** How a session starts. */
typedef struct {
    const char *program;        /**< prefix of the session's stderr lines ("vislamd") */
    int quiet;                  /**< nonzero: core warnings and notes off; core errors and session warnings stay */
    int config_has_calibration; /**< nonzero: the configuration's calibration is the rig's (vl_config_file_info_t) */
    int override_log;           /**< nonzero: calibration messages are ignored (vl_config_file_info_t) */
    vl_session_callbacks_t callbacks;
    vl_worker_t *worker; /**< optional: a started worker that shares the update (vl_worker_start); NULL = serial */
} vl_session_options_t;

/** Core log lines printed per level before the rate limit, then one in VL_SESSION_LOG_EVERY. */
#define VL_SESSION_LOG_BURST 20
/** See VL_SESSION_LOG_BURST. */
#define VL_SESSION_LOG_EVERY 1000

/** Session state: plain data owned by the caller; members are private (read them with the functions below). */
typedef struct {
    vl_estimator_t *est;
    vl_config_t cfg;
    vl_session_options_t opt;
    int initialized;
    int inputs_fed;           /* once inputs reached the core, a new calibration cannot restart it */
    const char *calib_source; /* "none", "config" or "log" */
    vl_session_counters_t n;
    uint64_t propagate_status[VL_SESSION_STATUS_SLOTS];
    uint64_t update_status[VL_SESSION_STATUS_SLOTS];
    int64_t last_input_utime; /* us, the last input the core used */
    vl_pose_t pose;           /* the latest pose handed out */
    /* logger */
    uint64_t log_seen[4];
    uint64_t log_suppressed;
    /* the frames' normalized innovation squared (vl_pose_t::innovation_ratio x rows) and rows, since start */
    double innovation_nis;
    uint64_t innovation_rows;
    /* "since the last mark" for the health bits and the status's innovation ratio */
    vl_session_counters_t n_at_mark;
    vl_counters_t core_at_mark;
    double innovation_nis_at_mark;
    uint64_t innovation_rows_at_mark;
} vl_session_t;

/**
 * Starts a session on @p est (caller-owned, VL_ESTIMATOR_ALIGN-aligned).
 * @p cfg's landmark_sink and log are replaced by the session's, and its
 * parallel_for by opt->worker's when that is set. With
 * opt->config_has_calibration the estimator is initialized at once.
 * @return VL_OK, VL_ERR_NULL, or vl_init's refusal (VL_ERR_CONFIG, VL_ERR_MISALIGNED)
 */
vl_status_t vl_session_init(vl_session_t *s, vl_estimator_t *est, const vl_config_t *cfg,
                            const vl_session_options_t *opt);

/**
 * Hands one event to the session: calibrations go through the policy, IMU
 * samples to vl_propagate, frames to vl_update (both once calibrated), decode
 * errors are counted; VL_LOG_EVENT_CORRUPT and VL_LOG_EVENT_END are ignored.
 * @param status the core's status when a core call ran, else VL_OK (may be NULL)
 * @return which core call ran
 */
vl_session_step_t vl_session_input(vl_session_t *s, const vl_log_event_t *ev, vl_status_t *status);

/**
 * The part of the last input's work that may wait until its pose is out: the
 * landmarks' downdate and the window's upkeep of a frame, and the observations
 * its update deferred under its time bound (vl_update_deferred). Every program
 * calls it after vl_session_input, before the next input, so that the same
 * inputs give the same estimate everywhere; the pose's latency is
 * vl_session_input's alone. A core re-initialization it
 * leads to is counted and reported as vl_session_input's are (on_event).
 * @return VL_OK when there was nothing to do, else vl_update_deferred's status
 */
vl_status_t vl_session_finish(vl_session_t *s);

/** Hands the window's landmarks to on_landmark (end of a run). */
void vl_session_flush(vl_session_t *s);

/**
 * Health bits (vislam.status_t HEALTH_*) now, for what happened since the last
 * vl_session_mark: every bit but HEALTH_BUDGET_OVERRUN, which is the caller's
 * (the session reads no clock).
 */
int32_t vl_session_health(const vl_session_t *s);

/**
 * Fills every field of a status message the session knows: counts, window,
 * noise in use, the core's robustness counters and vl_session_health. The
 * caller adds utime, the budget, steps and latencies (and BUDGET_OVERRUN).
 */
void vl_session_fill_status(const vl_session_t *s, vislam_status_t *out);

/** Starts a new "since the last mark" interval for vl_session_health (after publishing a status). */
void vl_session_mark(vl_session_t *s);

/**
 * The frames' normalized innovation squared per row (vl_pose_t::innovation_ratio, weighted by
 * each frame's rows) since the session started (@p since_mark = 0) or since the last
 * vl_session_mark (1); 0 when no frame updated the state in that interval.
 */
double vl_session_innovation_ratio(const vl_session_t *s, int since_mark);

/** The run counters. */
const vl_session_counters_t *vl_session_counters(const vl_session_t *s);

/** Fills @p out with the run counters by name, in VL_SESSION_COUNTERS order; returns VL_SESSION_NUM_COUNTERS. */
size_t vl_session_counter_list(const vl_session_t *s, vl_counter_entry_t out[VL_SESSION_NUM_COUNTERS]);

/** The core's counters (all zero before the estimator is initialized). */
const vl_counters_t *vl_session_core_counters(const vl_session_t *s);

/** How many times vl_propagate (@p update = 0) or vl_update (1) returned @p status. */
uint64_t vl_session_status_count(const vl_session_t *s, int update, vl_status_t status);

/** Nonzero once the estimator is initialized (a calibration is known). */
int vl_session_initialized(const vl_session_t *s);

/** Where the rig's calibration came from: "none", "config" or "log". */
const char *vl_session_calibration_source(const vl_session_t *s);

/** The configuration in use (the calibration included). */
const vl_config_t *vl_session_config(const vl_session_t *s);

/** The estimator, or NULL before it is initialized (for read-only queries: window, pose). */
const vl_estimator_t *vl_session_estimator(const vl_session_t *s);

/** Time of the last input the core used, us (0 before any). */
int64_t vl_session_last_input_utime(const vl_session_t *s);

/** Core log lines the rate limit suppressed. */
uint64_t vl_session_log_suppressed(const vl_session_t *s);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_SESSION_H */
