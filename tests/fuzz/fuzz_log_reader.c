/*
 * Fuzz harness: the LCM log reader (platform/vl_log_reader) on arbitrary files.
 *
 * The input is the whole log file. It is written to an in-memory file (memfd, or a temporary
 * file where memfd_create is missing), opened by path with vl_log_reader_open and read with
 * vl_log_reader_next to the end, as vislam-run and vislam-replay read a log. Besides not
 * crashing, the reader must:
 *   - end: every event consumes at least one header's worth of the file, so a file of n bytes
 *     holds at most n / VL_FUZZ_MIN_EVENT + 1 events (more means it is looping);
 *   - count every event it returned once in its stats, and no more than it read;
 *   - hand out frames whose count is within 0..256 (vl_msg's clamp) and stay at END once ended.
 */
#define _GNU_SOURCE /* memfd_create */

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "vl_fuzz.h"
#include "vl_log_reader.h"

/* Magic (4), event number (8), timestamp (8), channel and data lengths (4 + 4). */
#define VL_FUZZ_MIN_EVENT 28

static vl_log_reader_t g_reader;
static vl_log_event_t g_ev;
static int g_fd = -1;
static char g_path[64];

static void vl_fuzz_fail(const char *why)
{
    fprintf(stderr, "fuzz_log_reader: %s\n", why);
    __builtin_trap();
}

/* One file for the whole run: the reader opens it by path, each open with its own offset. */
static void vl_fuzz_open_file(void)
{
    if (g_fd >= 0) {
        return;
    }
#ifdef MFD_CLOEXEC
    g_fd = memfd_create("vl_fuzz_log", MFD_CLOEXEC);
    if (g_fd >= 0) {
        snprintf(g_path, sizeof(g_path), "/proc/self/fd/%d", g_fd);
        if (access(g_path, R_OK) == 0) {
            return;
        }
        close(g_fd);
        g_fd = -1;
    }
#endif
    const char *dir = getenv("TMPDIR");
    snprintf(g_path, sizeof(g_path), "%s/vl_fuzz_log_XXXXXX", dir != NULL && strlen(dir) < 32 ? dir : "/tmp");
    g_fd = mkstemp(g_path);
    if (g_fd < 0) {
        vl_fuzz_fail("cannot create a temporary file");
    }
    /* Removed when the process ends, whichever way it ends. */
    unlink(g_path);
    snprintf(g_path, sizeof(g_path), "/proc/self/fd/%d", g_fd);
}

static void vl_fuzz_write_file(const uint8_t *data, size_t size)
{
    if (ftruncate(g_fd, 0) != 0) {
        vl_fuzz_fail("ftruncate failed");
    }
    size_t done = 0;
    while (done < size) {
        const ssize_t n = pwrite(g_fd, data + done, size - done, (off_t)done);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n <= 0) {
            vl_fuzz_fail("write to the temporary file failed");
        }
        done += (size_t)n;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    vl_fuzz_open_file();
    vl_fuzz_write_file(data, size);

    char err[256];
    if (vl_log_reader_open(&g_reader, g_path, NULL, err, sizeof(err)) != 0) {
        fprintf(stderr, "fuzz_log_reader: %s\n", err);
        vl_fuzz_fail("vl_log_reader_open failed on a readable file");
    }
    const uint64_t max_events = size / VL_FUZZ_MIN_EVENT + 1;
    uint64_t returned = 0;
    for (;;) {
        const vl_log_event_kind_t kind = vl_log_reader_next(&g_reader, &g_ev);
        if (kind != g_ev.kind) {
            vl_fuzz_fail("returned kind differs from ev->kind");
        }
        if (kind == VL_LOG_EVENT_END) {
            break;
        }
        if (++returned > max_events) {
            vl_fuzz_fail("more events than the file can hold: the reader is looping");
        }
        if (kind == VL_LOG_EVENT_FRAME && g_ev.frame.count > VISLAM_STEREO_FRAME_T_MAX_FEATURES) {
            vl_fuzz_fail("frame count above the message capacity");
        }
        if (memchr(g_ev.channel, '\0', sizeof(g_ev.channel)) == NULL) {
            vl_fuzz_fail("channel name not terminated");
        }
    }
    if (vl_log_reader_next(&g_reader, &g_ev) != VL_LOG_EVENT_END) {
        vl_fuzz_fail("an event after the end");
    }
    const vl_log_reader_stats_t *s = vl_log_reader_stats(&g_reader);
    /* every return is one decoded event, one decode error or one damaged spot */
    if (s->imu + s->frames + s->calibrations + s->decode_errors + s->corrupt != returned) {
        vl_fuzz_fail("stats do not match the events returned");
    }
    if (returned - s->corrupt + s->skipped > s->events) {
        vl_fuzz_fail("more events returned or skipped than read");
    }
    vl_log_reader_close(&g_reader);
    vl_log_reader_close(&g_reader); /* documented as safe */
    return 0;
}
