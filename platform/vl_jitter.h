/**
 * @file vl_jitter.h
 * @brief The machine's own scheduling-jitter floor: one thread per CPU waking at 1 kHz.
 *
 * Each probe thread is pinned to its CPU and sleeps to absolute CLOCK_MONOTONIC
 * deadlines (clock_nanosleep TIMER_ABSTIME, period VL_JITTER_PERIOD_US); how
 * late it wakes is recorded in a vl_latency_t histogram. The lateness is what
 * any thread on that CPU can suffer from the kernel, the hypervisor and other
 * work, before it runs a single instruction of its own: the floor under every
 * step latency measured on the same machine at the same time. The same idea as
 * cyclictest, built in so that every latency report carries its own floor.
 */
#ifndef VISLAM_PLATFORM_VL_JITTER_H
#define VISLAM_PLATFORM_VL_JITTER_H

#include <pthread.h>
#include <stddef.h>

#include "vl_latency.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Most CPUs probed. */
#define VL_JITTER_MAX_CPUS 16
/** Probe period, us (1 kHz). */
#define VL_JITTER_PERIOD_US 1000

/** One probe thread; plain data owned by vl_jitter_t. */
typedef struct {
    int cpu;            /**< CPU the thread is pinned to */
    int pinned;         /**< nonzero when the pinning succeeded */
    int fifo;           /**< nonzero when SCHED_FIFO was granted */
    vl_latency_t late;  /**< wake-up lateness, us */
    volatile int *stop; /**< set by vl_jitter_stop */
    int priority;       /**< SCHED_FIFO priority asked for, 0 = normal scheduling */
    pthread_t thread;   /**< the probe thread */
    int running;        /**< the thread was started */
} vl_jitter_probe_t;

/** The probes of every CPU; keep it static (the histograms are 3 KB each). */
typedef struct {
    int count;                                    /**< probes started */
    volatile int stop;                            /**< asks the probes to end */
    vl_jitter_probe_t probes[VL_JITTER_MAX_CPUS]; /**< one per CPU */
} vl_jitter_t;

/**
 * Starts one probe on each of the first @p cpus CPUs (0 .. cpus-1; at most
 * VL_JITTER_MAX_CPUS). @p priority > 0 asks SCHED_FIFO at that priority (a
 * refusal leaves the probe at normal priority, with its fifo member 0).
 * @return probes started (0 when no thread could be created)
 */
int vl_jitter_start(vl_jitter_t *j, int cpus, int priority);

/** Stops and joins every probe; their histograms stay readable. */
void vl_jitter_stop(vl_jitter_t *j);

/** All probes' lateness merged into @p out, us. */
void vl_jitter_merged(const vl_jitter_t *j, vl_latency_t *out);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_JITTER_H */
