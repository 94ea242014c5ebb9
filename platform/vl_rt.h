/**
 * @file vl_rt.h
 * @brief Real-time set-up of a process: SCHED_FIFO, CPU affinity, locked memory, pre-faulted stack,
 *        and a CPU wake-up latency request (PM QoS).
 *
 * Every call returns a status and writes a one-line message, so a daemon can
 * warn and carry on when the machine refuses (no CAP_SYS_NICE, a container's
 * RLIMIT_MEMLOCK, a CPU outside the cpuset) instead of failing.
 */
#ifndef VISLAM_PLATFORM_VL_RT_H
#define VISLAM_PLATFORM_VL_RT_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Outcome of a real-time set-up call. */
typedef enum {
    VL_RT_OK = 0,       /**< Done; the message says what was done. */
    VL_RT_REFUSED = -1, /**< The machine refused (permission, limit, unsupported); the process is unchanged. */
    VL_RT_INVALID = -2  /**< The argument is out of range; nothing was tried. */
} vl_rt_status_t;

/**
 * Switches the calling thread (and threads it creates later) to SCHED_FIFO.
 * @param priority 1..99 (sched_get_priority_min/max for SCHED_FIFO)
 */
vl_rt_status_t vl_rt_set_fifo(int priority, char *msg, size_t msg_len);

/** Pins the calling thread (and threads it creates later) to CPU @p cpu (0-based). */
vl_rt_status_t vl_rt_set_affinity(int cpu, char *msg, size_t msg_len);

/** mlockall(MCL_CURRENT | MCL_FUTURE): no page of the process is paged out or faulted in late. */
vl_rt_status_t vl_rt_lock_memory(char *msg, size_t msg_len);

/**
 * Touches @p bytes of stack below the caller's frame so that those pages are
 * mapped (and, after vl_rt_lock_memory, locked) before the real-time loop.
 * Always succeeds; the message says how much was touched.
 */
vl_rt_status_t vl_rt_prefault_stack(size_t bytes, char *msg, size_t msg_len);

/**
 * Asks the kernel (PM QoS, /dev/cpu_dma_latency) to keep every CPU out of idle
 * states whose exit latency exceeds @p max_us, as cyclictest does: the CPU then
 * wakes for the next frame quickly instead of from a deep idle state. System-wide
 * and it costs power; the request lasts while *fd_out stays open
 * (vl_rt_release_cpu_latency, or the process's exit).
 * @param max_us  maximum wake-up latency in us, 0..2000000000 (0: shallowest idle only)
 * @param fd_out  the held request's file descriptor; -1 when nothing is held
 */
vl_rt_status_t vl_rt_request_cpu_latency(int max_us, int *fd_out, char *msg, size_t msg_len);

/** Ends a request of vl_rt_request_cpu_latency (closes *fd, sets it to -1); nothing when *fd < 0. */
void vl_rt_release_cpu_latency(int *fd);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_RT_H */
