/**
 * @file vl_msg.h
 * @brief Conversions between the LCM message types and the core types.
 *
 * Pure functions: no I/O, no allocation. Shared by the offline runner and the
 * daemon, so a log replayed offline and the same messages received live are
 * turned into identical core inputs.
 */
#ifndef VISLAM_PLATFORM_VL_MSG_H
#define VISLAM_PLATFORM_VL_MSG_H

#include <stdint.h>

#include "vislam/vislam.h"

#include "bot_core_pose_t.h"
#include "vislam_calibration_t.h"
#include "vislam_imu_t.h"
#include "vislam_landmarks_t.h"
#include "vislam_pose_t.h"
#include "vislam_stereo_frame_t.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Result of a message conversion. */
typedef enum {
    VL_MSG_OK = 0,        /**< Converted. */
    VL_MSG_ERR_NULL = -1, /**< A pointer argument was NULL. */
    VL_MSG_ERR_COUNT = -2 /**< num_features outside 0..VISLAM_STEREO_FRAME_T_MAX_FEATURES
                                     (the output was still filled, with the count clamped). */
} vl_msg_status_t;

/** Copies an IMU message into a core sample (values are not checked; the core rejects non-finite ones). */
vl_msg_status_t vl_msg_to_imu(const vislam_imu_t *msg, vl_imu_sample_t *out);

/** Copies a core IMU sample into a message (used by log writers and tests). */
vl_msg_status_t vl_msg_from_imu(const vl_imu_sample_t *imu, vislam_imu_t *out);

/**
 * Copies a feature message into a core frame.
 *
 * A count outside 0..256 means the message is corrupt: the frame is filled
 * with the count clamped into that range and VL_MSG_ERR_COUNT is returned, so
 * the caller decides whether to drop it (the log reader and daemon do).
 * If the core's VL_MAX_FRAME_FEATURES is smaller than the message's count,
 * only the first entries are copied but `count` keeps the full number so the
 * core counts the truncation.
 */
vl_msg_status_t vl_msg_to_stereo_frame(const vislam_stereo_frame_t *msg, vl_stereo_frame_t *out);

/** Copies a core frame into a message; more than 256 observations gives VL_MSG_ERR_COUNT (first 256 kept). */
vl_msg_status_t vl_msg_from_stereo_frame(const vl_stereo_frame_t *frame, vislam_stereo_frame_t *out);

/** Copies a calibration message into the core type; @p utime may be NULL. */
vl_msg_status_t vl_msg_to_calibration(const vislam_calibration_t *msg, vl_calibration_t *out, int64_t *utime);

/** Copies a core calibration into a message stamped @p utime (us). */
vl_msg_status_t vl_msg_from_calibration(const vl_calibration_t *calib, int64_t utime, vislam_calibration_t *out);

/**
 * 1 when a generated *_decode call that returned @p used consumed exactly the
 * @p len bytes received, else 0: a short read, a wrong hash and trailing
 * bytes all mean the payload is not one message. The one check every receiver
 * of a vislam message applies.
 */
int vl_msg_decoded_whole(int used, int len);

/** 1 when two calibrations are equal in every value, else 0. */
int vl_calibration_equal(const vl_calibration_t *a, const vl_calibration_t *b);

/**
 * Fills a vislam pose message.
 * @param source   VISLAM_POSE_T_SOURCE_IMU or VISLAM_POSE_T_SOURCE_FEATURES
 * @param sequence poses published before this one
 */
vl_msg_status_t vl_msg_from_pose(const vl_pose_t *pose, int8_t source, int64_t sequence, vislam_pose_t *out);

/**
 * Fills a libbot2-compatible pose with libbot2's frames: position in the
 * world (m), orientation (w, x, y, z) world-from-body, vel (m/s) and
 * rotation_rate (rad/s) in the world ("local") frame, i.e. R times the
 * offset-corrected body-frame values of @p pose; accel zero (not estimated).
 */
vl_msg_status_t vl_msg_from_pose_bot(const vl_pose_t *pose, bot_core_pose_t *out);

/**
 * Appends a landmark to a batch message (its covariance as the upper triangle).
 * @return VL_MSG_OK, or VL_MSG_ERR_COUNT when the batch already holds
 *         VISLAM_LANDMARKS_T_MAX_LANDMARKS (nothing written: publish it and start another)
 */
vl_msg_status_t vl_msg_add_landmark(const vl_landmark_t *landmark, vislam_landmarks_t *batch);

/**
 * Reads entry @p index of a batch message back into the core type.
 * @return VL_MSG_OK, or VL_MSG_ERR_COUNT when index is outside 0..count-1 of a count
 *         within 0..VISLAM_LANDMARKS_T_MAX_LANDMARKS (nothing written)
 */
vl_msg_status_t vl_msg_to_landmark(const vislam_landmarks_t *batch, int32_t index, vl_landmark_t *out);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_MSG_H */
