/**
 * @file vl_log_guard.h
 * @brief Checks each LCM log event header before liblcm reads the event.
 *
 * liblcm's lcm_eventlog_read_next_event trusts the lengths it reads: a data
 * length of 0x7fffffff makes it calloc 2 GiB (or, with the +1 it adds, a
 * negative size), fail, and fread into NULL. Every program here that reads a
 * log therefore asks the guard first; the guard reads the header itself with
 * plain stdio and only lets liblcm read an event that is whole and plausible.
 *
 * An event, as the LCM log format lays it out (integers big-endian):
 *
 *     uint32 sync word 0xEDA1DA01, int64 event number, int64 timestamp (us),
 *     int32 channel length, int32 data length, channel bytes, data bytes
 *
 * An event passes when its sync word is right, 1 <= channel length <=
 * VL_LOG_MAX_CHANNEL_BYTES, 0 <= data length <= VL_LOG_MAX_DATA_BYTES, the
 * event fits in the file, its channel is printable ASCII, and the bytes after
 * it end the file or start with the sync word. The last rule catches a length
 * that was damaged into another plausible value, so a misframed payload never
 * reaches a decoder; its price is that damage to an event's sync word also
 * drops the event before it.
 *
 * Policy on damage: resynchronize. The guard reports the damaged spot (file
 * offset and what is wrong), counts it, and moves to the next offset where a
 * sync word starts an event that passes; the bytes in between are skipped and
 * counted. A damaged spot that runs to the end of the file is a cut log
 * (truncated) when it is a cut header or an event longer than what is left.
 * No allocation; the file must be seekable.
 */
#ifndef VISLAM_PLATFORM_VL_LOG_GUARD_H
#define VISLAM_PLATFORM_VL_LOG_GUARD_H

#include <stdint.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

/** First four bytes of every event. */
#define VL_LOG_SYNC_WORD 0xEDA1DA01u
/** Bytes before the channel name: sync, event number, timestamp, two lengths. */
#define VL_LOG_HEADER_BYTES 28
/** Longest channel name accepted, bytes. */
#define VL_LOG_MAX_CHANNEL_BYTES 256
/** Largest payload accepted, bytes (16 MiB; the largest vislam message is about 10 KiB). */
#define VL_LOG_MAX_DATA_BYTES (16L * 1024L * 1024L)

/** What the check of one event found. */
typedef enum {
    VL_LOG_CHECK_OK = 0,                 /**< a whole, plausible event */
    VL_LOG_CHECK_END = 1,                /**< no byte left: the clean end of the file */
    VL_LOG_CHECK_CUT_HEADER = 2,         /**< fewer header bytes left than a header needs */
    VL_LOG_CHECK_BAD_SYNC = 3,           /**< the first four bytes are not the sync word */
    VL_LOG_CHECK_BAD_CHANNEL_LENGTH = 4, /**< channel length outside 1..VL_LOG_MAX_CHANNEL_BYTES */
    VL_LOG_CHECK_BAD_DATA_LENGTH = 5,    /**< data length outside 0..VL_LOG_MAX_DATA_BYTES */
    VL_LOG_CHECK_CUT_EVENT = 6,          /**< valid lengths, but the event runs past the end of the file */
    VL_LOG_CHECK_BAD_CHANNEL = 7,        /**< channel name not printable ASCII */
    VL_LOG_CHECK_NO_NEXT_SYNC = 8,       /**< the bytes after the event neither end the file nor start an event */
    VL_LOG_CHECK_IO_ERROR = 9            /**< seek or read failed */
} vl_log_check_t;

/** The fixed part of an event header, decoded. */
typedef struct {
    int64_t event_number;  /**< logger's event counter */
    int64_t timestamp;     /**< us, when the logger received the event */
    int32_t channel_bytes; /**< channel name length, bytes */
    int32_t data_bytes;    /**< payload length, bytes */
} vl_log_header_t;

/**
 * Checks the event starting at byte @p offset of @p f (size @p file_size bytes).
 * Moves the file position; callers seek back.
 * @param h filled with the decoded header when at least a header's bytes were read (may be NULL)
 */
vl_log_check_t vl_log_check_event(FILE *f, long offset, long file_size, vl_log_header_t *h);

/** A short English description of @p c ("bad sync word", ...). */
const char *vl_log_check_str(vl_log_check_t c);

/** Guard state and counts for one pass over a log. */
typedef struct {
    long file_size;         /**< bytes */
    uint64_t events;        /**< events that passed */
    uint64_t damaged;       /**< damaged spots met (each one report, one resynchronization) */
    uint64_t bytes_skipped; /**< bytes skipped while resynchronizing */
    int truncated;          /**< the file ends inside an event (cut header or payload) */
    int failed;             /**< a seek or read failed: reading stopped */
    long offset;            /**< where the latest damaged spot starts, bytes */
    vl_log_check_t what;    /**< what was wrong there */
    char error[224];        /**< the latest damaged spot, in words, with its offset */
} vl_log_guard_t;

/**
 * Starts a pass: measures the file and keeps its position (the start of the next event).
 * @return 0, or -1 if @p f cannot be measured (not seekable)
 */
int vl_log_guard_init(vl_log_guard_t *g, FILE *f);

/** What vl_log_guard_next found at the reading position. */
typedef enum {
    VL_LOG_GUARD_EVENT = 0,   /**< an event that passed starts at the position: let liblcm read it */
    VL_LOG_GUARD_DAMAGED = 1, /**< damage: g->error says where and what; the position has moved to the
                                   next event that passes (or the end); call again */
    VL_LOG_GUARD_END = 2      /**< nothing left (or a read failed: g->failed) */
} vl_log_guard_result_t;

/** Checks the event at @p f's position; see vl_log_guard_result_t. */
vl_log_guard_result_t vl_log_guard_next(vl_log_guard_t *g, FILE *f);

/** Nonzero if the pass met any damage (damaged spots, a cut end, a read failure). */
int vl_log_guard_damaged(const vl_log_guard_t *g);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_LOG_GUARD_H */
