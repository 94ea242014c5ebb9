/**
 * @file vl_awake.h
 * @brief Keeps one CPU from idling: a thread pinned to it that spins at SCHED_IDLE.
 *
 * At a camera's rate the estimation thread idles about 100 ms between frames; on a virtual
 * machine the idle (virtual) CPU halts, the host takes the core away, and the step after the idle
 * period runs slower (README, Latency). A thread that spins on that CPU at SCHED_IDLE keeps it from
 * halting, while any other thread there (SCHED_FIFO or normal) preempts it at once: the per-CPU
 * equivalent of booting with idle=poll. The cost is that CPU at 100 % (power, heat).
 *
 * The caller owns the handle; nothing is allocated after vl_awake_start returns.
 */
#ifndef VISLAM_PLATFORM_VL_AWAKE_H
#define VISLAM_PLATFORM_VL_AWAKE_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Stack of the spinning thread, bytes: it calls nothing, and a locked process maps all of it. */
#define VL_AWAKE_STACK_BYTES (64 * 1024)

/** One spin-loop iteration's hint to the CPU (pause on x86, yield on ARM; else a compiler barrier). */
static inline void vl_cpu_relax(void)
{
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__) || defined(__arm__)
    __asm__ __volatile__("yield" ::: "memory");
#else
    __asm__ __volatile__("" ::: "memory");
#endif
}

/** The spinner; plain data owned by the caller (a zeroed one is a stopped one). Members are private. */
typedef struct {
    pthread_t thread;
    int running;    /* the thread runs and has to be joined */
    int cpu;        /* the CPU it keeps awake */
    int stop;       /* atomic: set by vl_awake_stop */
    uint64_t loops; /* atomic (relaxed): spin iterations so far */
} vl_awake_t;

/**
 * Starts one thread pinned to @p cpu at SCHED_IDLE that spins until vl_awake_stop. On any error
 * (a CPU outside this machine or this process's cpuset, a thread that cannot be created or made
 * SCHED_IDLE) nothing is left running and @p msg says why.
 * @param cpu 0-based CPU to keep awake
 * @param msg one line: what runs, or why it could not start
 * @return 0 running, -1 not started
 */
int vl_awake_start(vl_awake_t *a, int cpu, char *msg, size_t msg_len);

/** Nonzero while the spinner runs. */
int vl_awake_running(const vl_awake_t *a);

/** Spin iterations so far (while running, or the final count after vl_awake_stop); 0 never started. */
uint64_t vl_awake_loops(const vl_awake_t *a);

/** Stops and joins the spinner (idempotent; nothing to do for a zeroed or failed handle). */
void vl_awake_stop(vl_awake_t *a);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_AWAKE_H */
