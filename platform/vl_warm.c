/*
 * The predictive wake before a frame: its due time from the frames' own intervals, and the read
 * that warms the estimator (see vl_warm.h).
 */
#include "vl_warm.h"

#include <string.h>

#define LINE_BYTES 64

void vl_warm_init(vl_warm_t *w, int64_t warm_us)
{
    memset(w, 0, sizeof(*w));
    w->warm_us = warm_us > 0 ? (warm_us < VL_WARM_MAX_US ? warm_us : VL_WARM_MAX_US) : 0;
}

/* Median of the ring, by insertion sort of a copy (16 values). */
static int64_t median(const vl_warm_t *w)
{
    int64_t s[VL_WARM_INTERVALS];
    const unsigned m = w->num_intervals;
    for (unsigned i = 0; i < m; ++i) {
        const int64_t v = w->intervals[i];
        unsigned j = i;
        while (j > 0 && s[j - 1] > v) {
            s[j] = s[j - 1];
            --j;
        }
        s[j] = v;
    }
    return s[m / 2];
}

void vl_warm_note_frame(vl_warm_t *w, int64_t utime, int64_t arrival_us)
{
    if (w->last_arrival_us != 0 && utime > w->last_utime) {
        w->intervals[w->next_interval] = utime - w->last_utime;
        w->next_interval = (w->next_interval + 1) % VL_WARM_INTERVALS;
        if (w->num_intervals < VL_WARM_INTERVALS) {
            w->num_intervals++;
        }
        w->period_us = median(w);
    } else if (w->last_arrival_us != 0) {
        w->num_intervals = 0;
        w->next_interval = 0;
        w->period_us = 0;
    }
    w->last_utime = utime;
    w->last_arrival_us = arrival_us;
}

int vl_warm_window(const vl_warm_t *w, int64_t now_us, int64_t *from_us, int64_t *until_us)
{
    if (w->warm_us <= 0 || w->period_us <= 0 || w->period_us < 4 * w->warm_us) {
        return 0;
    }
    const int64_t due = w->last_arrival_us + w->period_us;
    *from_us = due - w->warm_us;
    *until_us = due + w->warm_us;
    return now_us < *until_us;
}

int vl_warm_frame_due(const vl_warm_t *w, int64_t utime)
{
    return w->period_us > 0 && utime >= w->last_utime + w->period_us - w->period_us / 8;
}

uint64_t vl_warm_touch(const void *p, size_t bytes)
{
    /* Last line first: the start of the block is then what the cache holds most recently (the
       estimator keeps its state and covariance before its scratch buffers). */
    const volatile unsigned char *b = (const volatile unsigned char *)p;
    uint64_t sum = 0;
    for (size_t i = bytes; i > 0;) {
        i = i > LINE_BYTES ? (i - 1) / LINE_BYTES * LINE_BYTES : 0;
        sum += b[i];
    }
    return sum;
}
