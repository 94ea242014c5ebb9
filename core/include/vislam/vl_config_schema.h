/**
 * @file vl_config_schema.h
 * @brief The estimator configuration, defined once.
 *
 * VL_CONFIG_KEYS(X) holds one row per plain value of vl_config_t:
 *
 *     X(section, key, field, type, default, min, max, min_open, units, meaning)
 *
 * - section, key: where the value lives in the INI file ("[section] key = ...").
 * - field: the vl_config_t member; vislam.h declares the members from these rows,
 *   in this order.
 * - type: DOUBLE (double), UINT32 (uint32_t), BOOL (int, nonzero is true; written
 *   true|false) or MODE (vl_mode_t; written imu_only|mapping|slam).
 * - default: what vl_config_default() sets.
 * - min, max, min_open: the range vl_config_check() and the INI reader enforce:
 *   min < value (min_open = 1) or min <= value (min_open = 0), and value <= max.
 *   DOUBLE values must also be finite, so DBL_MAX as max means "no upper bound".
 *   BOOL rows are not range checked (any int is a truth value).
 * - units: the value's unit, "" for counts, flags and ratios.
 * - meaning: one paragraph for tools/vislam.ini and --print-config.
 *
 * From these rows come: the members of vl_config_t, vl_config_default(),
 * the per-key checks of vl_config_check(), the INI reader's key table and its
 * writer (platform/vl_config_file.c), and tools/vislam.ini, which a test
 * compares with the writer's output byte for byte.
 *
 * Not in the table: the calibration (vl_calibration_t: a rig, not tuning,
 * checked as a whole) and the callbacks; the INI file's [estimator] preset and
 * [calibration] keys are handled by the INI code itself. Checks that involve
 * more than one value stay as code in vl_config_check().
 *
 * Rows are grouped by section, sections in the INI file's order.
 * The table is only expanded where it is used, so VL_MAX_LANDMARKS, the vl_mode_t
 * values, VL_MAX_TIME_LIMIT, DBL_MAX and UINT32_MAX need only be visible there.
 */
#ifndef VISLAM_VL_CONFIG_SCHEMA_H
#define VISLAM_VL_CONFIG_SCHEMA_H

#include <float.h>
#include <stdint.h>

/** Value types of VL_CONFIG_KEYS rows (VL_CONFIG_ followed by the row's type). */
typedef enum {
    VL_CONFIG_DOUBLE = 0, /**< double */
    VL_CONFIG_UINT32 = 1, /**< uint32_t */
    VL_CONFIG_BOOL = 2,   /**< int, nonzero is true */
    VL_CONFIG_MODE = 3    /**< vl_mode_t */
} vl_config_type_t;

/** @cond */
/* The C type of each row type, for declaring the members. */
#define VL_CONFIG_CTYPE_DOUBLE double
#define VL_CONFIG_CTYPE_UINT32 uint32_t
#define VL_CONFIG_CTYPE_BOOL int
#define VL_CONFIG_CTYPE_MODE vl_mode_t
/** @endcond */

/* clang-format off */
/** Every plain configuration value; see the file comment for the columns. */
#define VL_CONFIG_KEYS(X) \
    /* ---- [estimator] ---- */ \
    X("estimator", "mode", mode, MODE, VL_MODE_SLAM, VL_MODE_IMU_ONLY, VL_MODE_SLAM, 0, "", \
      "What to estimate: imu_only (dead reckoning: prediction only), mapping (landmarks " \
      "estimated, the pose follows the prediction only), slam (joint pose and landmark update).") \
    X("estimator", "estimate_input_offsets", estimate_input_offsets, BOOL, 1, 0, 1, 0, "", \
      "true: estimate constant offsets of the linear and angular velocity inputs as six extra " \
      "states (see [noise] *_offset_*).") \
    X("estimator", "adaptive_noise", adaptive_noise, BOOL, 1, 0, 1, 0, "", \
      "true: the [noise] values linear_velocity, angular_velocity and pixel are priors, adapted " \
      "online from the filter's own corrections and residuals (within a factor of 100 of the " \
      "configured value).") \
    X("estimator", "interpolate_velocities", interpolate_velocities, BOOL, 1, 0, 1, 0, "", \
      "true: each velocity sample is the instantaneous velocity at its time, and between two " \
      "samples the velocity is taken as linear (trapezoidal integration; IMUs, wheel odometry, " \
      "INS). false: a sample holds until the next one (velocities that are means over the " \
      "interval that follows them, e.g. differences of consecutive poses).") \
    X("estimator", "velocity_sensor_x", velocity_sensor_x, DOUBLE, 0.0, -100.0, 100.0, 0, "m", \
      "Where the linear velocity samples are measured, in the body (IMU) frame of cam_T_imu: " \
      "x. A sensor away from the body origin (wheel odometry at an axle, an INS or GNSS " \
      "antenna elsewhere) sees the body's velocity plus the turn rate times its lever arm; " \
      "the estimator takes that back out (v_body = v - w x p), and the angular noise and " \
      "offsets reach the linear velocity through the same lever arm.") \
    X("estimator", "velocity_sensor_y", velocity_sensor_y, DOUBLE, 0.0, -100.0, 100.0, 0, "m", \
      "The same: y.") \
    X("estimator", "velocity_sensor_z", velocity_sensor_z, DOUBLE, 0.0, -100.0, 100.0, 0, "m", \
      "The same: z.") \
    /* Forward only by default: a lateral lever arm turns the mean yaw rate of a drive into a \
       forward velocity error, which it then trades with the images' scale (README). */ \
    X("estimator", "velocity_sensor_std_x", velocity_sensor_std_x, DOUBLE, 2.0, 0.0, 100.0, 0, "m", \
      "How well velocity_sensor_x is known: the prior std of the sensor position, estimated " \
      "as a state from the turns (0: known exactly, not estimated).") \
    X("estimator", "velocity_sensor_std_y", velocity_sensor_std_y, DOUBLE, 0.0, 0.0, 100.0, 0, "m", \
      "The same: y.") \
    X("estimator", "velocity_sensor_std_z", velocity_sensor_std_z, DOUBLE, 0.0, 0.0, 100.0, 0, "m", \
      "The same: z.") \
    X("estimator", "max_propagation_dt", max_propagation_dt, DOUBLE, 0.5, 0.0, DBL_MAX, 1, "s", \
      "A gap between inputs longer than this is counted (time_gaps) and still propagated.") \
    /* 64 observations (192 rows) keep an update at a full window of 128 under 2 ms at p99.9 \
       on 0034; what it leaves out goes after the pose (apply_deferred; README). */ \
    X("estimator", "max_update_observations", max_update_observations, UINT32, 64, 0, UINT32_MAX, 0, "", \
      "Most observations one update uses (0: all). A time bound: the update costs about " \
      "(15 + 3 landmarks)^2 x 3 observations; the inliers left out go after the frame's pose " \
      "(apply_deferred).") \
    /* 18.5 Mflop: the costliest step of 0034 at 1.75x the median step's work; with \
       apply_deferred the bound costs 0027 no accuracy (README, Bounded work per step). */ \
    X("estimator", "max_update_work", max_update_work, DOUBLE, 18.5, 0.0, DBL_MAX, 0, "Mflop", \
      "Most arithmetic one frame's joint updates may do, in millions of floating-point " \
      "operations (0: no bound). The update with n states and m rows costs about " \
      "n^2 m + n m^2 + m^3 / 3 flops, so the bound admits fewer observations the larger the " \
      "window: a flat worst case. At least one observation is always used; the inliers left " \
      "out go after the frame's pose (apply_deferred).") \
    /* On: at budgets of 22 Mflop and below the even spread leaves some landmarks never updated \
       (README, Bounded work per step). */ \
    X("estimator", "rotate_deferred", rotate_deferred, BOOL, 1, 0, 1, 0, "", \
      "When a time bound leaves observations out, keep those of the landmarks the updates have " \
      "used least (then longest ago) instead of an evenly spread subset, so that the landmarks " \
      "deferred in one frame go first in the next.") \
    /* On: what the bound leaves out is still used before the next input, so the bound costs the \
       pose's latency nothing and the estimate little (README, Bounded work per step). */ \
    X("estimator", "apply_deferred", apply_deferred, BOOL, 1, 0, 1, 0, "", \
      "Apply the inliers the time bound left out of a frame's update after the frame's pose is out " \
      "(vl_update_deferred, which every vislam program calls before its next input), at the corrected " \
      "state and within max_deferred_work.") \
    /* As much as the frame's update: over the test bed it keeps what no bound at all gains (0034's \
       costliest deferred update 84 Mflop unbounded), and a frame's work at most about twice its step's. */ \
    X("estimator", "max_deferred_work", max_deferred_work, DOUBLE, 18.5, 0.0, DBL_MAX, 0, "Mflop", \
      "Most arithmetic vl_update_deferred may do for one frame, in millions of floating-point " \
      "operations (0: no bound); the deferred inliers past it are dropped.") \
    \
    /* ---- [noise] ---- */ \
    /* The seed data's velocities carry about 0.5 m/s and 0.05 rad/s of noise per sample \
       (shared/data/README.md): model that, do not hide it. */ \
    X("noise", "linear_velocity", linear_velocity_noise, DOUBLE, 0.5, 0.0, DBL_MAX, 1, "m/s", \
      "Standard deviation of each linear velocity sample (each axis).") \
    X("noise", "angular_velocity", angular_velocity_noise, DOUBLE, 0.05, 0.0, DBL_MAX, 1, "rad/s", \
      "Standard deviation of each angular velocity sample (each axis).") \
    X("noise", "linear_offset_prior", linear_offset_prior, DOUBLE, 0.1, 0.0, DBL_MAX, 0, "m/s", \
      "Initial standard deviation of the linear velocity offset.") \
    X("noise", "angular_offset_prior", angular_offset_prior, DOUBLE, 0.01, 0.0, DBL_MAX, 0, "rad/s", \
      "Initial standard deviation of the angular velocity offset.") \
    X("noise", "linear_offset_walk", linear_offset_walk, DOUBLE, 1e-3, 0.0, DBL_MAX, 0, "m/s/sqrt(s)", \
      "Random walk of the linear velocity offset.") \
    X("noise", "angular_offset_walk", angular_offset_walk, DOUBLE, 1e-4, 0.0, DBL_MAX, 0, "rad/s/sqrt(s)", \
      "Random walk of the angular velocity offset.") \
    /* 100 s: at 50 s the sparse cells gain a little more and the simulated drives lose, at \
       200 s most of the gain is gone (docs/accuracy-notes.md). */ \
    X("noise", "offset_correlation_time", offset_correlation_time, DOUBLE, 100.0, 0.0, DBL_MAX, 0, "s", \
      "How long the velocity offsets' estimate stays tied to the trajectory that taught it: " \
      "each prediction step the offsets' correlations with every other state decay by " \
      "exp(-dt / this) while their own covariance and estimate stay (0: never), so a late " \
      "offset correction does not turn the whole window about the start.") \
    X("noise", "pixel", pixel_noise, DOUBLE, 1.5, 0.0, DBL_MAX, 1, "px", \
      "Standard deviation of each pixel coordinate of an observation.") \
    /* 0.35: better than off on 0027, its grid, the simulated drives, the realistic simulator and \
       the conditions table; 0.25 and 0.5 each lose on one of them (README, Accuracy). */ \
    X("noise", "repeat_anchor_noise", repeat_anchor_noise, DOUBLE, 0.35, 0.0, DBL_MAX, 0, "", \
      "At a repeated image (frames_repeated: a tracker's detection frame, whose carried tracks " \
      "resume at points displaced by the vehicle's step), the landmarks it observes get process " \
      "noise of one rigid motion they share, this many times the step since the previous frame " \
      "(translation and rotation about the vehicle). 0: off.") \
    /* 0.2: every suite of real data gains (0027 from 8 starts 1.78 to 1.50 m), and so does the \
       realistic simulator once it draws the measured jump (README, Accuracy). */ \
    X("noise", "repeat_track_walk", repeat_track_walk, DOUBLE, 0.2, 0.0, DBL_MAX, 0, "px", \
      "After a repeated image, each landmark whose track it carried gets, every frame for the rest " \
      "of its track, process noise of this many pixels in its camera's x, y and disparity (the " \
      "tracker displaces each carried track by about a pixel there, so a point triangulated " \
      "before the repeat no longer quite is the one tracked). 0: off.") \
    \
    /* ---- [landmarks] ---- */ \
    X("landmarks", "max_landmarks", max_landmarks, UINT32, VL_MAX_LANDMARKS, 1, VL_MAX_LANDMARKS, 0, "", \
      "Active window: landmarks held in the joint state, at most VL_MAX_LANDMARKS (a " \
      "compile-time capacity, 128 unless built otherwise).") \
    /* The seed's tracks have no gaps: an unseen track has ended. */ \
    X("landmarks", "max_unseen_frames", max_unseen_frames, UINT32, 0, 0, UINT32_MAX, 0, "", \
      "Frames a landmark may go unobserved before it is marginalized into the map (0: a track " \
      "that is not seen has ended).") \
    X("landmarks", "min_disparity", min_disparity, DOUBLE, 1.0, 0.0, DBL_MAX, 1, "px", \
      "No landmark starts from an observation with a smaller disparity u_left - u_right.") \
    X("landmarks", "max_depth", max_depth, DOUBLE, 150.0, 0.0, DBL_MAX, 1, "m", \
      "No landmark starts farther away than this.") \
    X("landmarks", "max_admissions", max_admissions, UINT32, 0, 0, UINT32_MAX, 0, "", \
      "Most landmarks admitted in one frame (0: no bound), the best-ranked first. The other " \
      "candidates wait (landmarks_deferred) and compete again in the next frame, so a burst of " \
      "new tracks grows the state over several frames.") \
    X("landmarks", "min_track_length", min_track_length, UINT32, 2, 1, UINT32_MAX, 0, "", \
      "Frames a new track must span before its landmark is admitted. From the second frame on, " \
      "the track must also agree with its previous observation (gate_chi2).") \
    X("landmarks", "first_sight_below", first_sight_below, UINT32, 24, 0, UINT32_MAX, 0, "", \
      "A frame with fewer observations than this admits its new tracks at first sight, whatever " \
      "min_track_length: a sparse tracker's tracks are short, and waiting a frame loses much of " \
      "each (0: never).") \
    \
    /* ---- [outliers] ---- */ \
    X("outliers", "gate_chi2", gate_chi2, DOUBLE, 11.34, 0.0, DBL_MAX, 0, "", \
      "Chi-square gate (3 dof) on an observation's innovation; 11.34 is the 0.99 quantile. " \
      "0 turns every outlier test below off (the seed's plain EKF).") \
    X("outliers", "max_broken_fraction", max_broken_fraction, DOUBLE, 0.3, 0.0, 1.0, 1, "", \
      "A frame in which more than this fraction of tracked observations fail the gate is a " \
      "tracker re-association: none is used, every such track restarts.") \
    X("outliers", "ransac_hypotheses", ransac_hypotheses, UINT32, 32, 0, 4096, 0, "", \
      "1-point RANSAC hypotheses per frame (0: gate each observation alone).") \
    X("outliers", "ransac_threshold", ransac_threshold, DOUBLE, 3.0, 0.0, DBL_MAX, 1, "px", \
      "Residual a RANSAC hypothesis may leave on an observation for the observation to " \
      "support it.") \
    \
    /* ---- [limits] ---- */ \
    /* Far outside anything a clean drive shows (the seed drives: steps of 0.1 s, at most \
       16 m/s and 0.8 rad/s, disparities up to 190 px, pixels up to 30 px beyond 2 cx and \
       2 cy), so clean data is never refused. */ \
    X("limits", "max_time_jump", max_time_jump, DOUBLE, 10.0, 0.0, VL_MAX_TIME_LIMIT, 1, "s", \
      "An input whose time is farther than this from the estimator's clock, ahead or behind, " \
      "is refused (time_jumps); the clock stays.") \
    X("limits", "new_timeline_samples", new_timeline_samples, UINT32, 5, 2, UINT32_MAX, 0, "", \
      "This many consecutive time-refused inputs (jumps or out of order) that follow one " \
      "another in time (each within max_time_jump of the previous, IMU and frames each " \
      "strictly forward) are a new timeline (a log restarted, a clock stepped): the estimator " \
      "re-initializes on it (timeline_changes) at the next IMU sample. 5 is 0.3 s at 10 Hz.") \
    X("limits", "max_speed", max_speed, DOUBLE, 100.0, 0.0, DBL_MAX, 1, "m/s", \
      "IMU samples with a faster linear velocity (norm) are refused; 100 m/s is 360 km/h.") \
    X("limits", "max_rotation_rate", max_rotation_rate, DOUBLE, 35.0, 0.0, DBL_MAX, 1, "rad/s", \
      "IMU samples with a faster angular velocity (norm) are refused; 35 rad/s is 2000 deg/s, " \
      "a common gyro full scale.") \
    X("limits", "image_width", image_width, DOUBLE, 0.0, 0.0, DBL_MAX, 0, "px", \
      "Image width; 0 takes 2 cx of the calibration. An observation with a pixel outside the " \
      "image widened by image_margin on every side is refused (observations_implausible).") \
    X("limits", "image_height", image_height, DOUBLE, 0.0, 0.0, DBL_MAX, 0, "px", \
      "Image height; 0 takes 2 cy of the calibration.") \
    X("limits", "image_margin", image_margin, DOUBLE, 64.0, 0.0, DBL_MAX, 0, "px", \
      "Pixels this far outside the image still count as inside. 64 covers the seed drives, " \
      "whose principal point is up to 30 px off the image centre.") \
    X("limits", "max_disparity", max_disparity, DOUBLE, 400.0, 0.0, DBL_MAX, 1, "px", \
      "Observations with a larger disparity u_left - u_right are refused (400 px is about " \
      "1 m away on the KITTI rig, fx b = 380 px m).") \
    X("limits", "max_imu_silence", max_imu_silence, DOUBLE, 0.5, 0.0, VL_MAX_TIME_LIMIT, 1, "s", \
      "An IMU velocity is used for at most this long after its sample (0.5 s: five missed " \
      "samples at 10 Hz). Past that the estimator reports itself degraded until the IMU " \
      "returns, no stale velocity is integrated, and the covariance takes the unknown motion; " \
      "in slam mode the frames carry the pose meanwhile (frames_imu_silent: at the velocity " \
      "between the last two frames, corrected by each), the other modes refuse them.") \
    X("limits", "divergence_frames", divergence_frames, UINT32, 20, 0, UINT32_MAX, 0, "", \
      "In slam mode, this many frames in a row whose update failed (refused, or most " \
      "observations contradicting the state) mean the estimator diverged: it re-initializes " \
      "(divergence_resets). 0: never. A non-finite state or covariance always re-initializes. " \
      "20 is 2 s at 10 Hz.")
/* clang-format on */

#endif /* VISLAM_VL_CONFIG_SCHEMA_H */
