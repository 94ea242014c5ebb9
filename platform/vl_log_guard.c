/* LCM log event header checks and resynchronization (see vl_log_guard.h for the format and policy). */
#define _POSIX_C_SOURCE 200809L

#include "vl_log_guard.h"

#include <string.h>

#include "vl_bytes.h"

/* Bytes read at a time while searching for the next sync word. */
#define SCAN_CHUNK 4096

static int32_t be32s(const unsigned char *p)
{
    const uint32_t v = vl_be32(p);
    int32_t s;
    memcpy(&s, &v, sizeof(s));
    return s;
}

static int read_at(FILE *f, long offset, void *buf, size_t n)
{
    return fseek(f, offset, SEEK_SET) == 0 && fread(buf, 1, n, f) == n;
}

vl_log_check_t vl_log_check_event(FILE *f, long offset, long file_size, vl_log_header_t *h)
{
    static const unsigned char sync[4] = {0xED, 0xA1, 0xDA, 0x01};
    unsigned char hdr[VL_LOG_HEADER_BYTES];
    if (h != NULL) {
        memset(h, 0, sizeof(*h));
    }
    const long left = file_size - offset;
    if (left <= 0) {
        return VL_LOG_CHECK_END;
    }
    if (left < VL_LOG_HEADER_BYTES) {
        /* A cut header still starts with (a prefix of) the sync word; anything else is junk. */
        const size_t n = left < 4 ? (size_t)left : 4;
        if (!read_at(f, offset, hdr, n)) {
            return VL_LOG_CHECK_IO_ERROR;
        }
        return memcmp(hdr, sync, n) == 0 ? VL_LOG_CHECK_CUT_HEADER : VL_LOG_CHECK_BAD_SYNC;
    }
    if (!read_at(f, offset, hdr, sizeof(hdr))) {
        return VL_LOG_CHECK_IO_ERROR;
    }
    if (vl_be32(hdr) != VL_LOG_SYNC_WORD) {
        return VL_LOG_CHECK_BAD_SYNC;
    }
    vl_log_header_t local;
    vl_log_header_t *hh = h != NULL ? h : &local;
    hh->event_number = vl_be64(hdr + 4);
    hh->timestamp = vl_be64(hdr + 12);
    hh->channel_bytes = be32s(hdr + 20);
    hh->data_bytes = be32s(hdr + 24);
    if (hh->channel_bytes < 1 || hh->channel_bytes > VL_LOG_MAX_CHANNEL_BYTES) {
        return VL_LOG_CHECK_BAD_CHANNEL_LENGTH;
    }
    if (hh->data_bytes < 0 || (long)hh->data_bytes > VL_LOG_MAX_DATA_BYTES) {
        return VL_LOG_CHECK_BAD_DATA_LENGTH;
    }
    const long end = offset + VL_LOG_HEADER_BYTES + (long)hh->channel_bytes + (long)hh->data_bytes;
    if (end > file_size) {
        return VL_LOG_CHECK_CUT_EVENT;
    }
    unsigned char channel[VL_LOG_MAX_CHANNEL_BYTES];
    if (fread(channel, 1, (size_t)hh->channel_bytes, f) != (size_t)hh->channel_bytes) {
        return VL_LOG_CHECK_IO_ERROR;
    }
    for (int32_t i = 0; i < hh->channel_bytes; ++i) {
        if (channel[i] < 0x20 || channel[i] > 0x7e) {
            return VL_LOG_CHECK_BAD_CHANNEL;
        }
    }
    if (end < file_size) {
        unsigned char next[4];
        const size_t n = file_size - end < 4 ? (size_t)(file_size - end) : 4;
        if (!read_at(f, end, next, n)) {
            return VL_LOG_CHECK_IO_ERROR;
        }
        /* A cut tail after a whole event may be a prefix of the next sync word: the event stands. */
        if (memcmp(next, sync, n) != 0) {
            return VL_LOG_CHECK_NO_NEXT_SYNC;
        }
    }
    return VL_LOG_CHECK_OK;
}

const char *vl_log_check_str(vl_log_check_t c)
{
    switch (c) {
    case VL_LOG_CHECK_OK:
        return "a valid event";
    case VL_LOG_CHECK_END:
        return "the end of the file";
    case VL_LOG_CHECK_CUT_HEADER:
        return "the file ends inside an event header (cut log)";
    case VL_LOG_CHECK_BAD_SYNC:
        return "no sync word (0xEDA1DA01) where an event should start";
    case VL_LOG_CHECK_BAD_CHANNEL_LENGTH:
        return "channel length outside 1..256";
    case VL_LOG_CHECK_BAD_DATA_LENGTH:
        return "data length outside 0..16 MiB";
    case VL_LOG_CHECK_CUT_EVENT:
        return "the event is longer than what is left of the file (cut log or damaged length)";
    case VL_LOG_CHECK_BAD_CHANNEL:
        return "channel name not printable";
    case VL_LOG_CHECK_NO_NEXT_SYNC:
        return "no sync word after the event (damaged length)";
    case VL_LOG_CHECK_IO_ERROR:
        return "read error";
    }
    return "unknown";
}

int vl_log_guard_init(vl_log_guard_t *g, FILE *f)
{
    memset(g, 0, sizeof(*g));
    g->file_size = -1;
    const long pos = ftell(f);
    if (pos < 0 || fseek(f, 0, SEEK_END) != 0) {
        g->failed = 1;
        return -1;
    }
    g->file_size = ftell(f);
    if (g->file_size < 0 || fseek(f, pos, SEEK_SET) != 0) {
        g->failed = 1;
        return -1;
    }
    return 0;
}

/* The first offset after @p from where an event that passes starts, or the file size. */
static long find_next_event(FILE *f, long from, long file_size, int *io_error)
{
    unsigned char buf[SCAN_CHUNK];
    uint32_t window = 0;
    long seen = 0; /* bytes shifted into window */
    long pos = from;
    *io_error = 0;
    while (pos < file_size) {
        if (fseek(f, pos, SEEK_SET) != 0) {
            *io_error = 1;
            return file_size;
        }
        const size_t n = fread(buf, 1, sizeof(buf), f);
        if (n == 0) {
            *io_error = ferror(f) != 0;
            return file_size;
        }
        for (size_t i = 0; i < n; ++i) {
            window = (window << 8) | buf[i];
            if (++seen >= 4 && window == VL_LOG_SYNC_WORD) {
                const long candidate = pos + (long)i - 3;
                const vl_log_check_t c = vl_log_check_event(f, candidate, file_size, NULL);
                if (c == VL_LOG_CHECK_OK) {
                    return candidate;
                }
                if (c == VL_LOG_CHECK_IO_ERROR) {
                    *io_error = 1;
                    return file_size;
                }
            }
        }
        pos += (long)n;
    }
    return file_size;
}

vl_log_guard_result_t vl_log_guard_next(vl_log_guard_t *g, FILE *f)
{
    if (g->failed) {
        return VL_LOG_GUARD_END;
    }
    const long offset = ftell(f);
    if (offset < 0) {
        g->failed = 1;
        return VL_LOG_GUARD_END;
    }
    vl_log_header_t h;
    const vl_log_check_t c = vl_log_check_event(f, offset, g->file_size, &h);
    if (c == VL_LOG_CHECK_OK || c == VL_LOG_CHECK_END || c == VL_LOG_CHECK_IO_ERROR) {
        if (c == VL_LOG_CHECK_IO_ERROR || fseek(f, offset, SEEK_SET) != 0) {
            g->failed = 1;
            g->offset = offset;
            g->what = VL_LOG_CHECK_IO_ERROR;
            snprintf(g->error, sizeof(g->error), "offset %ld: read error; reading stopped", offset);
            return VL_LOG_GUARD_END;
        }
        if (c == VL_LOG_CHECK_OK) {
            g->events++;
            return VL_LOG_GUARD_EVENT;
        }
        return VL_LOG_GUARD_END;
    }
    /* Damage: skip to the next event that passes. The search starts one byte on, so a bad
       event whose own sync word is intact is never chosen again. */
    int io_error = 0;
    const long next = find_next_event(f, offset + 1, g->file_size, &io_error);
    g->damaged++;
    g->bytes_skipped += (uint64_t)(next - offset);
    g->offset = offset;
    g->what = c;
    const int runs_to_end = next >= g->file_size;
    if (runs_to_end && (c == VL_LOG_CHECK_CUT_HEADER || c == VL_LOG_CHECK_CUT_EVENT)) {
        g->truncated = 1;
    }
    char detail[96] = "";
    if (c == VL_LOG_CHECK_BAD_CHANNEL_LENGTH || c == VL_LOG_CHECK_BAD_DATA_LENGTH || c == VL_LOG_CHECK_CUT_EVENT ||
        c == VL_LOG_CHECK_NO_NEXT_SYNC) {
        snprintf(detail, sizeof(detail), " (event %lld: channel %d bytes, data %d bytes)", (long long)h.event_number,
                 (int)h.channel_bytes, (int)h.data_bytes);
    }
    if (runs_to_end) {
        snprintf(g->error, sizeof(g->error), "offset %ld: %s%s; no valid event after it (%ld bytes to the end)", offset,
                 vl_log_check_str(c), detail, next - offset);
    } else {
        snprintf(g->error, sizeof(g->error), "offset %ld: %s%s; skipped %ld bytes to the next event", offset,
                 vl_log_check_str(c), detail, next - offset);
    }
    if (io_error || fseek(f, next, SEEK_SET) != 0) {
        g->failed = 1;
    }
    return VL_LOG_GUARD_DAMAGED;
}

int vl_log_guard_damaged(const vl_log_guard_t *g)
{
    return g->damaged != 0 || g->truncated || g->failed;
}
