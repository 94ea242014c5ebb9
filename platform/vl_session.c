/* The session between input events and the core: calibration policy, counters, health, logger, outputs. */
#include "vl_session.h"

#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "vl_msg.h"

static const vl_counters_t g_zero_counters;

static const char *program(const vl_session_t *s)
{
    return s->opt.program != NULL ? s->opt.program : "vislam";
}

/* ---- core logger: one copy for every program, rate limited by count ---- */

static const char *level_name(vl_log_level_t level)
{
    switch (level) {
    case VL_LOG_DEBUG:
        return "debug";
    case VL_LOG_INFO:
        return "info";
    case VL_LOG_WARN:
        return "warning";
    case VL_LOG_ERROR:
        return "error";
    }
    return "?";
}

/* By count, not by wall time: what is printed then depends on the inputs only, offline or live,
   and a flood costs at most one line in VL_SESSION_LOG_EVERY. */
static void core_log(void *user, vl_log_level_t level, int64_t utime, const char *message)
{
    vl_session_t *s = (vl_session_t *)user;
    if (level < VL_LOG_WARN || (s->opt.quiet && level < VL_LOG_ERROR)) {
        return;
    }
    const uint64_t n = ++s->log_seen[(int)level & 3];
    if (n > VL_SESSION_LOG_BURST && n % VL_SESSION_LOG_EVERY != 0) {
        s->log_suppressed++;
        return;
    }
    fprintf(stderr, "%s: core %s at utime %" PRId64 ": %s%s\n", program(s), level_name(level), utime,
            message != NULL ? message : "", n > VL_SESSION_LOG_BURST ? " (rate limited)" : "");
}

static void landmark_sink(void *user, const vl_landmark_t *lm)
{
    const vl_session_t *s = (const vl_session_t *)user;
    if (s->opt.callbacks.on_landmark != NULL) {
        s->opt.callbacks.on_landmark(s->opt.callbacks.user, lm);
    }
}

vl_status_t vl_session_init(vl_session_t *s, vl_estimator_t *est, const vl_config_t *cfg,
                            const vl_session_options_t *opt)
{
    if (s == NULL || est == NULL || cfg == NULL || opt == NULL) {
        return VL_ERR_NULL;
    }
    memset(s, 0, sizeof(*s));
    s->est = est;
    s->cfg = *cfg;
    s->opt = *opt;
    s->cfg.landmark_sink = landmark_sink;
    s->cfg.landmark_sink_user = s;
    s->cfg.log = core_log;
    s->cfg.log_user = s;
    if (opt->worker != NULL) {
        s->cfg.parallel_for = vl_worker_parallel_for;
        s->cfg.parallel_ctx = opt->worker;
    }
    s->calib_source = "none";
    if (opt->config_has_calibration) {
        const vl_status_t st = vl_init(est, &s->cfg);
        if (st != VL_OK) {
            return st;
        }
        s->initialized = 1;
        s->calib_source = "config";
    }
    return VL_OK;
}

/* ---- calibration policy ---- */

static void on_calibration(vl_session_t *s, const vl_calibration_t *calib, int64_t utime)
{
    if (s->opt.override_log) {
        s->n.calibrations_ignored++;
        return;
    }
    if (s->initialized && vl_calibration_equal(&s->cfg.calibration, calib)) {
        /* Nothing to redo; the first one still counts as the rig's source. */
        if (strcmp(s->calib_source, "log") != 0) {
            s->calib_source = "log";
            s->n.calibrations_used++;
        } else {
            s->n.calibrations_ignored++;
        }
        return;
    }
    if (s->inputs_fed) {
        if (s->n.calibrations_changed++ == 0) {
            fprintf(stderr, "%s: warning: calibration changed after inputs (utime %" PRId64 "); ignored\n", program(s),
                    utime);
        }
        return;
    }
    vl_config_t candidate = s->cfg;
    candidate.calibration = *calib;
    if (vl_config_check(&candidate) != VL_OK || vl_init(s->est, &candidate) != VL_OK) {
        if (s->n.calibrations_invalid++ == 0) {
            fprintf(stderr, "%s: warning: calibration message (utime %" PRId64 ") rejected by vl_config_check\n",
                    program(s), utime);
        }
        return;
    }
    s->cfg = candidate;
    s->initialized = 1;
    s->calib_source = "log";
    s->n.calibrations_used++;
    if (s->opt.callbacks.on_event != NULL) {
        s->opt.callbacks.on_event(s->opt.callbacks.user, VL_SESSION_EVENT_CALIBRATED, utime);
    }
}

/* ---- inputs ---- */

static void count_status(uint64_t *slots, vl_status_t status)
{
    int v = (int)status;
    if (v < (int)VL_STATUS_MIN || v > (int)VL_STATUS_MAX) {
        v = (int)VL_STATUS_MIN; /* an unknown status: keep the count rather than drop it */
    }
    slots[v - (int)VL_STATUS_MIN]++;
}

static void note_reinitialized(vl_session_t *s, int64_t utime)
{
    s->n.reinitializations++;
    if (!s->opt.quiet) {
        const vl_counters_t *c = vl_get_counters(s->est);
        fprintf(stderr,
                "%s: estimator re-initialized at utime %" PRId64 " (%" PRIu64 " timeline change(s), %" PRIu64
                " divergence reset(s) in all)\n",
                program(s), utime, c->timeline_changes, c->divergence_resets);
    }
    if (s->opt.callbacks.on_event != NULL) {
        s->opt.callbacks.on_event(s->opt.callbacks.user, VL_SESSION_EVENT_REINITIALIZED, utime);
    }
}

/* After a core call: counts, the re-initialization event, then the pose. */
static void after_step(vl_session_t *s, vl_session_step_t step, vl_status_t st, int64_t utime)
{
    const int update = step == VL_SESSION_STEP_UPDATE;
    count_status(update ? s->update_status : s->propagate_status, st);
    if (st < 0) {
        if (update) {
            s->n.frames_rejected++;
        } else {
            s->n.imu_rejected++;
        }
        if (st == VL_ERR_TIME_ORDER || st == VL_ERR_TIME_JUMP) {
            s->n.time_refused++;
        }
        return;
    }
    if (update) {
        s->n.frames_used++;
    } else {
        s->n.imu_used++;
    }
    s->last_input_utime = utime;
    if (st == VL_RESET) {
        note_reinitialized(s, utime);
    }
    if (vl_get_pose(s->est, &s->pose) != VL_OK) {
        s->n.poses_withheld++;
        return;
    }
    if (step == VL_SESSION_STEP_UPDATE) {
        s->innovation_nis += s->pose.innovation_ratio * (double)s->pose.innovation_rows;
        s->innovation_rows += s->pose.innovation_rows;
    }
    const uint64_t sequence = s->n.poses_out++;
    if (s->opt.callbacks.on_pose != NULL) {
        s->opt.callbacks.on_pose(s->opt.callbacks.user, step, utime, sequence, &s->pose);
    }
}

static void count_received(vl_session_t *s, vl_log_event_kind_t kind)
{
    switch (kind) {
    case VL_LOG_EVENT_IMU:
        s->n.imu_in++;
        break;
    case VL_LOG_EVENT_FRAME:
        s->n.frames_in++;
        break;
    case VL_LOG_EVENT_CALIBRATION:
        s->n.calibrations_in++;
        break;
    default:
        break;
    }
}

vl_session_step_t vl_session_input(vl_session_t *s, const vl_log_event_t *ev, vl_status_t *status)
{
    vl_status_t st = VL_OK;
    vl_session_step_t step = VL_SESSION_STEP_NONE;
    if (status != NULL) {
        *status = VL_OK;
    }
    if (s == NULL || ev == NULL) {
        return step;
    }
    switch (ev->kind) {
    case VL_LOG_EVENT_CALIBRATION:
        count_received(s, ev->kind);
        on_calibration(s, &ev->calibration, ev->calibration_utime);
        break;
    case VL_LOG_EVENT_IMU:
        count_received(s, ev->kind);
        if (!s->initialized) {
            s->n.imu_waiting++;
            break;
        }
        s->inputs_fed = 1;
        st = vl_propagate(s->est, &ev->imu);
        step = VL_SESSION_STEP_PROPAGATE;
        after_step(s, step, st, ev->imu.utime);
        break;
    case VL_LOG_EVENT_FRAME:
        count_received(s, ev->kind);
        if (!s->initialized) {
            if (s->n.frames_waiting++ == 0) {
                fprintf(stderr, "%s: frame at utime %" PRId64 " before any calibration; refused (counted)\n",
                        program(s), ev->frame.utime);
            }
            break;
        }
        s->inputs_fed = 1;
        st = vl_update(s->est, &ev->frame);
        step = VL_SESSION_STEP_UPDATE;
        after_step(s, step, st, ev->frame.utime);
        break;
    case VL_LOG_EVENT_DECODE_ERROR:
        count_received(s, ev->decode_kind);
        s->n.decode_errors++;
        break;
    case VL_LOG_EVENT_CORRUPT:
    case VL_LOG_EVENT_END:
        break;
    }
    if (status != NULL) {
        *status = st;
    }
    return step;
}

vl_status_t vl_session_finish(vl_session_t *s)
{
    if (s == NULL || !s->initialized) {
        return VL_OK;
    }
    const vl_status_t st = vl_update_deferred(s->est);
    if (st == VL_RESET) {
        note_reinitialized(s, s->last_input_utime);
    }
    return st;
}

void vl_session_flush(vl_session_t *s)
{
    if (s != NULL && s->initialized) {
        vl_flush_landmarks(s->est);
    }
}

/* ---- health and status ---- */

static uint64_t rejected_total(const vl_session_counters_t *n)
{
    return n->decode_errors + n->imu_waiting + n->frames_waiting + n->imu_rejected + n->frames_rejected;
}

int32_t vl_session_health(const vl_session_t *s)
{
    const vl_counters_t *c = vl_session_core_counters(s);
    const vl_counters_t *was = &s->core_at_mark;
    const vl_session_counters_t *n = &s->n;
    const vl_session_counters_t *at = &s->n_at_mark;
    int32_t h = VISLAM_STATUS_T_HEALTH_OK;
    if (!s->initialized) {
        h |= VISLAM_STATUS_T_HEALTH_WAITING_CALIBRATION;
    }
    if (c->numerical_failures != was->numerical_failures) {
        h |= VISLAM_STATUS_T_HEALTH_NUMERICAL_FAILURE;
    }
    if (rejected_total(n) != rejected_total(at)) {
        h |= VISLAM_STATUS_T_HEALTH_INPUT_REJECTED;
    }
    if (n->time_refused != at->time_refused) {
        h |= VISLAM_STATUS_T_HEALTH_TIME_REFUSED;
    }
    if (c->timeline_changes != was->timeline_changes) {
        h |= VISLAM_STATUS_T_HEALTH_TIMELINE_CHANGE;
    }
    if (c->imu_implausible != was->imu_implausible || c->observations_implausible != was->observations_implausible) {
        h |= VISLAM_STATUS_T_HEALTH_IMPLAUSIBLE_INPUT;
    }
    if (c->divergence_resets != was->divergence_resets) {
        h |= VISLAM_STATUS_T_HEALTH_DIVERGENCE_RESET;
    }
    const uint32_t state = s->initialized ? vl_get_state_flags(s->est) : 0u;
    if ((state & VL_STATE_IMU_SILENT) || c->frames_imu_silent != was->frames_imu_silent) {
        h |= VISLAM_STATUS_T_HEALTH_IMU_SILENT;
    }
    const uint64_t inputs = n->imu_in + n->frames_in;
    const uint64_t used = n->imu_used + n->frames_used;
    if (s->initialized && ((state & VL_STATE_NO_CLOCK) ||
                           (inputs != at->imu_in + at->frames_in && used == at->imu_used + at->frames_used))) {
        h |= VISLAM_STATUS_T_HEALTH_NOT_TRACKING;
    }
    return h;
}

void vl_session_fill_status(const vl_session_t *s, vislam_status_t *out)
{
    const vl_counters_t *c = vl_session_core_counters(s);
    out->last_input_utime = s->last_input_utime;
    out->health = vl_session_health(s);
    out->imu_in = (int64_t)s->n.imu_in;
    out->frames_in = (int64_t)s->n.frames_in;
    out->poses_out = (int64_t)s->n.poses_out;
    out->inputs_rejected = (int64_t)rejected_total(&s->n);
    out->observations_gated = (int64_t)c->observations_gated;
    out->window_landmarks = s->initialized ? (int32_t)vl_window_size(s->est) : 0;
    out->window_capacity = (int32_t)s->cfg.max_landmarks;
    out->landmarks_mapped = (int64_t)c->landmarks_marginalized;
    vl_pose_t pose;
    const int have_pose = s->initialized && vl_get_pose(s->est, &pose) == VL_OK;
    out->linear_velocity_noise = have_pose ? pose.linear_velocity_noise : s->cfg.linear_velocity_noise;
    out->angular_velocity_noise = have_pose ? pose.angular_velocity_noise : s->cfg.angular_velocity_noise;
    out->pixel_noise = have_pose ? pose.pixel_noise : s->cfg.pixel_noise;
    out->innovation_ratio = vl_session_innovation_ratio(s, 1);
    const double sensor[3] = {s->cfg.velocity_sensor_x, s->cfg.velocity_sensor_y, s->cfg.velocity_sensor_z};
    for (int i = 0; i < 3; ++i) {
        out->linear_offset[i] = have_pose ? pose.linear_offset[i] : 0.0;
        out->angular_offset[i] = have_pose ? pose.angular_offset[i] : 0.0;
        out->velocity_sensor[i] = have_pose ? pose.velocity_sensor[i] : sensor[i];
    }
    out->frames_repeated = (int64_t)c->frames_repeated;
    out->time_jumps = (int64_t)c->time_jumps;
    out->timeline_changes = (int64_t)c->timeline_changes;
    out->divergence_resets = (int64_t)c->divergence_resets;
    out->resets = (int64_t)c->resets;
    out->imu_implausible = (int64_t)c->imu_implausible;
    out->observations_implausible = (int64_t)c->observations_implausible;
    out->frames_imu_silent = (int64_t)c->frames_imu_silent;
}

void vl_session_mark(vl_session_t *s)
{
    s->n_at_mark = s->n;
    s->core_at_mark = *vl_session_core_counters(s);
    s->innovation_nis_at_mark = s->innovation_nis;
    s->innovation_rows_at_mark = s->innovation_rows;
}

double vl_session_innovation_ratio(const vl_session_t *s, int since_mark)
{
    const double nis = s->innovation_nis - (since_mark ? s->innovation_nis_at_mark : 0.0);
    const uint64_t rows = s->innovation_rows - (since_mark ? s->innovation_rows_at_mark : 0u);
    return rows > 0 ? nis / (double)rows : 0.0;
}

/* ---- queries ---- */

const vl_session_counters_t *vl_session_counters(const vl_session_t *s)
{
    return &s->n;
}

size_t vl_session_counter_list(const vl_session_t *s, vl_counter_entry_t out[VL_SESSION_NUM_COUNTERS])
{
    size_t i = 0;
#define VL_SESSION_COUNTER_ENTRY(name_, meaning) \
    out[i].name = #name_;                        \
    out[i].value = s->n.name_;                   \
    ++i;
    VL_SESSION_COUNTERS(VL_SESSION_COUNTER_ENTRY)
#undef VL_SESSION_COUNTER_ENTRY
    return i;
}

const vl_counters_t *vl_session_core_counters(const vl_session_t *s)
{
    return s->initialized ? vl_get_counters(s->est) : &g_zero_counters;
}

uint64_t vl_session_status_count(const vl_session_t *s, int update, vl_status_t status)
{
    const int v = (int)status;
    if (v < (int)VL_STATUS_MIN || v > (int)VL_STATUS_MAX) {
        return 0;
    }
    return (update ? s->update_status : s->propagate_status)[v - (int)VL_STATUS_MIN];
}

int vl_session_initialized(const vl_session_t *s)
{
    return s->initialized;
}

const char *vl_session_calibration_source(const vl_session_t *s)
{
    return s->calib_source;
}

const vl_config_t *vl_session_config(const vl_session_t *s)
{
    return &s->cfg;
}

const vl_estimator_t *vl_session_estimator(const vl_session_t *s)
{
    return s->initialized ? s->est : NULL;
}

int64_t vl_session_last_input_utime(const vl_session_t *s)
{
    return s->last_input_utime;
}

uint64_t vl_session_log_suppressed(const vl_session_t *s)
{
    return s->log_suppressed;
}
