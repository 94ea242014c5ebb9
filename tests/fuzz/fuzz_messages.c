/*
 * Fuzz harness: LCM message decoding, conversion to core inputs and the core's input API,
 * driven as vislamd drives them.
 *
 * An input is a configuration byte and a sequence of (channel, payload) records (vl_fuzz.h).
 * Each payload goes through the generated LCM decoder of its channel into static storage
 * (the types are fixed-size), must decode to exactly its length (vislamd's rule), is
 * converted by platform/vl_msg, and then:
 *   - a calibration (re)initializes the estimator while no input has reached it, is ignored
 *     when equal to the one in use, and is ignored when different after inputs (vislamd's
 *     apply_calibration; vl_config_check refuses bad ones);
 *   - an IMU sample goes to vl_propagate, a frame to vl_update, once calibrated; before that
 *     both are dropped, as vislamd does.
 * After every step the published pose is read with vl_get_pose; when it returns VL_OK, a
 * non-finite position, rotation, covariance, velocity or quaternion aborts the run
 * (__builtin_trap), as a pose vislamd would put on the wire. VL_FUZZ_CHECK_FINITE=0 in the
 * environment turns that check off (on by default), so the decoders and the API's own
 * crash-freedom can still be fuzzed while a known finiteness bug is open.
 * At the end the window is flushed into a sink, as vislam-run does at the end of a log.
 * VL_FUZZ_VERBOSE=1 prints, per input, what reached the estimator (to check that seeds do).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vislam/vislam.h"
#include "vl_fuzz.h"
#include "vl_msg.h"

/* Static, as in vislamd: 3.7 MB, 64-byte aligned by its type. */
static vl_estimator_t g_est;
static vislam_imu_t g_imu_msg;
static vislam_stereo_frame_t g_frame_msg;
static vislam_calibration_t g_calib_msg;
static vislam_pose_t g_pose_msg;
static vl_imu_sample_t g_imu;
static vl_stereo_frame_t g_frame;

/* vislamd's calibration state for one input. */
typedef struct {
    vl_config_t cfg;
    int initialized;
    int inputs_fed;
} vl_fuzz_daemon_t;

static int vl_fuzz_check_finite_enabled(void)
{
    static int enabled = -1;
    if (enabled < 0) {
        const char *env = getenv("VL_FUZZ_CHECK_FINITE");
        enabled = !(env != NULL && strcmp(env, "0") == 0);
    }
    return enabled;
}

static void vl_fuzz_config(uint8_t selector, vl_config_t *cfg)
{
    static const uint32_t windows[4] = {0, 16, 4, 1};
    if (selector & VL_FUZZ_CFG_PRESET_SEED) {
        vl_config_preset_seed(cfg);
    } else {
        vl_config_default(cfg);
    }
    switch (selector & VL_FUZZ_CFG_MODE_MASK) {
    case 1:
        cfg->mode = VL_MODE_MAPPING;
        break;
    case 2:
        cfg->mode = VL_MODE_IMU_ONLY;
        break;
    default:
        cfg->mode = VL_MODE_SLAM;
        break;
    }
    if (selector & VL_FUZZ_CFG_ADAPTIVE) {
        cfg->adaptive_noise = 1;
    }
    const uint32_t window = windows[(selector & VL_FUZZ_CFG_WINDOW_MASK) >> 4];
    if (window != 0 && window < cfg->max_landmarks) {
        cfg->max_landmarks = window;
    }
    if (selector & VL_FUZZ_CFG_NO_OFFSETS) {
        cfg->estimate_input_offsets = 0;
    }
    if (selector & VL_FUZZ_CFG_NO_OUTLIERS) {
        cfg->gate_chi2 = 0.0;
    }
}

static void vl_fuzz_require_finite(const double *v, int n, const char *what, const char *step)
{
    for (int i = 0; i < n; ++i) {
        if (!isfinite(v[i])) {
            fprintf(stderr, "fuzz_messages: vl_get_pose returned VL_OK with a non-finite %s[%d] = %g after %s\n", what,
                    i, v[i], step);
            __builtin_trap();
        }
    }
}

/* What vislamd would publish after a step: the pose and its message must be finite. */
static void vl_fuzz_check_pose(const char *step)
{
    vl_pose_t pose;
    if (vl_get_pose(&g_est, &pose) != VL_OK || !vl_fuzz_check_finite_enabled()) {
        return;
    }
    vl_fuzz_require_finite(pose.position, 3, "position", step);
    vl_fuzz_require_finite(pose.rotation, 9, "rotation", step);
    vl_fuzz_require_finite(pose.covariance, 36, "covariance", step);
    vl_fuzz_require_finite(pose.linear_velocity, 3, "linear_velocity", step);
    vl_fuzz_require_finite(pose.angular_velocity, 3, "angular_velocity", step);
    vl_msg_from_pose(&pose, VISLAM_POSE_T_SOURCE_FEATURES, 0, &g_pose_msg);
    vl_fuzz_require_finite(g_pose_msg.orientation, 4, "orientation", step);
}

static int vl_fuzz_decoded_ok(int used, size_t len)
{
    return used >= 0 && (size_t)used == len;
}

static void vl_fuzz_on_calibration(vl_fuzz_daemon_t *d, const uint8_t *payload, size_t len)
{
    if (!vl_fuzz_decoded_ok(vislam_calibration_t_decode(payload, 0, (int)len, &g_calib_msg), len)) {
        return;
    }
    vl_calibration_t calib;
    if (vl_msg_to_calibration(&g_calib_msg, &calib, NULL) != VL_MSG_OK) {
        __builtin_trap(); /* only NULL arguments may fail */
    }
    if (d->initialized && vl_calibration_equal(&d->cfg.calibration, &calib)) {
        return;
    }
    if (d->inputs_fed) {
        return;
    }
    vl_config_t candidate = d->cfg;
    candidate.calibration = calib;
    if (vl_config_check(&candidate) != VL_OK || vl_init(&g_est, &candidate) != VL_OK) {
        return;
    }
    d->cfg = candidate;
    d->initialized = 1;
    vl_fuzz_check_pose("vl_init");
}

static void vl_fuzz_on_imu(vl_fuzz_daemon_t *d, const uint8_t *payload, size_t len)
{
    if (!vl_fuzz_decoded_ok(vislam_imu_t_decode(payload, 0, (int)len, &g_imu_msg), len) || !d->initialized) {
        return;
    }
    vl_msg_to_imu(&g_imu_msg, &g_imu);
    d->inputs_fed = 1;
    (void)vl_propagate(&g_est, &g_imu);
    vl_fuzz_check_pose("vl_propagate");
}

static void vl_fuzz_on_features(vl_fuzz_daemon_t *d, const uint8_t *payload, size_t len)
{
    if (!vl_fuzz_decoded_ok(vislam_stereo_frame_t_decode(payload, 0, (int)len, &g_frame_msg), len) ||
        vl_msg_to_stereo_frame(&g_frame_msg, &g_frame) != VL_MSG_OK || !d->initialized) {
        return;
    }
    d->inputs_fed = 1;
    (void)vl_update(&g_est, &g_frame);
    vl_fuzz_check_pose("vl_update");
    (void)vl_update_deferred(&g_est);
    vl_fuzz_check_pose("vl_update_deferred");
}

static void vl_fuzz_sink(void *user, const vl_landmark_t *landmark)
{
    (void)landmark;
    ++*(uint64_t *)user;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size == 0) {
        return 0;
    }
    static uint64_t mapped;
    mapped = 0;
    vl_fuzz_daemon_t d;
    memset(&d, 0, sizeof(d));
    vl_fuzz_config(data[0], &d.cfg);
    d.cfg.landmark_sink = vl_fuzz_sink;
    d.cfg.landmark_sink_user = &mapped;

    size_t pos = 1;
    while (size - pos >= VL_FUZZ_RECORD_HEADER) {
        const uint8_t selector = data[pos];
        size_t len = (size_t)data[pos + 1] | ((size_t)data[pos + 2] << 8);
        pos += VL_FUZZ_RECORD_HEADER;
        if (len > size - pos) {
            len = size - pos;
        }
        const uint8_t *payload = data + pos;
        pos += len;
        switch (selector % VL_FUZZ_NUM_CHANNELS) {
        case VL_FUZZ_CH_IMU:
            vl_fuzz_on_imu(&d, payload, len);
            break;
        case VL_FUZZ_CH_FEATURES:
            vl_fuzz_on_features(&d, payload, len);
            break;
        default:
            vl_fuzz_on_calibration(&d, payload, len);
            break;
        }
    }
    if (d.initialized) {
        (void)vl_flush_landmarks(&g_est);
        vl_fuzz_check_pose("vl_flush_landmarks");
    }
    const char *verbose = getenv("VL_FUZZ_VERBOSE");
    if (verbose != NULL && strcmp(verbose, "1") == 0) {
        const vl_counters_t *c = vl_get_counters(&g_est);
        printf("  %s: imu %llu/%llu frames %llu/%llu observations used %llu, landmarks mapped %llu\n",
               d.initialized ? "estimated" : "never calibrated",
               d.initialized ? (unsigned long long)c->imu_accepted : 0ULL,
               d.initialized ? (unsigned long long)c->imu_rejected : 0ULL,
               d.initialized ? (unsigned long long)c->frames_accepted : 0ULL,
               d.initialized ? (unsigned long long)c->frames_rejected : 0ULL,
               d.initialized ? (unsigned long long)c->observations_used : 0ULL, (unsigned long long)mapped);
    }
    return 0;
}
