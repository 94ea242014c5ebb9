/**
 * @file vislam.h
 * @brief vislam core: an allocation-free visual-inertial EKF on SE(3).
 *
 * The estimator tracks the world-from-IMU pose T = (R, p), optional constant
 * offsets of the two velocity inputs, and a bounded window of 3-D landmarks in
 * one joint Gaussian. Landmarks that leave the window are marginalized exactly
 * (their rows and columns are dropped) and handed to the caller's map sink.
 *
 * Memory: the caller owns the vl_estimator_t (about 3.7 MB at the default
 * capacity of 128 landmarks, see the README); nothing in the core allocates,
 * before or after vl_init. The core never touches the OS:
 * every input carries its own time in microseconds, and logging goes through
 * an injected callback, so replaying a log gives bit-identical output.
 *
 * Conventions:
 * - Small matrices in this API are row-major double arrays.
 * - The pose covariance this API reports is over a right (body-frame)
 *   perturbation, T = T_hat * exp(hat(xi)) with xi = [rho (m); phi (rad)],
 *   translation first. (Internally the filter uses invariant world-frame errors.)
 * - Pixels are rectified, u to the right, v down.
 */
#ifndef VISLAM_VISLAM_H
#define VISLAM_VISLAM_H

#include <stddef.h>
#include <stdint.h>

#include "vislam/vl_config_schema.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Compile-time landmark capacity of the joint state (override from CMake). */
#ifndef VL_MAX_LANDMARKS
#define VL_MAX_LANDMARKS 128
#endif

/** Most observations one stereo frame may carry; the excess is truncated and counted. */
#ifndef VL_MAX_FRAME_FEATURES
#define VL_MAX_FRAME_FEATURES 256
#endif

/**
 * Alignment of vl_estimator_t, bytes. Eigen's vectorized loops split their work
 * by the address of the data; a fixed alignment makes every caller's copy of the
 * estimator compute bit-identical results (vl_init refuses other addresses).
 */
#define VL_ESTIMATOR_ALIGN 64
#if defined(__GNUC__) || defined(__clang__)
#define VL_ALIGNED(n) __attribute__((aligned(n)))
#else
#error "vislam needs a compiler with __attribute__((aligned))"
#endif

/** Pose (6), velocity-input offsets (6) and the velocity sensor's position (3) lead the state vector. */
#define VL_CORE_DIM 15
/** The core's parameters: the states after the pose (offsets and sensor position), constant but for the offsets' walk. */
#define VL_PARAM_DIM (VL_CORE_DIM - 6)
/** Largest joint state dimension. */
#define VL_STATE_DIM_MAX (VL_CORE_DIM + 3 * VL_MAX_LANDMARKS)
/** Leading dimension of the joint covariance (vl_estimator_t::P): the largest state dimension
 *  rounded up to a multiple of 4, so the update's products run on whole 4-row packets (README
 *  "Results"). */
#define VL_COV_LD ((VL_STATE_DIM_MAX + 3) / 4 * 4)
/** Rows of a compressed stereo observation: u_left, mean v, u_right. */
#define VL_OBS_DIM 3

/**
 * Status of every core call. Negative values are refusals: the input was not
 * used and the estimator is unchanged apart from its counters, except
 * VL_ERR_NOT_POSITIVE_DEFINITE, where only the joint update was refused (the
 * frame's prediction and window bookkeeping still happened). Positive values
 * are events of a call that succeeded.
 */
typedef enum {
    VL_OK = 0,                         /**< Done. */
    VL_FRAME_TRUNCATED = 1,            /**< Frame had more than VL_MAX_FRAME_FEATURES observations;
                                           the first ones were used, the rest counted. */
    VL_RESET = 2,                      /**< The estimator re-initialized in this call, keeping its
                                           configuration, calibration and counters: identity pose,
                                           empty window. On a new timeline (timeline_changes) the input
                                           is the first IMU sample of the new clock; after divergence
                                           (divergence_resets) the input was used, the divergence found
                                           after it, and the clock and held IMU sample are kept. */
    VL_ERR_NULL = -1,                  /**< A required pointer was NULL. */
    VL_ERR_CONFIG = -2,                /**< A configuration value is out of range (see vl_config_check). */
    VL_ERR_NOT_READY = -3,             /**< A frame arrived before the first IMU sample set the clock. */
    VL_ERR_NON_FINITE = -4,            /**< An input holds NaN or infinity; the sample was rejected. */
    VL_ERR_TIME_ORDER = -5,            /**< Input time is not after the previous input of its kind,
                                           or earlier than the state; the sample was rejected. */
    VL_ERR_NOT_POSITIVE_DEFINITE = -6, /**< The innovation covariance failed its Cholesky factorization;
                                           the update was not applied. */
    VL_ERR_CAPACITY = -7,              /**< Output buffer too small (vl_get_landmarks). */
    VL_ERR_MISALIGNED = -8,            /**< The estimator is not VL_ESTIMATOR_ALIGN-byte aligned (heap
                                           copies need aligned_alloc; static ones are aligned). */
    VL_ERR_TIME_JUMP = -9,             /**< Input time more than max_time_jump away from the estimator's
                                           clock, ahead or behind; refused, the clock did not move. */
    VL_ERR_IMPLAUSIBLE = -10,          /**< IMU sample beyond max_speed or max_rotation_rate; refused. */
    VL_ERR_IMU_SILENT = -11,           /**< Frame more than max_imu_silence after the last IMU sample
                                           in a mode other than slam (where the frames carry the pose):
                                           refused; the estimator is degraded until the IMU returns. */
    VL_ERR_ABI_MISMATCH = -12          /**< vl_init: the caller was compiled with other capacities
                                           (VL_MAX_LANDMARKS, VL_MAX_FRAME_FEATURES) or another
                                           vislam.h than the library; the estimator was not touched. */
} vl_status_t;

/** Lowest and highest vl_status_t values, for tables indexed by status. */
#define VL_STATUS_MIN VL_ERR_ABI_MISMATCH
#define VL_STATUS_MAX VL_RESET

/** What the estimator does with its inputs (the seed project's three parts). */
typedef enum {
    VL_MODE_IMU_ONLY = 0, /**< (a) Dead reckoning: prediction only. */
    VL_MODE_MAPPING = 1,  /**< (b) Landmarks are estimated; the pose follows the prediction only. */
    VL_MODE_SLAM = 2      /**< (c) Joint pose + landmark update. */
} vl_mode_t;

/** Stereo rig calibration. */
typedef struct {
    double fx;            /**< px */
    double fy;            /**< px */
    double cx;            /**< px */
    double cy;            /**< px */
    double baseline;      /**< m, positive */
    double cam_T_imu[16]; /**< 4x4 row-major, IMU frame to left camera optical frame */
} vl_calibration_t;

/** A landmark as handed to the map or read from the window. */
typedef struct {
    int32_t id;            /**< track id from the frames */
    double position[3];    /**< world frame, m */
    double covariance[9];  /**< 3x3 row-major, m^2 */
    uint32_t observations; /**< frames that observed it, initialization included */
    int64_t first_utime;   /**< us */
    int64_t last_utime;    /**< us */
} vl_landmark_t;

/** Receives each landmark leaving the window. Called from vl_update and vl_flush_landmarks, and from
 * vl_propagate, vl_update or vl_reset when a new timeline or a reset ends the landmarks' world. */
typedef void (*vl_landmark_sink_fn)(void *user, const vl_landmark_t *landmark);

/** Log severities for the injected logger. */
typedef enum { VL_LOG_DEBUG = 0, VL_LOG_INFO = 1, VL_LOG_WARN = 2, VL_LOG_ERROR = 3 } vl_log_level_t;

/** Injected logger; the core formats nothing itself beyond a short fixed message. */
typedef void (*vl_log_fn)(void *user, vl_log_level_t level, int64_t utime, const char *message);

/** One task of a parallel loop: the work of index @p index (0..count-1) of vl_parallel_for_fn. */
typedef void (*vl_parallel_task_fn)(void *arg, uint32_t index);

/**
 * Injected parallel loop: runs task(arg, i) once for every i in 0..count-1, on
 * any threads in any order, and returns when all have finished. The core cuts
 * its work into a fixed partition of disjoint blocks, the same whatever runs
 * them, so the results are bit-identical to the serial loop's. Only loops
 * with 8 Mflop or more in those blocks use it (the costly ones). A call with
 * count 0 runs nothing: it announces loops soon (the update calls it first, so
 * that a sleeping worker wakes while the serial part runs). Called from
 * vl_update and vl_update_deferred only; it must not allocate if the caller's
 * step must not.
 */
typedef void (*vl_parallel_for_fn)(void *ctx, vl_parallel_task_fn task, void *arg, uint32_t count);

/** Largest max_time_jump and max_imu_silence, s (their microseconds stay far inside int64). */
#define VL_MAX_TIME_LIMIT 1e9

/**
 * Estimator configuration. Start from vl_config_default() or vl_config_preset_seed().
 *
 * The plain values come first: one member per row of VL_CONFIG_KEYS in
 * vislam/vl_config_schema.h, in the table's order, named by its field column.
 * The table gives each one's type, default, range, units and meaning.
 */
typedef struct {
/** @cond */
#define VL_CONFIG_MEMBER_(section, key, field, type, def, min, max, min_open, units, meaning) \
    VL_CONFIG_CTYPE_##type field;
    VL_CONFIG_KEYS(VL_CONFIG_MEMBER_)
#undef VL_CONFIG_MEMBER_
    /** @endcond */

    vl_calibration_t calibration; /**< stereo rig */

    vl_landmark_sink_fn landmark_sink; /**< optional: receives marginalized landmarks */
    void *landmark_sink_user;          /**< passed to landmark_sink */
    vl_log_fn log;                     /**< optional logger */
    void *log_user;                    /**< passed to log */
    vl_parallel_for_fn parallel_for;   /**< optional: runs the update's blocks on more threads; NULL = serial */
    void *parallel_ctx;                /**< passed to parallel_for */
} vl_config_t;

/** One IMU velocity sample. */
typedef struct {
    int64_t utime;              /**< us */
    double linear_velocity[3];  /**< body frame, m/s */
    double angular_velocity[3]; /**< body frame, rad/s */
} vl_imu_sample_t;

/** One stereo observation of a tracked keypoint. */
typedef struct {
    int32_t id;     /**< track id, unique per track */
    double u_left;  /**< px */
    double v_left;  /**< px */
    double u_right; /**< px */
    double v_right; /**< px */
} vl_stereo_obs_t;

/** One camera frame of stereo observations. */
typedef struct {
    int64_t utime;                              /**< us */
    uint32_t count;                             /**< observations given (may exceed capacity) */
    vl_stereo_obs_t obs[VL_MAX_FRAME_FEATURES]; /**< the first min(count, capacity) are read */
} vl_stereo_frame_t;

/** Pose estimate. */
typedef struct {
    int64_t utime;              /**< us, time of the state */
    double rotation[9];         /**< world-from-IMU rotation, row-major */
    double position[3];         /**< IMU origin in the world, m */
    double covariance[36];      /**< 6x6 row-major over [rho (m), phi (rad)] */
    double linear_velocity[3];  /**< last offset-corrected body velocity (at the body origin: velocity_sensor_*), m/s */
    double angular_velocity[3]; /**< last offset-corrected body angular velocity, rad/s */
    double linear_offset[3];    /**< estimated linear velocity offset, m/s */
    double angular_offset[3];   /**< estimated angular velocity offset, rad/s */
    double velocity_sensor[3];  /**< estimated position of the linear velocity sensor in the body frame, m */
    double linear_velocity_noise;  /**< m/s, per-sample noise std in use (adapted with adaptive_noise) */
    double angular_velocity_noise; /**< rad/s, likewise */
    double pixel_noise;            /**< px, likewise */
    /** Normalized innovation squared per row of the last frame's update(s): r^T S^-1 r over their
     * rows, on the observations the update used (after the gate and RANSAC). About 1 when the
     * noise model fits them, over 1 when the filter is overconfident (noise set too small), under
     * 1 when it is over-conservative (noise set too large); 0 when that frame made no update. */
    double innovation_ratio;
    uint32_t innovation_rows; /**< rows of those updates (3 per observation); 0 when none */
} vl_pose_t;

/**
 * Every counter, in declaration order: X(type, name, meaning). vl_counters_t's
 * members, VL_NUM_COUNTERS and vl_counters_list() all come from this list, so a
 * new counter is one line here. All counters are monotonic since vl_init; the
 * type is uint64_t or uint32_t (vl_counter_entry_t carries any of them).
 */
#define VL_COUNTERS(X)                                                                                              \
    X(uint64_t, imu_accepted, "IMU samples used")                                                                   \
    X(uint64_t, imu_rejected, "IMU samples refused (non-finite, time order, time jump, implausible)")               \
    X(uint64_t, frames_accepted, "frames used")                                                                     \
    X(uint64_t, frames_rejected, "frames refused (time order, time jump, not ready, IMU silent outside slam mode)") \
    X(uint64_t, frames_truncated, "frames over VL_MAX_FRAME_FEATURES")                                              \
    X(uint64_t, observations_received, "observations in accepted frames, before truncation")                        \
    X(uint64_t, observations_truncated, "observations dropped by truncation")                                       \
    X(uint64_t, observations_invalid, "non-finite pixels, duplicate ids, negative ids")                             \
    X(uint64_t, observations_low_disparity, "refused for disparity below min_disparity or depth above max_depth")   \
    X(uint64_t, observations_used, "applied in an update")                                                          \
    X(uint64_t, observations_gated, "refused as outliers (RANSAC or gate, and not rescued)")                        \
    X(uint64_t, observations_rescued, "outliers of the first pass accepted after the correction")                   \
    X(uint64_t, observations_deferred, "inliers left out by max_update_observations or max_update_work")            \
    X(uint64_t, observations_deferred_used, "of those, applied after the frame's pose (vl_update_deferred)")        \
    X(uint64_t, observations_deferred_dropped,                                                                      \
      "of those, not applied: past max_deferred_work, landmark gone, refused, or the next input or a reset first")  \
    X(uint64_t, observations_behind_camera, "predicted behind the camera: not used")                                \
    X(uint64_t, landmarks_initialized, "admitted to the window")                                                    \
    X(uint64_t, landmarks_deferred, "admissions postponed: the window was full, or max_admissions reached")         \
    X(uint64_t, tracks_inconsistent,                                                                                \
      "observations that disagreed with their track's previous one (candidates; on sparse frames, window tracks "   \
      "against the motion the others agree on or drifting against the velocities', and first-sight landmarks at "   \
      "their second sight)")                                                                                        \
    X(uint64_t, frames_reassociated, "frames whose tracked observations were all distrusted")                       \
    X(uint64_t, frames_repeated, "frames repeating the previous frame's pixels exactly (a stale image)")            \
    X(uint64_t, tracks_broken, "window landmarks whose observation contradicted them: mapped, id restarted")        \
    X(uint64_t, landmarks_marginalized, "left the window and handed to the sink")                                   \
    X(uint64_t, landmarks_evicted, "of those, removed early to make room")                                          \
    X(uint64_t, numerical_failures, "updates refused with VL_ERR_NOT_POSITIVE_DEFINITE")                            \
    X(uint64_t, time_gaps, "propagations longer than max_propagation_dt")                                           \
    X(uint64_t, time_jumps, "inputs refused as more than max_time_jump from the clock")                             \
    X(uint64_t, timeline_changes, "re-initializations on a new timeline")                                           \
    X(uint64_t, divergence_resets, "re-initializations after divergence")                                           \
    X(uint64_t, resets, "every re-initialization (those two and vl_reset)")                                         \
    X(uint64_t, landmarks_discarded, "window landmarks dropped by a divergence reset (not handed to the sink)")     \
    X(uint64_t, imu_implausible, "IMU samples beyond max_speed or max_rotation_rate")                               \
    X(uint64_t, observations_implausible, "pixels outside the image (with margin) or disparity over max_disparity") \
    X(uint64_t, imu_silences, "times the IMU fell silent for longer than max_imu_silence")                          \
    X(uint64_t, frames_imu_silent,                                                                                  \
      "frames past max_imu_silence: carried on vision alone in slam mode, refused in the others")                   \
    X(uint32_t, window_peak, "most landmarks ever in the window")

/** Running counters; all monotonic since vl_init. One member per VL_COUNTERS row (meaning there). */
typedef struct {
#define VL_COUNTER_MEMBER_(type, name, meaning) type name;
    VL_COUNTERS(VL_COUNTER_MEMBER_)
#undef VL_COUNTER_MEMBER_
} vl_counters_t;

/** One named counter, for printing and publishing every counter without listing them again. */
typedef struct {
    const char *name;    /**< the vl_counters_t member's name */
    uint64_t value;      /**< its value */
    const char *meaning; /**< what it counts (the VL_COUNTERS row's text) */
} vl_counter_entry_t;

/** @cond */
#define VL_COUNTER_ONE_(type, name, meaning) +1
/** @endcond */
/** Number of members of vl_counters_t (rows of VL_COUNTERS). */
#define VL_NUM_COUNTERS (0 VL_COUNTERS(VL_COUNTER_ONE_))

/**
 * The arithmetic one vl_propagate or vl_update call did, counted by the core from
 * the dimensions it used (not measured): a machine-independent cost of the step.
 * Units are floating-point operations (a multiply-add is 2); copying an element of
 * the covariance (marginalization) counts 1. Leading terms follow the algorithm
 * (the joint update with n states and m rows: n^2 m + n m^2 + m^3 / 3 + ...); the
 * small fixed-size parts are rounded estimates. A refused call did no work: zero.
 */
typedef struct {
    uint64_t flops;      /**< all stages below, flops */
    uint64_t predict;    /**< prediction to the input's time (the core block), and in a frame the deferred
                              prediction applied to the rest of P (one structured rank-6 pass), flops */
    uint64_t gate;       /**< innovation gate of the tracked observations, flops */
    uint64_t ransac;     /**< 1-point RANSAC: hypotheses x (one-row correction + residuals), flops */
    uint64_t update;     /**< the joint update on the inliers (a step's without the landmark block's
                              downdate, which vl_update_deferred's counts) and the noise adaptation, flops */
    uint64_t rescue;     /**< re-checking the rejected rows and the joint update of the rescued ones, flops */
    uint64_t window;     /**< update rows (a step's), marginalizations and admissions (vl_update_deferred's), flops */
    uint32_t state_dim;  /**< joint state dimension n at the update (or prediction), states */
    uint32_t rows;       /**< rows m of the joint updates (3 per observation used), rows */
    uint32_t hypotheses; /**< RANSAC hypotheses tried */
} vl_work_t;

/** Per-landmark bookkeeping of the window (internal; read with vl_get_landmarks). */
typedef struct {
    int32_t id;
    uint32_t observations;
    uint32_t unseen_frames;
    uint32_t updates;           /**< its observations the updates used */
    uint32_t carried;           /**< 1: its track went through a repeated image (repeat_track_walk) */
    uint64_t last_update_frame; /**< frame index of the last update that used it, else of its admission */
    int64_t first_utime;
    int64_t last_utime;
} vl_landmark_slot_t;

/** Tracks of a sparse frame whose two-view drift is summed (vl_noise_two_view.c: its sparse frames
 *  have fewer observations than this). */
#define VL_DRIFT_TRACKS 16u

/** One track's two-view residuals summed over the sparse frames in a row that matched it (internal). */
typedef struct {
    double residual[3];   /**< px, sum of y - h(the velocities' motion since the previous frame), each row clipped */
    double covariance[9]; /**< px^2, sum of their expected covariances */
    uint32_t frames;      /**< frames in the sums */
    uint8_t moving;       /**< 1: the sums showed the track moving on its own: neither used nor admitted */
} vl_track_drift_t;

/** A candidate track not yet in the window: its age orders admissions. */
typedef struct {
    int32_t id;
    uint32_t frames_seen;
    uint64_t last_frame;
    double point[3];      /**< world point triangulated at its last observation, m */
    double covariance[9]; /**< its covariance from pixel noise alone, m^2 */
} vl_pending_track_t;

/** A frame observation that may become a window landmark, and its rank. */
typedef struct {
    uint32_t obs; /**< index in the frame */
    double score; /**< higher is admitted first */
} vl_candidate_t;

/** A frame's admission candidates. */
typedef struct {
    vl_candidate_t item[VL_MAX_FRAME_FEATURES];
    uint32_t count;
} vl_candidates_t;

/** One observation's rows of the joint update (internal workspace). */
typedef struct {
    double H_pose[18];    /**< 3x6 row-major, d y / d xi */
    double H_landmark[9]; /**< 3x3 row-major, d y / d landmark state */
    double residual[3];   /**< measured minus predicted, px */
    double noise_var[3];  /**< observation noise diagonal, px^2 */
    int landmark_col;     /**< first state index of the landmark */
} vl_obs_row_t;

/**
 * The prediction's effect on P not yet applied beyond the core block (vl_predict.c).
 * Between updates the landmarks do not move and every step's input Jacobian is
 * G = B Gp with B fixed, so K steps act on P as P <- (I + U Y E^T) P (...)^T + U A U^T
 * with U = [B, E] (E selecting the parameters): Y and A are the steps' transition and
 * noise in core coordinates, and the core block itself is kept current.
 */
typedef struct {
    uint32_t steps;                                /**< prediction steps accumulated since P was last settled */
    double core0[VL_CORE_DIM * VL_CORE_DIM];       /**< P's core block before the first of them, column-major */
    double transition[VL_CORE_DIM * VL_PARAM_DIM]; /**< Y: parameter columns of the steps' core transition less I */
    double noise[VL_CORE_DIM * VL_CORE_DIM];       /**< A: their noise, carried to the last step */
} vl_deferred_prediction_t;

/** Capacity of the pending-track table. */
#define VL_MAX_PENDING (2 * VL_MAX_FRAME_FEATURES)

/**
 * The estimator. Caller-owned; treat every member as private and use the
 * functions below. Size: sizeof(vl_estimator_t), dominated by the covariance
 * and two update workspaces of VL_STATE_DIM_MAX^2 doubles each.
 */
typedef struct {
    vl_config_t cfg;
    vl_counters_t counters;
    vl_work_t work; /**< the last vl_propagate or vl_update's work (vl_get_work) */

    int initialized;
    int have_imu;
    int64_t state_utime;      /**< us */
    int64_t last_imu_utime;   /**< us */
    int64_t last_frame_utime; /**< us */
    uint64_t frame_index;
    int have_frame;      /**< a frame was accepted on this timeline */
    int64_t clock_utime; /**< us, latest input time that passed the time policy */
    int imu_silent;      /**< the IMU has been silent longer than max_imu_silence */
    int unknown_motion;  /**< motion past max_imu_silence widened P since the last frame (vl_predict_silence_to) */
    double unknown_motion_var[2]; /**< its velocity variance per axis: linear (m/s)^2, angular (rad/s)^2 */
    uint32_t failed_frame_run;    /**< consecutive frames whose update failed (divergence guard) */
    /** A candidate new timeline: consecutive time-refused inputs that follow one another. */
    uint32_t timeline_count;
    int64_t timeline_last_utime;       /**< us, latest input of the candidate */
    int64_t timeline_last_imu_utime;   /**< us, latest IMU sample of the candidate */
    int64_t timeline_last_frame_utime; /**< us, latest frame of the candidate */
    int timeline_have_imu, timeline_have_frame;

    double R[9];               /**< world-from-IMU rotation, row-major */
    double p[3];               /**< m */
    double held_linear[3];     /**< raw last linear velocity sample, m/s */
    double held_angular[3];    /**< raw last angular velocity sample, rad/s */
    int held_trusted;          /**< the held sample may carry the motion on (not after a divergence it led to) */
    double offset_linear[3];   /**< m/s */
    double offset_angular[3];  /**< rad/s */
    double sensor_position[3]; /**< m, the linear velocity sensor in the body frame (velocity_sensor_*) */

    uint32_t num_landmarks;
    vl_landmark_slot_t slots[VL_MAX_LANDMARKS];
    double landmark_state[3 * VL_MAX_LANDMARKS];

    uint32_t num_pending;
    vl_pending_track_t pending[VL_MAX_PENDING];

    /** Noise levels in use: the configured values, adapted online when adaptive_noise is set. */
    double linear_velocity_var;  /**< (m/s)^2 per sample */
    double angular_velocity_var; /**< (rad/s)^2 per sample */
    double pixel_var;            /**< px^2 */
    double pixel_log_ratio;      /**< fast average of log(sample / pixel_var) over dense frames (vl_noise.c) */
    double innovation_nis;       /**< r^T S^-1 r summed over the last frame's updates (vl_update.c) */
    uint32_t innovation_rows;    /**< rows of those updates */
    uint32_t reassociated_run;   /**< consecutive frames distrusted as re-associations */
    /** (rad/s)^2: the angular variance the angular offsets' covariance was last reopened for (vl_noise.c) */
    double angular_velocity_var_reopened;

    /** The sparse frames' two-view velocity noise matching (vl_noise_two_view.c). */
    double stereo_row_var;      /**< px^2 per coordinate: white pixel noise from v_left - v_right, 0 until seen */
    double stereo_row_evidence; /**< observations stereo_row_var averages over */
    double step_noise_time2;    /**< s^2: sum of tau^2 x noise share over the prediction steps since the last frame */
    double step_time;           /**< s: sum of tau over the same steps */
    double step_turn[3];        /**< rad: sum of tau x the corrected angular velocity over the same steps */
    int prev_frame_repeated;    /**< the previous accepted frame repeated the one before it */
    int velocity_matched;       /**< this frame's velocity noise was matched on its two views */
    /** The two-view frames' moment estimate of each velocity variance (linear, angular), as sums
     * that forget over VL_TWO_VIEW_MOMENT_MEMORY frames: the estimate is num / den (vl_noise_two_view.c). */
    double velocity_moment_num[2];    /**< sum of w a (seen - c), w = 1 / (2 tr M^2), a = 3 sum tau^2 */
    double velocity_moment_den[2];    /**< sum of w a^2 */
    double velocity_moment_frames[2]; /**< frames the sums hold (forgetting included) */

    /** The pose after the previous accepted frame: the step to a repeated image (repeat_anchor_noise). */
    double frame_R[9]; /**< world-from-IMU rotation, row-major */
    double frame_p[3]; /**< m */
    /** The body-frame velocity between the last two accepted frames' poses (slam mode): what carries
     * the pose across an IMU silence (vl_predict_silence_to). */
    double frame_velocity[6]; /**< linear m/s, angular rad/s */
    int have_frame_velocity;  /**< frame_velocity holds: two frames in a row, in slam mode */

    /** The state after the last input that passed the divergence check: where a divergence re-initializes. */
    double sound_R[9];                         /**< world-from-IMU rotation, row-major */
    double sound_p[3];                         /**< m */
    double sound_param[VL_PARAM_DIM];          /**< the parameters: linear offset m/s, angular rad/s, sensor m */
    double sound_P[VL_CORE_DIM * VL_CORE_DIM]; /**< the core block of P (pose and parameters), column-major */

    /** The previous accepted frame's observations, to recognize a repeated (stale) image. */
    uint32_t num_prev_obs;
    vl_stereo_obs_t prev_obs[VL_MAX_FRAME_FEATURES];
    /** prev_obs whose track alone contradicted the expected motion on its two views (a sparse frame's
        minority; vl_noise_two_view.c): a second contradiction in a row breaks the track. */
    uint8_t prev_contradicted[VL_MAX_FRAME_FEATURES];
    /** prev_obs's tracks' drift sums, when that frame was sparse (num_prev_drift of them, else none). */
    uint32_t num_prev_drift;
    vl_track_drift_t prev_drift[VL_DRIFT_TRACKS];

    /** Prediction steps applied to P's core block only (vl_predict_settle applies them to the rest). */
    vl_deferred_prediction_t deferred;

    /** Joint covariance, column-major with leading dimension VL_COV_LD. */
    double P[VL_COV_LD * VL_COV_LD] VL_ALIGNED(VL_ESTIMATOR_ALIGN);

    /** Update workspaces (P H^T, then the whitened gain; innovation covariance). */
    double work_PHt[VL_COV_LD * VL_OBS_DIM * VL_MAX_LANDMARKS];
    double work_S[(VL_OBS_DIM * VL_MAX_LANDMARKS) * (VL_OBS_DIM * VL_MAX_LANDMARKS)];
    vl_obs_row_t work_rows[VL_MAX_LANDMARKS];
    double work_r[VL_OBS_DIM * VL_MAX_LANDMARKS];
    double work_R[VL_OBS_DIM * VL_MAX_LANDMARKS];
    double work_dx[VL_COV_LD];
    uint32_t work_slot[VL_MAX_LANDMARKS];
    uint32_t work_frame_obs[VL_MAX_LANDMARKS];
    uint8_t work_seen[VL_MAX_LANDMARKS];
    uint8_t work_inlier[VL_MAX_LANDMARKS];
    uint8_t work_support[VL_MAX_LANDMARKS];
    uint32_t work_broken[VL_MAX_LANDMARKS];
    uint32_t num_broken;
    uint8_t work_moved[VL_MAX_FRAME_FEATURES]; /**< the frame's observations whose track contradicted the
                                                    motion its fellows agree on, or drifted against the
                                                    velocities' (two-view matching) */
    uint32_t num_work_drift;                   /**< the frame's observations when it is sparse, else 0 */
    /** The last vl_update's work after its pose, which vl_update_deferred (or else the next input)
     * does: the downdate of P's landmark block by work_PHt's first pending_cols columns
     * (vl_la_pending_t), then the window's upkeep with the frame's candidates (indices into prev_obs). */
    int frame_open;
    uint32_t pending_cols;
    vl_candidates_t work_candidates;
    /** The last frame's inliers its update deferred under the time bound, as indices into prev_obs:
     * vl_update_deferred applies them; the next input drops them. */
    uint32_t num_held;
    uint32_t held_obs[VL_MAX_LANDMARKS];
    vl_track_drift_t work_drift[VL_DRIFT_TRACKS]; /**< a sparse frame's tracks' drift sums */
} vl_estimator_t;

/** Fills the tuned default configuration (measured best on 0027; see README). */
void vl_config_default(vl_config_t *cfg);

/**
 * Fills the seed project's noise preset: W = diag(1e-5 I3, 1e-4 I3) per 0.1 s step
 * and V = 3500 I4, no offset states, Euclidean landmarks.
 */
void vl_config_preset_seed(vl_config_t *cfg);

/** Checks every configuration value; VL_OK or VL_ERR_CONFIG. */
vl_status_t vl_config_check(const vl_config_t *cfg);

/**
 * The members of the API's types that a caller fills or reads, in declaration
 * order, as X(type, member): all but the configuration's table rows and the
 * counters, which come from VL_CONFIG_KEYS and VL_COUNTERS. vl_abi_layout()
 * hashes them; tests/python/test_abi_layout.py checks that this list names
 * every member of those types.
 */
#define VL_ABI_MEMBERS(X)                \
    X(vl_calibration_t, fx)              \
    X(vl_calibration_t, fy)              \
    X(vl_calibration_t, cx)              \
    X(vl_calibration_t, cy)              \
    X(vl_calibration_t, baseline)        \
    X(vl_calibration_t, cam_T_imu)       \
    X(vl_landmark_t, id)                 \
    X(vl_landmark_t, position)           \
    X(vl_landmark_t, covariance)         \
    X(vl_landmark_t, observations)       \
    X(vl_landmark_t, first_utime)        \
    X(vl_landmark_t, last_utime)         \
    X(vl_config_t, calibration)          \
    X(vl_config_t, landmark_sink)        \
    X(vl_config_t, landmark_sink_user)   \
    X(vl_config_t, log)                  \
    X(vl_config_t, log_user)             \
    X(vl_config_t, parallel_for)         \
    X(vl_config_t, parallel_ctx)         \
    X(vl_imu_sample_t, utime)            \
    X(vl_imu_sample_t, linear_velocity)  \
    X(vl_imu_sample_t, angular_velocity) \
    X(vl_stereo_obs_t, id)               \
    X(vl_stereo_obs_t, u_left)           \
    X(vl_stereo_obs_t, v_left)           \
    X(vl_stereo_obs_t, u_right)          \
    X(vl_stereo_obs_t, v_right)          \
    X(vl_stereo_frame_t, utime)          \
    X(vl_stereo_frame_t, count)          \
    X(vl_stereo_frame_t, obs)            \
    X(vl_pose_t, utime)                  \
    X(vl_pose_t, rotation)               \
    X(vl_pose_t, position)               \
    X(vl_pose_t, covariance)             \
    X(vl_pose_t, linear_velocity)        \
    X(vl_pose_t, angular_velocity)       \
    X(vl_pose_t, linear_offset)          \
    X(vl_pose_t, angular_offset)         \
    X(vl_pose_t, velocity_sensor)        \
    X(vl_pose_t, linear_velocity_noise)  \
    X(vl_pose_t, angular_velocity_noise) \
    X(vl_pose_t, pixel_noise)            \
    X(vl_pose_t, innovation_ratio)       \
    X(vl_pose_t, innovation_rows)        \
    X(vl_counter_entry_t, name)          \
    X(vl_counter_entry_t, value)         \
    X(vl_counter_entry_t, meaning)       \
    X(vl_work_t, flops)                  \
    X(vl_work_t, predict)                \
    X(vl_work_t, gate)                   \
    X(vl_work_t, ransac)                 \
    X(vl_work_t, update)                 \
    X(vl_work_t, rescue)                 \
    X(vl_work_t, window)                 \
    X(vl_work_t, state_dim)              \
    X(vl_work_t, rows)                   \
    X(vl_work_t, hypotheses)

/** @cond */
/* FNV-1a over one member: its name, then the bytes of its offset and size. Never inlined: unrolled
   over ~100 constant names, the loop took a compiler with coverage instrumentation minutes per file. */
static __attribute__((unused, noinline)) uint32_t vl_abi_mix_(uint32_t h, const char *name, size_t offset, size_t size)
{
    for (; *name != '\0'; ++name) {
        h = (h ^ (uint8_t)*name) * 16777619u;
    }
    for (unsigned shift = 0; shift < 32u; shift += 8u) {
        h = (h ^ (uint8_t)(offset >> shift)) * 16777619u;
        h = (h ^ (uint8_t)(size >> shift)) * 16777619u;
    }
    return h;
}
#define VL_ABI_MEMBER_(type, member) \
    h = vl_abi_mix_(h, #type "." #member, offsetof(type, member), sizeof(((type *)0)->member));
#define VL_ABI_CONFIG_(section, key, field, type, def, min, max, min_open, units, meaning) \
    h = vl_abi_mix_(h, "vl_config_t." #field " " #type, offsetof(vl_config_t, field),      \
                    sizeof(((vl_config_t *)0)->field));
#define VL_ABI_COUNTER_(type, name, meaning)                                            \
    h = vl_abi_mix_(h, "vl_counters_t." #name " " #type, offsetof(vl_counters_t, name), \
                    sizeof(((vl_counters_t *)0)->name));
/** @endcond */

/**
 * The API's layout as this translation unit's vislam.h declares it: a hash of
 * the name, offset and size of every member of the types a caller fills or
 * reads (the configuration's table rows with their value types, its other
 * members, the inputs, pose, landmarks, counters and work counts), and of the
 * status codes' and modes' values. vl_init passes the caller's; the library
 * compares it with its own, so another vislam.h is refused even where every
 * size agrees (two keys swapped, a member renamed or retyped at the same size).
 */
static inline uint32_t vl_abi_layout(void)
{
    uint32_t h = 2166136261u;
    VL_CONFIG_KEYS(VL_ABI_CONFIG_)
    VL_COUNTERS(VL_ABI_COUNTER_)
    VL_ABI_MEMBERS(VL_ABI_MEMBER_)
    h = vl_abi_mix_(h, "vl_status_t", (size_t)(VL_STATUS_MAX - VL_STATUS_MIN), (size_t)(0 - VL_STATUS_MIN));
    h = vl_abi_mix_(h, "vl_mode_t", (size_t)VL_MODE_MAPPING, (size_t)VL_MODE_SLAM);
    return h;
}

/**
 * Initializes the estimator: identity pose, empty window. The config is copied.
 *
 * A macro over vl_init_checked: it passes the sizes, capacities and layout the
 * caller was compiled with, so a caller built with another VL_MAX_LANDMARKS (or
 * another vislam.h) than the library gets VL_ERR_ABI_MISMATCH instead of a
 * library writing past the end of a smaller estimator or reading a
 * configuration laid out otherwise.
 * @return VL_OK, VL_ERR_NULL, VL_ERR_ABI_MISMATCH, VL_ERR_MISALIGNED or VL_ERR_CONFIG
 */
#define vl_init(e, cfg)                                                                                 \
    vl_init_checked((e), (cfg), sizeof(vl_estimator_t), sizeof(vl_config_t), sizeof(vl_stereo_frame_t), \
                    VL_MAX_LANDMARKS, vl_abi_layout())

/**
 * vl_init with the caller's view of the types: refuses with VL_ERR_ABI_MISMATCH,
 * before touching e, unless every argument equals the library's own value.
 * @param estimator_size sizeof(vl_estimator_t), bytes
 * @param config_size    sizeof(vl_config_t), bytes
 * @param frame_size     sizeof(vl_stereo_frame_t), bytes (it carries VL_MAX_FRAME_FEATURES)
 * @param max_landmarks  VL_MAX_LANDMARKS
 * @param layout         vl_abi_layout()
 */
vl_status_t vl_init_checked(vl_estimator_t *e, const vl_config_t *cfg, size_t estimator_size, size_t config_size,
                            size_t frame_size, uint32_t max_landmarks, uint32_t layout);

/**
 * Propagates the state to imu->utime with the previously held velocities,
 * then holds this sample's velocities. The first sample sets the clock only.
 */
vl_status_t vl_propagate(vl_estimator_t *e, const vl_imu_sample_t *imu);

/**
 * Applies one stereo frame: propagates to frame->utime if it is later than the
 * state and updates with the observed window landmarks (mode SLAM or MAPPING).
 * On return the pose and its covariance are final; what does not move them, the
 * downdate of the landmarks' covariance block, the marginalization of landmarks
 * whose tracks ended and the admission of new ones, is left to vl_update_deferred
 * (or to the next vl_propagate, vl_update, vl_reset or vl_flush_landmarks, which do
 * it first). vl_get_pose and vl_get_landmarks read the state correctly meanwhile.
 */
vl_status_t vl_update(vl_estimator_t *e, const vl_stereo_frame_t *frame);

/**
 * Completes the last vl_update after its pose: the landmark block's downdate and
 * the window's upkeep (vl_update), then the inliers that vl_update left out under its
 * time bound (max_update_work, max_update_observations), re-linearized at the
 * corrected state and checked against the gate again, within max_deferred_work
 * (apply_deferred on). Call it after the frame's pose is out and before the next
 * input: the frame's latency is then vl_update's alone, and what the bound left
 * out still reaches the state. The next vl_propagate, vl_update or vl_reset does the
 * frame's downdate and upkeep itself and drops the held inliers (counted in
 * observations_deferred_dropped, as are those past max_deferred_work). Its work is
 * read with vl_get_work like a step's (stages update and window); with nothing to do
 * (vl_deferred_due 0) it returns at once and leaves vl_get_work as the last step left it.
 * @return VL_OK (also with nothing to apply), VL_ERR_NULL, VL_ERR_NOT_POSITIVE_DEFINITE
 *         (counted in numerical_failures, as vl_update's), or VL_RESET after a divergence.
 */
vl_status_t vl_update_deferred(vl_estimator_t *e);

/** Observations vl_update_deferred would check now: 0 when there are none (and for NULL). */
uint32_t vl_deferred_pending(const vl_estimator_t *e);

/** Nonzero when vl_update_deferred has work to do: after every vl_update that reached its
 * update (mode SLAM or MAPPING), until that work is done (0 for NULL). */
int vl_deferred_due(const vl_estimator_t *e);

/**
 * Reads the current pose and its marginal covariance. Never hands out a
 * non-finite pose: VL_ERR_NON_FINITE instead (the divergence guard resets the
 * estimator before that can last beyond one call).
 */
vl_status_t vl_get_pose(const vl_estimator_t *e, vl_pose_t *out);

/**
 * Copies the landmarks now in the window into out (up to capacity).
 * @param count set to the number in the window, even when capacity is too small
 * @return VL_OK, or VL_ERR_CAPACITY when capacity < count (out holds the first capacity).
 */
vl_status_t vl_get_landmarks(const vl_estimator_t *e, vl_landmark_t *out, size_t capacity, size_t *count);

/**
 * Re-initializes the estimator as vl_init would with its current configuration
 * (calibration included), keeping the counters; the window's landmarks go to the
 * sink first (vl_flush_landmarks), in the world they were estimated in. Counted in resets.
 */
vl_status_t vl_reset(vl_estimator_t *e);

/** Bits of vl_get_state_flags: conditions of the estimator now (not events). */
#define VL_STATE_NO_CLOCK 1u   /**< no IMU sample yet since vl_init or the last reset: nothing to track */
#define VL_STATE_IMU_SILENT 2u /**< degraded: the IMU has been silent longer than max_imu_silence */

/** VL_STATE_* bits of the estimator now; 0 when tracking normally (and for NULL). */
uint32_t vl_get_state_flags(const vl_estimator_t *e);

/** Marginalizes every landmark in the window into the sink (end of a run). */
vl_status_t vl_flush_landmarks(vl_estimator_t *e);

/**
 * The work of the last vl_propagate, vl_update or vl_update_deferred call, per stage (zero after
 * vl_init and after a refused call). Cheap: a copy; out is zeroed for a NULL e.
 */
void vl_get_work(const vl_estimator_t *e, vl_work_t *out);

/** Counters since vl_init. */
const vl_counters_t *vl_get_counters(const vl_estimator_t *e);

/** Fills out with every counter, in declaration order; returns VL_NUM_COUNTERS. */
size_t vl_counters_list(const vl_counters_t *counters, vl_counter_entry_t out[VL_NUM_COUNTERS]);

/** Landmarks now in the window. */
uint32_t vl_window_size(const vl_estimator_t *e);

/** Dimension of the joint state now (VL_CORE_DIM + 3 * landmarks). */
uint32_t vl_state_dim(const vl_estimator_t *e);

/** Unit quaternion [w, x, y, z] (w >= 0, so equal rotations print equal) of a row-major rotation. */
void vl_rotation_to_quaternion(const double R[9], double q_wxyz[4]);

/** A short English description of a status value. */
const char *vl_status_str(vl_status_t status);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_VISLAM_H */
