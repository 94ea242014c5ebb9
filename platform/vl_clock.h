/**
 * @file vl_clock.h
 * @brief Clocks in microseconds (nanoseconds for timing short steps) and absolute-deadline sleeping.
 *
 * CLOCK_MONOTONIC is for measuring durations and scheduling (it never jumps);
 * CLOCK_REALTIME only for stamping messages with wall-clock time.
 */
#ifndef VISLAM_PLATFORM_VL_CLOCK_H
#define VISLAM_PLATFORM_VL_CLOCK_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** CLOCK_MONOTONIC in microseconds (arbitrary origin, never jumps). */
int64_t vl_clock_monotonic_us(void);

/** CLOCK_MONOTONIC in nanoseconds (same origin as vl_clock_monotonic_us): for timing one step. */
int64_t vl_clock_monotonic_ns(void);

/** CLOCK_REALTIME in microseconds since the Unix epoch. */
int64_t vl_clock_realtime_us(void);

/**
 * CLOCK_REALTIME in nanoseconds since the Unix epoch: for stamps compared across processes on one
 * host and with the kernel's socket receive stamps (SO_TIMESTAMP, which LCM hands over as
 * lcm_recv_buf_t::recv_utime), never for durations within one process.
 */
int64_t vl_clock_realtime_ns(void);

/**
 * Sleeps until CLOCK_MONOTONIC reaches @p deadline_us (clock_nanosleep with
 * TIMER_ABSTIME, so repeated sleeps to a schedule do not accumulate drift).
 * @return 0 when the deadline passed (also when it was already past), or -1
 *         when a signal interrupted the sleep (errno EINTR): the caller checks
 *         its stop flag and calls again to resume.
 */
int vl_clock_sleep_until_us(int64_t deadline_us);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_CLOCK_H */
