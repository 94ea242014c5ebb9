/**
 * @file vl_signal.h
 * @brief SIGINT/SIGTERM to a stop flag, for loops that must finish their current step.
 *
 * The handler only stores the signal number in a volatile sig_atomic_t
 * (async-signal-safe). It is installed without SA_RESTART, so a blocking
 * select/poll/clock_nanosleep returns EINTR and the loop sees the flag at once.
 *
 * Threads started by libraries (LCM's UDP receive thread) could otherwise take
 * the signal while the main thread sleeps on. vl_signal_block() blocks both
 * signals in the calling thread, and every thread it creates afterwards
 * inherits that mask; the main loop then waits with vl_signal_wait_fd(), which
 * unblocks them only for the duration of the wait (pselect). That makes the
 * delivery race-free: a signal that arrives during a step stays pending and
 * ends the next wait immediately.
 */
#ifndef VISLAM_PLATFORM_VL_SIGNAL_H
#define VISLAM_PLATFORM_VL_SIGNAL_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Installs the SIGINT and SIGTERM handlers (no SA_RESTART). 0, or -1 with errno. */
int vl_signal_install(void);

/** Nonzero once SIGINT or SIGTERM arrived. */
int vl_signal_stop_requested(void);

/** The signal that requested the stop (SIGINT or SIGTERM), or 0. */
int vl_signal_last(void);

/** Clears the flag (tests). */
void vl_signal_reset(void);

/**
 * Blocks SIGINT and SIGTERM in the calling thread; call before creating threads
 * (lcm_create, the first lcm_subscribe) so that they inherit the blocked mask.
 * 0, or -1 with errno.
 */
int vl_signal_block(void);

/**
 * Waits until @p fd is readable, @p timeout_us passes, or SIGINT/SIGTERM
 * arrives; the two signals are unblocked only during the wait.
 * @return 1 readable, 0 timeout, -1 interrupted by a signal (check
 *         vl_signal_stop_requested) or another error (errno).
 */
int vl_signal_wait_fd(int fd, int64_t timeout_us);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_SIGNAL_H */
