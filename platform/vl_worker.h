/**
 * @file vl_worker.h
 * @brief A second thread for the core's update: the vl_parallel_for_fn every program can inject.
 *
 * One persistent worker thread, started once (vl_worker_start), pinned to its
 * own CPU and optionally SCHED_FIFO. vl_worker_parallel_for hands it a loop of
 * tasks: the calling thread publishes the loop, wakes the worker only if it
 * sleeps, and runs tasks itself; each thread takes the next free index until
 * none is left, so a worker that wakes late costs nothing but its share, and
 * the caller returns once every task has finished. Between loops the worker
 * spins briefly (VL_WORKER_SPIN_NS, VL_WORKER_READY_NS), then sleeps on a
 * futex; a loop of count 0 (the update's first call) wakes it early. Nothing
 * is allocated after the start.
 *
 * The core's blocks are fixed by the update's dimensions, never by who runs
 * them, so a run with the worker is bit-identical to one without.
 */
#ifndef VISLAM_PLATFORM_VL_WORKER_H
#define VISLAM_PLATFORM_VL_WORKER_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** How long the worker spins for the next loop after running tasks, ns: the update's second loop
 * follows its first within microseconds, and a longer spin would keep the worker's CPU from others
 * (the replay's, at the same SCHED_FIFO priority) after the last one. */
#define VL_WORKER_SPIN_NS 30000
/** How long it spins after a wake-up that found no task (the update's announcement), ns: the
 * update's serial part (P H^T, S and its factorization) runs meanwhile; also how long the caller
 * spins for the worker's last tasks before it sleeps. */
#define VL_WORKER_READY_NS 300000
/** Stack the worker touches at start (Eigen's packing buffers live there), bytes. */
#define VL_WORKER_STACK_PREFAULT (256 * 1024)

/** The worker options every program shares (--threads, --worker-cpu). */
typedef struct {
    int threads;  /**< 1: serial (no worker); 2: the caller and one worker */
    int cpu;      /**< the worker's CPU; -1: another CPU than the caller's when the caller is pinned to one */
    int priority; /**< SCHED_FIFO 1..99 for the worker; 0: the starting thread's scheduling */
} vl_worker_options_t;

/**
 * The usage lines of the shared options, for a program's --help: PAD (a string
 * literal of spaces) moves the descriptions from column 19 to the program's own.
 */
#define VL_WORKER_USAGE(PAD)                                                                     \
    "  --threads N      " PAD "1 (default): the update on one thread; 2: its whitening and\n"    \
    "                   " PAD "covariance downdate shared with a worker thread (bit-identical\n" \
    "                   " PAD "results)\n"                                                       \
    "  --worker-cpu K   " PAD "the worker's CPU (default: another CPU than the estimator's,\n"   \
    "                   " PAD "when that one is pinned)\n"

/** The defaults: serial, the worker's CPU chosen at start. */
void vl_worker_options_default(vl_worker_options_t *o);

/**
 * Reads one of the shared options (VL_WORKER_USAGE) from the command line.
 * @param name   the option ("--threads")
 * @param value  its value (may be NULL when the command line has none)
 * @return 1 taken; 0 not a worker option; -1 a bad value (a line "PROGRAM: ..." printed on stderr)
 */
int vl_worker_parse_option(const char *program, const char *name, const char *value, vl_worker_options_t *o);

/** The worker; plain data owned by the caller (keep it static). Members are private. */
typedef struct {
    pthread_t thread;
    int running;
    int cpu;        /* the CPU it runs on, -1 unpinned */
    int fifo;       /* SCHED_FIFO granted */
    int stop;       /* atomic */
    uint32_t ready; /* atomic: set up */
    char msg[192];
    vl_worker_options_t opt;
    /* the loop in hand (atomics): count in the high half of claim, next free index in the low */
    uint64_t claim;
    uint32_t completed;
    uint32_t generation;
    uint32_t worker_sleeping;
    uint32_t caller_sleeping;
    vl_parallel_task_fn task;
    void *arg;
    /* counts since the start */
    uint64_t loops;
    uint64_t tasks;
    uint64_t worker_tasks; /* atomic */
} vl_worker_t;

/**
 * Starts the worker when o->threads is 2 (otherwise does nothing and returns 0,
 * and vl_worker_parallel_for runs loops serially). Pinning or priority refused:
 * the worker still runs, and @p msg says so. Call after the caller's own CPU and
 * priority are set (a worker with cpu -1 avoids the caller's CPU).
 * @param msg one line: what the worker runs on, or why it could not start
 * @return 0 (running, or not asked for), -1 the thread could not be created (loops run serially)
 */
int vl_worker_start(vl_worker_t *w, const vl_worker_options_t *o, char *msg, size_t msg_len);

/**
 * The vl_parallel_for_fn to inject (vl_config_t::parallel_for, ctx = the
 * worker): runs task(arg, 0..count-1) on the caller and the worker, serially
 * when the worker is not running. Only one thread may call it at a time.
 */
void vl_worker_parallel_for(void *ctx, vl_parallel_task_fn task, void *arg, uint32_t count);

/** Nonzero when the worker thread runs (loops are shared). */
int vl_worker_running(const vl_worker_t *w);

/** Loops handed out, their tasks, and the tasks the worker ran, since the start (after a loop returned). */
void vl_worker_counts(const vl_worker_t *w, uint64_t *loops, uint64_t *tasks, uint64_t *worker_tasks);

/** Stops and joins the worker (idempotent; nothing to do when it never started). */
void vl_worker_stop(vl_worker_t *w);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_WORKER_H */
