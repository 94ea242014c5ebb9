/**
 * @file vl_sim.h
 * @brief Deterministic synthetic visual-inertial scenario with known truth.
 *
 * A vehicle drives a loop-ish path (about 8 m/s forward, a 90-degree turn every
 * few seconds, small pitch/roll/heave wobble) through a world of random
 * points scattered around the road (never on it), denser near the road. Each step the simulator returns what the
 * real datasets hold for one step (see ../shared/data/README.md):
 * - an IMU sample: body velocities (IMU frame x forward, y left, z up) with
 *   Gaussian noise and constant offsets added: the instantaneous velocity at
 *   this step's time, as a real IMU or odometer measures it (or, with
 *   interval_velocities, the constant velocity from this step to the next);
 * - a stereo frame: rectified pixel observations [u_left, v_left, u_right,
 *   v_right] of the visible points, with track ids;
 * - the true world-from-IMU pose at this step's time.
 *
 * The vehicle's velocity u(s) is a smooth function of time. By default the
 * truth integrates it between steps (VL_SIM_SUBSTEPS midpoint steps of the
 * exponential map), and a step's sample is u at the step's time. With
 * interval_velocities the velocity is constant between steps instead, and the
 * truth obeys w_T_i(t+1) = w_T_i(t) * exp(tau_t * hat(u_t)) exactly. In both,
 * u_t is the noise-free velocity of step t, tau_t the difference of the two
 * microsecond times in seconds, and w_T_i(0) = identity.
 *
 * Determinism: everything derives from two seeds through independent random
 * streams. `seed` fixes the world (path shape, time jitter, points, track
 * lengths); `noise_seed` fixes the measurement noise only. Changing the noise
 * levels or noise_seed therefore leaves the trajectory, the points and every
 * track (ids, lengths, which frames see them) unchanged: Monte-Carlo runs over
 * noise_seed see the same scenario with fresh noise.
 *
 * Tracks: a visible point without a track starts one (new id, ids increase by
 * one from 0) with probability detect_probability per frame. A track lasts at
 * most a random number of frames (track_length_min plus an exponential draw),
 * and ends early when its point leaves the view or the frame is full. An ended
 * id never appears again; the same point may later get a new id.
 *
 * Realistic conditions (all off by default; vl_sim_config_realistic sets the
 * rates measured on the seed drives by tools/sim/track_stats.py):
 * - Stale frames. A stale frame k repeats the previous frame's observations of
 *   every live track exactly (same ids, same pixels), and none of them ends
 *   there; new tracks may start on it, on time. Each track that lives through
 *   it then loses one step of motion: from frame k + 1 on it shows its point
 *   as if the camera were still at pose k (its point is moved by
 *   T(k+1) T(k)^-1, world-from-IMU, for the rest of the track), and moves on
 *   time after that. The real data shows exactly this (tracks carried over a
 *   stale frame agree with the ground-truth motion k-1 -> k across it, not
 *   k-1 -> k+1, and with k+1 -> k+2 after it). But each carried track also
 *   jumps: its u and v by stale_jump px (std, zero mean) and its disparity by
 *   stale_jump_disparity, drawn once at the stale frame and kept for the rest
 *   of the track (it sees a point displaced so). A frame is stale with
 *   probability stale_probability, and, with detect_below_fraction set, on
 *   every detection frame: the real tracker starts tracks only when fewer than
 *   about 50 remain, and each of its detection frames is stale.
 * - Re-associated ids: in a frame chosen with probability reassoc_probability,
 *   a fraction of the continued tracks hand their id to another visible,
 *   untracked point at most reassoc_radius px away; the id continues there.
 * - Moving points: a fraction of the placed points move at a constant world
 *   velocity, consistent within a track but not with the static world.
 * - Mismatches: an observation of a continued track is replaced, with
 *   probability mismatch_probability, by the pixels of a random location.
 * - Far points: a fraction of the placed points lie far ahead instead, at a
 *   depth giving a disparity in [far_disparity_min, far_disparity_max]; they
 *   are observable beyond max_depth.
 * - Calibration error: observations come from a perturbed cam_T_imu and
 *   baseline; vl_sim_calibration still returns the nominal calibration.
 * The decisions draw from three further world streams, seeded from `seed`:
 * rng_event (stale frames, re-associations, mismatches and the mismatched
 * pixels), rng_place (which placed points are far or moving, and how) and
 * rng_jump (the stale frames' jumps). No
 * stream is drawn from for a condition that is off, so with every condition
 * off the outputs are those of the plain simulator, bit for bit. With one on,
 * the world streams still give the same path and points, and noise_seed still
 * changes the noise only.
 *
 * Memory: the caller owns the vl_sim_t (see VL_SIM_* capacities; about
 * 1.4 MB, so prefer static or heap storage over the stack). Nothing
 * allocates; vl_sim_step does a fixed amount of work per live point.
 */
#ifndef VISLAM_VL_SIM_H
#define VISLAM_VL_SIM_H

#include <stdint.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Planned poses held around the vehicle (ring size); bounds the lookahead at low speed. */
#define VL_SIM_POSE_RING 1024
/** Integration steps of the continuous motion between two sensor steps. */
#define VL_SIM_SUBSTEPS 16
/** World points alive at once; the oldest is recycled when a new one is needed. */
#define VL_SIM_MAX_POINTS 8192
/** Most recent track ids whose true position vl_sim_landmark can still return. */
#define VL_SIM_MAX_TRACKS 16384

/** Scenario configuration. Start from vl_sim_config_default(). */
typedef struct {
    uint64_t seed;       /**< world: path, time jitter, points, track lengths */
    uint64_t noise_seed; /**< measurement noise only (pixels, velocities) */
    uint32_t num_steps;  /**< steps to produce; 0 = unlimited */
    int64_t start_utime; /**< us, time of step 0 */

    double dt_min; /**< s, shortest step (uniform in [dt_min, dt_max]) */
    double dt_max; /**< s, longest step */

    double speed;                 /**< m/s, mean forward (IMU x) speed */
    double speed_wobble;          /**< m/s, amplitude of the slow forward speed variation */
    double side_wobble;           /**< m/s, amplitude of the lateral (y) and vertical (z) velocity */
    double turn_angle;            /**< rad, mean magnitude of each turn */
    double left_turn_probability; /**< chance that a turn goes left (the rest go right); 1 drives a loop */
    double turn_angle_spread;     /**< relative std of each turn's angle (0 = all equal) */
    double turn_period;           /**< s, time between turn centres */
    double first_turn_time;       /**< s, centre of the first turn after step 0 */
    double turn_duration;         /**< s, length of each raised-cosine turn (<= turn_period) */
    double yaw_wobble;            /**< rad/s, amplitude of a slow yaw-rate wander */
    double roll_pitch_rate;       /**< rad/s, amplitude of the roll and pitch rates */

    double points_per_meter; /**< points scattered per metre of path */
    double road_half_width;  /**< m, no point lies closer than this (horizontally) to the path */
    double scatter_radius;   /**< m, points lie within this distance of the path pose that placed them */
    double scatter_exponent; /**< > 1 concentrates points near the path (r = w + (radius - w) * U^exponent) */
    double height_min;       /**< m, point height over the placing pose (its z up) */
    double height_max;       /**< m */

    vl_calibration_t calibration; /**< stereo rig (default: the KITTI 0027 values) */
    double image_width;           /**< px, u in [0, image_width - 1] */
    double image_height;          /**< px, v in [0, image_height - 1] */
    double border_margin;         /**< px, true projections must lie this far inside the image */
    double min_depth;             /**< m, nearest observable depth (camera z) */
    double max_depth;             /**< m, farthest observable depth */
    uint32_t max_observations;    /**< observations per frame, 1..VL_MAX_FRAME_FEATURES */
    double detect_probability;    /**< per frame, that a visible untracked point starts a track */
    double track_length_mean;     /**< frames, mean of the per-track maximum length */
    uint32_t track_length_min;    /**< frames, shortest per-track maximum length (>= 1) */

    double pixel_noise;        /**< px, std of each of u_left, v_left, u_right, v_right */
    double linear_noise;       /**< m/s, std of each linear velocity sample and axis */
    double angular_noise;      /**< rad/s, std of each angular velocity sample and axis */
    double linear_offset[3];   /**< m/s, constant offset added to the linear velocities */
    double angular_offset[3];  /**< rad/s, constant offset added to the angular velocities */
    double velocity_sensor[3]; /**< m, the linear velocity sensor's position in the IMU frame: its samples are the
                                  velocity there, v + w x p (0: at the IMU, as the estimator's default assumes) */
    int interval_velocities;   /**< 1: the velocity is constant between steps (the sample holds until the next) */

    /* Realistic conditions (see the file comment); 0 turns each one off. */
    double stale_probability;          /**< per frame after step 0, that the frame is stale */
    double detect_below_fraction;      /**< of max_observations: when > 0, tracks start only on step 0 and
                                       on frames after one with fewer observations than this share
                                       (rounded, at least 1) and that was not stale itself;
                                       those frames are stale */
    double detect_new_fraction;        /**< of max_observations: most tracks started per frame (rounded, at
                                       least 1); 0 = no limit */
    double reassoc_probability;        /**< per frame, that continued ids are handed to other points */
    double reassoc_fraction;           /**< share of the continued tracks re-associated in such a frame
                                       (each with this chance, at least one) */
    double reassoc_radius;             /**< px, farthest a re-associated id's left pixel jumps */
    double moving_fraction;            /**< share of placed points that move (constant world velocity) */
    double moving_speed;               /**< m/s, speed of a moving point (horizontal, random heading) */
    double mismatch_probability;       /**< per observation of a continued track: pixels of a random location */
    double far_fraction;               /**< share of placed points put far ahead instead */
    double far_disparity_min;          /**< px, smallest disparity of a far point (> 0) */
    double far_disparity_max;          /**< px, largest disparity of a far point */
    double calib_rotation_error[3];    /**< deg, rotation vector (camera axes) applied to cam_T_imu
                                            for the observations */
    double calib_translation_error[3]; /**< m, added to cam_T_imu's translation for the observations */
    double baseline_error;             /**< relative: observations use baseline * (1 + baseline_error) */
    double stale_jump;                 /**< px, std of the jump of each carried track's u and v across a
                                            stale frame */
    double stale_jump_disparity;       /**< px, std of the same jump in disparity */
} vl_sim_config_t;

/** How often the realistic conditions occurred so far. */
typedef struct {
    uint64_t stale_frames;   /**< frames that repeated the previous one's observations */
    uint64_t reassociations; /**< ids handed to another point */
    uint64_t mismatches;     /**< observations replaced by a random location */
} vl_sim_counts_t;

/** Random stream state (xoshiro256**, with a cached Box-Muller deviate). */
typedef struct {
    uint64_t s[4];
    double spare;
    int has_spare;
} vl_sim_rng_t;

/** One planned step: its time, true pose and true velocities. */
typedef struct {
    int64_t utime; /**< us */
    double R[9];   /**< world-from-IMU rotation, row-major */
    double p[3];   /**< m */
    double u[6];   /**< true [v (m/s); w (rad/s)] held from this step to the next */
    double s;      /**< m, path length from step 0 */
} vl_sim_pose_t;

/** A world point and the state of its current track. */
typedef struct {
    double x[3];        /**< world position at time t0, m */
    double v[3];        /**< m/s, world velocity (moving points only) */
    double shift[3];    /**< m, displacement the current track sees (motion lost at stale frames) */
    int64_t t0;         /**< us, time of x (moving points only) */
    int32_t track_id;   /**< current track id, -1 when untracked */
    uint32_t remaining; /**< frames the current track may still be observed */
    uint8_t far;        /**< 1: placed far, observable beyond max_depth */
    uint8_t moving;     /**< 1: moves with v */
    uint8_t shifted;    /**< 1: shift is not zero */
} vl_sim_point_t;

/** The simulator. Caller-owned; read it only through the functions below. */
typedef struct {
    vl_sim_config_t cfg;
    vl_sim_rng_t rng_path;      /**< turn angles, phases, time jitter */
    vl_sim_rng_t rng_map;       /**< point placement */
    vl_sim_rng_t rng_track;     /**< detections and track lengths */
    vl_sim_rng_t rng_noise;     /**< measurement noise */
    vl_sim_rng_t rng_event;     /**< stale frames, re-associations, mismatches */
    vl_sim_rng_t rng_place;     /**< far and moving points */
    vl_sim_rng_t rng_jump;      /**< the carried tracks' jumps across stale frames */
    vl_calibration_t obs_calib; /**< the calibration the observations are made with */

    double phase[8]; /**< rad, phases of the wobble terms */

    vl_sim_pose_t ring[VL_SIM_POSE_RING];
    uint64_t planned;        /**< poses planned (ring holds the last ones) */
    uint64_t step;           /**< steps returned so far */
    uint64_t scattered;      /**< planned segments whose points have been placed */
    double vehicle_distance; /**< m, path length up to the last step returned */
    double spawn_carry;      /**< fractional point carried to the next segment */

    vl_sim_point_t points[VL_SIM_MAX_POINTS];
    uint32_t num_points; /**< points placed, saturating at VL_SIM_MAX_POINTS */
    uint32_t next_point; /**< slot the next placed point takes */

    int32_t next_track_id;
    double track_x[VL_SIM_MAX_TRACKS][3]; /**< true position of track id (ring by id) */

    vl_imu_sample_t last_true_imu;                   /**< noise-free velocities of the last step */
    uint32_t cand_point[VL_MAX_FRAME_FEATURES];      /**< scratch: points observed this frame */
    vl_stereo_obs_t last_obs[VL_MAX_FRAME_FEATURES]; /**< the last frame's observations (stale frames repeat them) */
    uint32_t last_count;                             /**< observations in the last frame */
    uint8_t last_stale;                              /**< 1 when the last frame was stale */
    vl_sim_counts_t counts;
} vl_sim_t;

/** The KITTI 0027 stereo rig: its intrinsics, baseline and cam_T_imu (the simulator's default). */
void vl_sim_kitti_calibration(vl_calibration_t *cal);

/** Fills the defaults: a 300-step, 10 Hz drive with KITTI-like camera and the real data's noise. */
void vl_sim_config_default(vl_sim_config_t *cfg);

/**
 * Sets every realistic condition to the rate measured on the seed drives (tools/sim/track_stats.py),
 * max_observations to 95 (the real tracker's 50 + 45 at a detection frame), points_per_meter to 4
 * (enough points for those detections) and pixel_noise to 0.3 px (the real stereo rows agree to
 * 0.38 px std); other fields are left as they are. Lower max_observations afterwards for sparser drives: the detection threshold
 * and the tracks per detection scale with it. The calibration error is a small guess (the data
 * cannot show it), not a measurement.
 */
void vl_sim_config_realistic(vl_sim_config_t *cfg);

/**
 * Checks the configuration and starts the scenario at step 0.
 * @return 0, or -1 when a pointer is NULL or a value is out of range.
 */
int vl_sim_init(vl_sim_t *sim, const vl_sim_config_t *cfg);

/**
 * Produces the next step. Any output pointer may be NULL.
 * @param imu     measured velocities (noise and offsets added) at this step's time
 * @param frame   stereo observations at this step's time (ids ascending)
 * @param true_R  true world-from-IMU rotation at this step's time, row-major
 * @param true_p  true IMU position in the world at this step's time, m
 * @return 0 when a step was produced, 1 when num_steps have been produced already.
 */
int vl_sim_step(vl_sim_t *sim, vl_imu_sample_t *imu, vl_stereo_frame_t *frame, double true_R[9], double true_p[3]);

/** The nominal stereo rig calibration (what the log carries; the observations may use a perturbed one). */
void vl_sim_calibration(const vl_sim_t *sim, vl_calibration_t *calib);

/** How often each realistic condition occurred so far (zeros when sim is NULL). */
void vl_sim_counts(const vl_sim_t *sim, vl_sim_counts_t *counts);

/**
 * True world position of a track id: its point's position at the track's first frame (a
 * re-associated id keeps the first point's; a moving point moves on).
 * @return 0, or -1 when the id was never issued or is older than the last VL_SIM_MAX_TRACKS ids.
 */
int vl_sim_landmark(const vl_sim_t *sim, int32_t id, double position[3]);

/** Noise-free IMU sample of the last step produced (same time as the measured one). */
const vl_imu_sample_t *vl_sim_true_imu(const vl_sim_t *sim);

/** Steps produced so far. */
uint64_t vl_sim_steps_done(const vl_sim_t *sim);

/** Track ids issued so far (ids are 0 .. count - 1). */
int32_t vl_sim_tracks_issued(const vl_sim_t *sim);

/** Path length driven up to the last step produced, m. */
double vl_sim_distance(const vl_sim_t *sim);

/**
 * Applies the simulator's SE(3) exponential: (R, p) <- (R, p) * exp(tau * hat([v; w])).
 * Exposed so tests and tools can integrate velocities exactly as the truth does.
 */
void vl_sim_integrate(double R[9], double p[3], const double u[6], double tau);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_VL_SIM_H */
