/* LCM event log reader: decodes vislam messages into core types. */
#include "vl_log_reader.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

#include <lcm/eventlog.h>

#include "vl_msg.h"

void vl_log_channels_default(vl_log_channels_t *channels)
{
    if (channels == NULL) {
        return;
    }
    channels->imu = VL_CHANNEL_IMU;
    channels->features = VL_CHANNEL_FEATURES;
    channels->calibration = VL_CHANNEL_CALIBRATION;
}

static int copy_channel(char dst[VL_LOG_CHANNEL_MAX], const char *src, const char *fallback)
{
    if (src == NULL || src[0] == '\0') {
        src = fallback;
    }
    size_t n = strlen(src);
    if (n >= VL_LOG_CHANNEL_MAX) {
        return -1;
    }
    memcpy(dst, src, n + 1);
    return 0;
}

int vl_log_reader_open(vl_log_reader_t *r, const char *path, const vl_log_channels_t *channels, char *err,
                       size_t err_len)
{
    if (r == NULL || path == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "vl_log_reader_open: NULL argument");
        }
        return -1;
    }
    memset(r, 0, sizeof(*r));
    vl_log_channels_t def;
    vl_log_channels_default(&def);
    const vl_log_channels_t *ch = channels != NULL ? channels : &def;
    if (copy_channel(r->imu_channel, ch->imu, def.imu) != 0 ||
        copy_channel(r->features_channel, ch->features, def.features) != 0 ||
        copy_channel(r->calibration_channel, ch->calibration, def.calibration) != 0) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "channel name longer than %d characters", VL_LOG_CHANNEL_MAX - 1);
        }
        return -1;
    }

    errno = 0;
    lcm_eventlog_t *log = lcm_eventlog_create(path, "r");
    if (log == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "%s: cannot open log: %s", path, errno != 0 ? strerror(errno) : "unknown error");
        }
        return -1;
    }
    if (vl_log_guard_init(&r->guard, log->f) != 0) {
        lcm_eventlog_destroy(log);
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "%s: cannot seek (the log must be a regular file): %s", path, strerror(errno));
        }
        return -1;
    }
    r->log = log;
    return 0;
}

/* A payload must be exactly one message: a short read or leftover bytes both mean corruption. */
static int check_decoded(int used, int len, const char *type, vl_log_event_t *ev)
{
    if (vl_msg_decoded_whole(used, len)) {
        return 1;
    }
    if (used < 0) {
        snprintf(ev->error, sizeof(ev->error), "%s event %lld: %d-byte payload is not a valid %s (size or hash)",
                 ev->channel, (long long)ev->event_number, len, type);
        return 0;
    }
    if (used != len) {
        snprintf(ev->error, sizeof(ev->error), "%s event %lld: %d trailing bytes after %s", ev->channel,
                 (long long)ev->event_number, len - used, type);
        return 0;
    }
    return 1;
}

vl_log_event_kind_t vl_log_event_decode(vl_log_decoder_t *d, vl_log_event_kind_t kind, const void *data, int len,
                                        vl_log_event_t *ev)
{
    int ok = 0;
    ev->error[0] = '\0';
    switch (kind) {
    case VL_LOG_EVENT_IMU:
        ok = check_decoded(vislam_imu_t_decode(data, 0, len, &d->imu), len, "vislam.imu_t", ev);
        if (ok) {
            vl_msg_to_imu(&d->imu, &ev->imu);
        }
        break;
    case VL_LOG_EVENT_FRAME:
        ok = check_decoded(vislam_stereo_frame_t_decode(data, 0, len, &d->frame), len, "vislam.stereo_frame_t", ev);
        if (ok && vl_msg_to_stereo_frame(&d->frame, &ev->frame) != VL_MSG_OK) {
            snprintf(ev->error, sizeof(ev->error), "%s event %lld: num_features %d outside 0..%d", ev->channel,
                     (long long)ev->event_number, (int)d->frame.num_features, VISLAM_STEREO_FRAME_T_MAX_FEATURES);
            ok = 0;
        }
        break;
    case VL_LOG_EVENT_CALIBRATION:
        ok = check_decoded(vislam_calibration_t_decode(data, 0, len, &d->calibration), len, "vislam.calibration_t", ev);
        if (ok) {
            vl_msg_to_calibration(&d->calibration, &ev->calibration, &ev->calibration_utime);
        }
        break;
    default:
        snprintf(ev->error, sizeof(ev->error), "%s event %lld: not an input channel", ev->channel,
                 (long long)ev->event_number);
        break;
    }
    ev->decode_kind = kind;
    ev->kind = ok ? kind : VL_LOG_EVENT_DECODE_ERROR;
    return ev->kind;
}

vl_log_event_kind_t vl_log_reader_next(vl_log_reader_t *r, vl_log_event_t *ev)
{
    if (r == NULL || ev == NULL) {
        return VL_LOG_EVENT_END;
    }
    ev->kind = VL_LOG_EVENT_END;
    ev->error[0] = '\0';
    if (r->log == NULL || r->ended) {
        return VL_LOG_EVENT_END;
    }
    lcm_eventlog_t *log = (lcm_eventlog_t *)r->log;

    for (;;) {
        /* liblcm trusts the lengths it reads (an absurd one crashes it): the guard checks first. */
        const vl_log_guard_result_t g = vl_log_guard_next(&r->guard, log->f);
        if (g == VL_LOG_GUARD_DAMAGED) {
            r->stats.corrupt = r->guard.damaged;
            r->stats.bytes_skipped = r->guard.bytes_skipped;
            snprintf(ev->error, sizeof(ev->error), "%s", r->guard.error);
            ev->channel[0] = '\0';
            ev->kind = VL_LOG_EVENT_CORRUPT;
            return VL_LOG_EVENT_CORRUPT;
        }
        lcm_eventlog_event_t *le = g == VL_LOG_GUARD_EVENT ? lcm_eventlog_read_next_event(log) : NULL;
        if (le == NULL) {
            /* A checked event that liblcm still cannot read means the file changed under us. */
            if (g == VL_LOG_GUARD_EVENT) {
                r->guard.failed = 1;
            }
            r->ended = 1;
            return VL_LOG_EVENT_END;
        }
        r->stats.events++;
        ev->event_number = le->eventnum;
        ev->log_utime = le->timestamp;
        snprintf(ev->channel, sizeof(ev->channel), "%s", le->channel);

        vl_log_event_kind_t kind;
        if (strcmp(le->channel, r->imu_channel) == 0) {
            kind = VL_LOG_EVENT_IMU;
        } else if (strcmp(le->channel, r->features_channel) == 0) {
            kind = VL_LOG_EVENT_FRAME;
        } else if (strcmp(le->channel, r->calibration_channel) == 0) {
            kind = VL_LOG_EVENT_CALIBRATION;
        } else {
            r->stats.skipped++;
            lcm_eventlog_free_event(le);
            continue;
        }
        kind = vl_log_event_decode(&r->decoder, kind, le->data, le->datalen, ev);
        lcm_eventlog_free_event(le);
        switch (kind) {
        case VL_LOG_EVENT_IMU:
            r->stats.imu++;
            break;
        case VL_LOG_EVENT_FRAME:
            r->stats.frames++;
            break;
        case VL_LOG_EVENT_CALIBRATION:
            r->stats.calibrations++;
            break;
        default:
            r->stats.decode_errors++;
            break;
        }
        return kind;
    }
}

const vl_log_reader_stats_t *vl_log_reader_stats(const vl_log_reader_t *r)
{
    return r != NULL ? &r->stats : NULL;
}

int vl_log_reader_truncated(const vl_log_reader_t *r)
{
    return r != NULL && (r->guard.truncated || r->guard.failed);
}

void vl_log_reader_close(vl_log_reader_t *r)
{
    if (r == NULL) {
        return;
    }
    if (r->log != NULL) {
        lcm_eventlog_destroy((lcm_eventlog_t *)r->log);
        r->log = NULL;
    }
    r->ended = 1;
}
