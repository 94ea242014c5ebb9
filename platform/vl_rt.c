#define _GNU_SOURCE /* sched_setaffinity, CPU_SET */

#include "vl_rt.h"

#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <sched.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

static void say(char *msg, size_t len, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

static void say(char *msg, size_t len, const char *fmt, ...)
{
    if (msg != NULL && len > 0) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, len, fmt, ap);
        va_end(ap);
    }
}

vl_rt_status_t vl_rt_set_fifo(int priority, char *msg, size_t msg_len)
{
    const int lo = sched_get_priority_min(SCHED_FIFO);
    const int hi = sched_get_priority_max(SCHED_FIFO);
    if (priority < lo || priority > hi) {
        say(msg, msg_len, "SCHED_FIFO priority %d outside %d..%d", priority, lo, hi);
        return VL_RT_INVALID;
    }
    struct sched_param sp;
    memset(&sp, 0, sizeof(sp));
    sp.sched_priority = priority;
    if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0) {
        const int e = errno;
        say(msg, msg_len, "cannot switch to SCHED_FIFO priority %d: %s (needs root or CAP_SYS_NICE, and an RT budget)",
            priority, strerror(e));
        return VL_RT_REFUSED;
    }
    say(msg, msg_len, "scheduling: SCHED_FIFO priority %d", priority);
    return VL_RT_OK;
}

vl_rt_status_t vl_rt_set_affinity(int cpu, char *msg, size_t msg_len)
{
    const long ncpu = sysconf(_SC_NPROCESSORS_CONF);
    if (cpu < 0 || cpu >= CPU_SETSIZE || (ncpu > 0 && cpu >= ncpu)) {
        say(msg, msg_len, "CPU %d outside 0..%ld", cpu, ncpu > 0 ? ncpu - 1 : (long)CPU_SETSIZE - 1);
        return VL_RT_INVALID;
    }
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof(set), &set) != 0) {
        const int e = errno;
        say(msg, msg_len, "cannot pin to CPU %d: %s (outside this process's cpuset?)", cpu, strerror(e));
        return VL_RT_REFUSED;
    }
    say(msg, msg_len, "affinity: CPU %d", cpu);
    return VL_RT_OK;
}

vl_rt_status_t vl_rt_lock_memory(char *msg, size_t msg_len)
{
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
        const int e = errno;
        struct rlimit rl;
        long limit_kib = -1;
        if (getrlimit(RLIMIT_MEMLOCK, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY) {
            limit_kib = (long)(rl.rlim_cur / 1024);
        }
        say(msg, msg_len, "cannot lock memory (mlockall): %s (RLIMIT_MEMLOCK %ld KiB%s)", strerror(e), limit_kib,
            limit_kib < 0 ? ", -1 = unlimited" : "; raise it or grant CAP_IPC_LOCK");
        return VL_RT_REFUSED;
    }
    say(msg, msg_len, "memory: locked (mlockall current and future)");
    return VL_RT_OK;
}

/* Not inlined, so the array really lives in a frame below the caller's. */
static __attribute__((noinline)) unsigned touch_stack(size_t bytes)
{
    /* Variable-length array: exactly the requested depth, written page by page. */
    volatile unsigned char buf[bytes > 0 ? bytes : 1];
    const size_t page = 4096;
    for (size_t i = 0; i < bytes; i += page) {
        buf[i] = 0;
    }
    if (bytes > 0) {
        buf[bytes - 1] = 0;
    }
    return buf[0]; /* read back, so the writes are not dead stores */
}

vl_rt_status_t vl_rt_prefault_stack(size_t bytes, char *msg, size_t msg_len)
{
    (void)touch_stack(bytes);
    say(msg, msg_len, "stack: %zu KiB pre-faulted", bytes / 1024);
    return VL_RT_OK;
}

/* The kernel's PM QoS CPU latency interface: a request is a binary int32 (us), held while open. */
static const char cpu_latency_path[] = "/dev/cpu_dma_latency";

vl_rt_status_t vl_rt_request_cpu_latency(int max_us, int *fd_out, char *msg, size_t msg_len)
{
    *fd_out = -1;
    if (max_us < 0 || max_us > 2000000000) {
        say(msg, msg_len, "CPU wake-up latency %d us outside 0..2000000000", max_us);
        return VL_RT_INVALID;
    }
    const int fd = open(cpu_latency_path, O_WRONLY | O_CLOEXEC);
    if (fd < 0) {
        const int e = errno;
        say(msg, msg_len, "cannot open %s: %s (needs root; CPUs may enter deep idle states)", cpu_latency_path,
            strerror(e));
        return VL_RT_REFUSED;
    }
    const int32_t value = (int32_t)max_us;
    if (write(fd, &value, sizeof(value)) != (ssize_t)sizeof(value)) {
        const int e = errno;
        close(fd);
        say(msg, msg_len, "cannot write %s: %s", cpu_latency_path, strerror(e));
        return VL_RT_REFUSED;
    }
    *fd_out = fd;
    say(msg, msg_len, "CPU wake-up latency: at most %d us (%s held open)", max_us, cpu_latency_path);
    return VL_RT_OK;
}

void vl_rt_release_cpu_latency(int *fd)
{
    if (*fd >= 0) {
        close(*fd);
        *fd = -1;
    }
}
