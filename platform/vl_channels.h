/**
 * @file vl_channels.h
 * @brief The default LCM channel names, defined once for every program and test tool.
 *
 * vislamd subscribes to the three inputs and publishes the four outputs;
 * vislam-replay, vislam-run (through the log reader), vislam-sim and the test
 * tools use the same names. Programs that take a channel option start from these.
 * The Python tools (tools/vislam_tools) cannot include this header and spell the
 * names again; the README's Messages table is the contract both follow.
 */
#ifndef VISLAM_PLATFORM_VL_CHANNELS_H
#define VISLAM_PLATFORM_VL_CHANNELS_H

/** vislam.imu_t: body linear and angular velocity. */
#define VL_CHANNEL_IMU "VISLAM_IMU"
/** vislam.stereo_frame_t: the stereo keypoint tracks of one camera frame. */
#define VL_CHANNEL_FEATURES "VISLAM_FEATURES"
/** vislam.calibration_t: the stereo rig. */
#define VL_CHANNEL_CALIBRATION "VISLAM_CALIB"
/** vislam.pose_t: the estimate after every input. */
#define VL_CHANNEL_POSE "VISLAM_POSE"
/** bot_core.pose_t: the same pose for libbot2 tools. */
#define VL_CHANNEL_BOT_POSE "POSE"
/** vislam.status_t: counts, timing and health, once a second and on events. */
#define VL_CHANNEL_STATUS "VISLAM_STATUS"
/** vislam.landmarks_t: the landmarks leaving the window (the map), in batches. */
#define VL_CHANNEL_LANDMARKS "VISLAM_LANDMARKS"

#endif /* VISLAM_PLATFORM_VL_CHANNELS_H */
