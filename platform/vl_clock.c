#define _POSIX_C_SOURCE 200809L

#include "vl_clock.h"

#include <errno.h>
#include <time.h>

static int64_t read_us(clockid_t id)
{
    struct timespec ts;
    if (clock_gettime(id, &ts) != 0) {
        return 0; /* cannot happen for these two clocks on Linux */
    }
    return (int64_t)ts.tv_sec * 1000000 + (int64_t)(ts.tv_nsec / 1000);
}

int64_t vl_clock_monotonic_us(void)
{
    return read_us(CLOCK_MONOTONIC);
}

static int64_t read_ns(clockid_t id)
{
    struct timespec ts;
    if (clock_gettime(id, &ts) != 0) {
        return 0;
    }
    return (int64_t)ts.tv_sec * 1000000000 + (int64_t)ts.tv_nsec;
}

int64_t vl_clock_monotonic_ns(void)
{
    return read_ns(CLOCK_MONOTONIC);
}

int64_t vl_clock_realtime_us(void)
{
    return read_us(CLOCK_REALTIME);
}

int64_t vl_clock_realtime_ns(void)
{
    return read_ns(CLOCK_REALTIME);
}

int vl_clock_sleep_until_us(int64_t deadline_us)
{
    if (deadline_us < 0) {
        return 0;
    }
    struct timespec ts;
    ts.tv_sec = (time_t)(deadline_us / 1000000);
    ts.tv_nsec = (long)(deadline_us % 1000000) * 1000;
    /* clock_nanosleep returns the error number instead of setting errno. */
    int rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    if (rc == 0) {
        return 0;
    }
    errno = rc;
    return rc == EINTR ? -1 : 0;
}
