/**
 * @file vl_log_reader.h
 * @brief Reads an LCM event log and decodes vislam messages into core types.
 *
 * Events come back one at a time in log order. A payload that fails to decode
 * is reported as VL_LOG_EVENT_DECODE_ERROR and counted, and reading goes on
 * with the next event; events on other channels are skipped and counted.
 * Every event header is checked before liblcm reads the event (vl_log_guard):
 * a damaged spot (bad sync word, absurd or cut lengths, junk) is reported as
 * VL_LOG_EVENT_CORRUPT with its file offset, counted, and reading resumes at
 * the next valid event; a log cut inside an event is reported as truncated.
 * Decoding uses fixed-size storage inside the reader (the message types have
 * fixed-size arrays), so no allocation happens per event beyond LCM's own
 * event buffer.
 */
#ifndef VISLAM_PLATFORM_VL_LOG_READER_H
#define VISLAM_PLATFORM_VL_LOG_READER_H

#include <stddef.h>
#include <stdint.h>

#include "vislam/vislam.h"
#include "vl_channels.h"
#include "vl_log_guard.h"

#include "vislam_calibration_t.h"
#include "vislam_imu_t.h"
#include "vislam_stereo_frame_t.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Longest channel name the reader stores, terminator included. */
#define VL_LOG_CHANNEL_MAX 64

/** Channels the reader decodes; NULL or empty members take the defaults. */
typedef struct {
    const char *imu;         /**< vislam.imu_t */
    const char *features;    /**< vislam.stereo_frame_t */
    const char *calibration; /**< vislam.calibration_t */
} vl_log_channels_t;

/** What vl_log_reader_next produced. */
typedef enum {
    VL_LOG_EVENT_END = 0,          /**< No more events (end of file or an unreadable tail, see truncated). */
    VL_LOG_EVENT_IMU = 1,          /**< ev->imu is valid. */
    VL_LOG_EVENT_FRAME = 2,        /**< ev->frame is valid. */
    VL_LOG_EVENT_CALIBRATION = 3,  /**< ev->calibration and ev->calibration_utime are valid. */
    VL_LOG_EVENT_DECODE_ERROR = 4, /**< A payload on a known channel did not decode; ev->error says why. */
    VL_LOG_EVENT_CORRUPT = 5       /**< Bytes that are not a valid event (ev->error: file offset and what);
                                        the next call resumes at the next valid event. */
} vl_log_event_kind_t;

/** One decoded event. Large (holds a full frame): keep it static or on the heap. */
typedef struct {
    vl_log_event_kind_t kind;
    int64_t event_number;             /**< LCM event number in the log */
    int64_t log_utime;                /**< us, time the logger received the event */
    char channel[VL_LOG_CHANNEL_MAX]; /**< channel name (truncated if longer) */
    vl_imu_sample_t imu;              /**< kind == VL_LOG_EVENT_IMU */
    vl_stereo_frame_t frame;          /**< kind == VL_LOG_EVENT_FRAME */
    vl_calibration_t calibration;     /**< kind == VL_LOG_EVENT_CALIBRATION */
    int64_t calibration_utime;        /**< us, stamp of the calibration message */
    char error[256];                  /**< kind == VL_LOG_EVENT_DECODE_ERROR or _CORRUPT: what went wrong */
    vl_log_event_kind_t decode_kind;  /**< kind == VL_LOG_EVENT_DECODE_ERROR: what the payload should have been */
} vl_log_event_t;

/** Decoding storage of vl_log_event_decode: the message types are fixed-size, so decoding never allocates. */
typedef struct {
    vislam_imu_t imu;
    vislam_stereo_frame_t frame;
    vislam_calibration_t calibration;
} vl_log_decoder_t;

/**
 * Decodes one payload received on the channel of @p kind (VL_LOG_EVENT_IMU,
 * _FRAME or _CALIBRATION) into @p ev. The one definition of what a valid input
 * message is, for the log reader and the daemon alike: the payload is exactly
 * one message (a short read, a wrong hash or trailing bytes are errors) and a
 * frame's count lies within 0..VISLAM_STEREO_FRAME_T_MAX_FEATURES.
 * ev->channel and ev->event_number name the event in the error message.
 * @return @p kind, or VL_LOG_EVENT_DECODE_ERROR (ev->error says why, ev->decode_kind = @p kind);
 *         also stored in ev->kind
 */
vl_log_event_kind_t vl_log_event_decode(vl_log_decoder_t *d, vl_log_event_kind_t kind, const void *data, int len,
                                        vl_log_event_t *ev);

/** Counts since vl_log_reader_open. */
typedef struct {
    uint64_t events;        /**< events read from the file, every channel */
    uint64_t imu;           /**< IMU events decoded */
    uint64_t frames;        /**< frame events decoded */
    uint64_t calibrations;  /**< calibration events decoded */
    uint64_t decode_errors; /**< events on known channels that failed to decode */
    uint64_t skipped;       /**< events on other channels */
    uint64_t corrupt;       /**< damaged spots (invalid event headers or junk), each skipped */
    uint64_t bytes_skipped; /**< bytes skipped over damaged spots */
} vl_log_reader_stats_t;

/** Reader state; members are private. */
typedef struct {
    void *log; /**< lcm_eventlog_t */
    char imu_channel[VL_LOG_CHANNEL_MAX];
    char features_channel[VL_LOG_CHANNEL_MAX];
    char calibration_channel[VL_LOG_CHANNEL_MAX];
    vl_log_guard_t guard; /**< header checks and resynchronization */
    int ended;
    vl_log_reader_stats_t stats;
    vl_log_decoder_t decoder;
} vl_log_reader_t;

/** Fills @p channels with the default names. */
void vl_log_channels_default(vl_log_channels_t *channels);

/**
 * Opens @p path for reading.
 * @param channels NULL for the defaults
 * @return 0, or -1 (errno-style message in @p err) if the file cannot be opened
 *         or a channel name is too long.
 */
int vl_log_reader_open(vl_log_reader_t *r, const char *path, const vl_log_channels_t *channels, char *err,
                       size_t err_len);

/**
 * Reads the next event on a known channel, skipping others.
 * @return the event kind (also stored in ev->kind); VL_LOG_EVENT_END forever once the log is done.
 */
vl_log_event_kind_t vl_log_reader_next(vl_log_reader_t *r, vl_log_event_t *ev);

/** Counters since open. */
const vl_log_reader_stats_t *vl_log_reader_stats(const vl_log_reader_t *r);

/** Nonzero if the file ends inside an event (a cut log), or reading it failed. */
int vl_log_reader_truncated(const vl_log_reader_t *r);

/** Closes the log; safe on a reader that failed to open or is already closed. */
void vl_log_reader_close(vl_log_reader_t *r);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_LOG_READER_H */
