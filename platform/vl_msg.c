/* Conversions between LCM messages and core types. */
#include "vl_msg.h"

#include <math.h>
#include <string.h>

vl_msg_status_t vl_msg_to_imu(const vislam_imu_t *msg, vl_imu_sample_t *out)
{
    if (msg == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->utime = msg->utime;
    for (int i = 0; i < 3; ++i) {
        out->linear_velocity[i] = msg->linear_velocity[i];
        out->angular_velocity[i] = msg->angular_velocity[i];
    }
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_from_imu(const vl_imu_sample_t *imu, vislam_imu_t *out)
{
    if (imu == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->utime = imu->utime;
    for (int i = 0; i < 3; ++i) {
        out->linear_velocity[i] = imu->linear_velocity[i];
        out->angular_velocity[i] = imu->angular_velocity[i];
    }
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_to_stereo_frame(const vislam_stereo_frame_t *msg, vl_stereo_frame_t *out)
{
    if (msg == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    vl_msg_status_t status = VL_MSG_OK;
    int32_t n = msg->num_features;
    if (n < 0) {
        n = 0;
        status = VL_MSG_ERR_COUNT;
    } else if (n > VISLAM_STEREO_FRAME_T_MAX_FEATURES) {
        n = VISLAM_STEREO_FRAME_T_MAX_FEATURES;
        status = VL_MSG_ERR_COUNT;
    }
    out->utime = msg->utime;
    /* Keep the full count even when the core holds fewer: the core counts the truncation. */
    out->count = (uint32_t)n;
    int32_t copy = n < VL_MAX_FRAME_FEATURES ? n : VL_MAX_FRAME_FEATURES;
    for (int32_t i = 0; i < copy; ++i) {
        out->obs[i].id = msg->id[i];
        out->obs[i].u_left = msg->u_left[i];
        out->obs[i].v_left = msg->v_left[i];
        out->obs[i].u_right = msg->u_right[i];
        out->obs[i].v_right = msg->v_right[i];
    }
    return status;
}

vl_msg_status_t vl_msg_from_stereo_frame(const vl_stereo_frame_t *frame, vislam_stereo_frame_t *out)
{
    if (frame == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    vl_msg_status_t status = VL_MSG_OK;
    uint32_t n = frame->count;
    if (n > VL_MAX_FRAME_FEATURES) {
        n = VL_MAX_FRAME_FEATURES;
    }
    if (n > VISLAM_STEREO_FRAME_T_MAX_FEATURES) {
        n = VISLAM_STEREO_FRAME_T_MAX_FEATURES;
    }
    if (frame->count > n) {
        status = VL_MSG_ERR_COUNT;
    }
    /* Zero the unused tail so encoded messages are reproducible byte for byte. */
    memset(out, 0, sizeof(*out));
    out->utime = frame->utime;
    out->num_features = (int32_t)n;
    for (uint32_t i = 0; i < n; ++i) {
        out->id[i] = frame->obs[i].id;
        out->u_left[i] = frame->obs[i].u_left;
        out->v_left[i] = frame->obs[i].v_left;
        out->u_right[i] = frame->obs[i].u_right;
        out->v_right[i] = frame->obs[i].v_right;
    }
    return status;
}

vl_msg_status_t vl_msg_to_calibration(const vislam_calibration_t *msg, vl_calibration_t *out, int64_t *utime)
{
    if (msg == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->fx = msg->fx;
    out->fy = msg->fy;
    out->cx = msg->cx;
    out->cy = msg->cy;
    out->baseline = msg->baseline;
    memcpy(out->cam_T_imu, msg->cam_T_imu, sizeof(out->cam_T_imu));
    if (utime != NULL) {
        *utime = msg->utime;
    }
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_from_calibration(const vl_calibration_t *calib, int64_t utime, vislam_calibration_t *out)
{
    if (calib == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->utime = utime;
    out->fx = calib->fx;
    out->fy = calib->fy;
    out->cx = calib->cx;
    out->cy = calib->cy;
    out->baseline = calib->baseline;
    memcpy(out->cam_T_imu, calib->cam_T_imu, sizeof(out->cam_T_imu));
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_from_pose(const vl_pose_t *pose, int8_t source, int64_t sequence, vislam_pose_t *out)
{
    if (pose == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->utime = pose->utime;
    out->source = source;
    out->sequence = sequence;
    vl_rotation_to_quaternion(pose->rotation, out->orientation);
    for (int i = 0; i < 3; ++i) {
        out->position[i] = pose->position[i];
        out->linear_velocity[i] = pose->linear_velocity[i];
        out->angular_velocity[i] = pose->angular_velocity[i];
    }
    memcpy(out->covariance, pose->covariance, sizeof(out->covariance));
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_from_pose_bot(const vl_pose_t *pose, bot_core_pose_t *out)
{
    if (pose == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    out->utime = pose->utime;
    vl_rotation_to_quaternion(pose->rotation, out->orientation);
    /* libbot2 defines vel and rotation_rate in the local (world) frame: rotate the body-frame values. */
    const double *R = pose->rotation;
    const double *v = pose->linear_velocity;
    const double *w = pose->angular_velocity;
    for (int i = 0; i < 3; ++i) {
        out->pos[i] = pose->position[i];
        out->vel[i] = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
        out->rotation_rate[i] = R[3 * i] * w[0] + R[3 * i + 1] * w[1] + R[3 * i + 2] * w[2];
        out->accel[i] = 0.0;
    }
    return VL_MSG_OK;
}

/* The covariance's upper triangle, row by row: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2) of the 3x3. */
static const int k_upper[6] = {0, 1, 2, 4, 5, 8};

vl_msg_status_t vl_msg_add_landmark(const vl_landmark_t *landmark, vislam_landmarks_t *batch)
{
    if (landmark == NULL || batch == NULL) {
        return VL_MSG_ERR_NULL;
    }
    if (batch->count < 0 || batch->count >= VISLAM_LANDMARKS_T_MAX_LANDMARKS) {
        return VL_MSG_ERR_COUNT;
    }
    const int32_t i = batch->count++;
    batch->id[i] = landmark->id;
    for (int k = 0; k < 3; ++k) {
        batch->position[i][k] = landmark->position[k];
    }
    for (int k = 0; k < 6; ++k) {
        batch->covariance[i][k] = landmark->covariance[k_upper[k]];
    }
    batch->observations[i] = (int32_t)landmark->observations;
    batch->first_utime[i] = landmark->first_utime;
    batch->last_utime[i] = landmark->last_utime;
    return VL_MSG_OK;
}

vl_msg_status_t vl_msg_to_landmark(const vislam_landmarks_t *batch, int32_t index, vl_landmark_t *out)
{
    if (batch == NULL || out == NULL) {
        return VL_MSG_ERR_NULL;
    }
    if (batch->count < 0 || batch->count > VISLAM_LANDMARKS_T_MAX_LANDMARKS || index < 0 || index >= batch->count) {
        return VL_MSG_ERR_COUNT;
    }
    out->id = batch->id[index];
    for (int k = 0; k < 3; ++k) {
        out->position[k] = batch->position[index][k];
    }
    for (int k = 0; k < 6; ++k) {
        const int rc = k_upper[k]; /* (r, c) = (rc / 3, rc % 3), and its mirror (c, r) */
        out->covariance[rc] = batch->covariance[index][k];
        out->covariance[3 * (rc % 3) + rc / 3] = batch->covariance[index][k];
    }
    out->observations = (uint32_t)batch->observations[index];
    out->first_utime = batch->first_utime[index];
    out->last_utime = batch->last_utime[index];
    return VL_MSG_OK;
}

int vl_calibration_equal(const vl_calibration_t *a, const vl_calibration_t *b)
{
    if (a->fx != b->fx || a->fy != b->fy || a->cx != b->cx || a->cy != b->cy || a->baseline != b->baseline) {
        return 0;
    }
    for (int i = 0; i < 16; ++i) {
        if (a->cam_T_imu[i] != b->cam_T_imu[i]) {
            return 0;
        }
    }
    return 1;
}

int vl_msg_decoded_whole(int used, int len)
{
    return used >= 0 && used == len;
}
