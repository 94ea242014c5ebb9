#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT, syscall */

#include "vl_worker.h"

#include <errno.h>
#include <linux/futex.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "vl_awake.h" /* vl_cpu_relax */
#include "vl_clock.h"
#include "vl_rt.h"

/* Sleeps while *word == expected (returns at once otherwise, or on any wake-up). */
static void futex_wait(uint32_t *word, uint32_t expected)
{
    (void)syscall(SYS_futex, word, FUTEX_WAIT_PRIVATE, expected, NULL, NULL, 0);
}

static void futex_wake(uint32_t *word)
{
    (void)syscall(SYS_futex, word, FUTEX_WAKE_PRIVATE, 1, NULL, NULL, 0);
}

void vl_worker_options_default(vl_worker_options_t *o)
{
    o->threads = 1;
    o->cpu = -1;
    o->priority = 0;
}

static int parse_int(const char *program, const char *name, const char *value, long lo, long hi, int *out)
{
    char *end = NULL;
    errno = 0;
    const long v = value != NULL ? strtol(value, &end, 10) : 0;
    if (value == NULL || end == value || *end != '\0' || errno != 0 || v < lo || v > hi) {
        fprintf(stderr, "%s: %s %s: expected an integer in %ld..%ld\n", program, name, value != NULL ? value : "(none)",
                lo, hi);
        return -1;
    }
    *out = (int)v;
    return 0;
}

int vl_worker_parse_option(const char *program, const char *name, const char *value, vl_worker_options_t *o)
{
    if (strcmp(name, "--threads") == 0) {
        return parse_int(program, name, value, 1, 2, &o->threads) == 0 ? 1 : -1;
    }
    if (strcmp(name, "--worker-cpu") == 0) {
        return parse_int(program, name, value, 0, CPU_SETSIZE - 1, &o->cpu) == 0 ? 1 : -1;
    }
    return 0;
}

/* Takes the loop's next free index until none is left; returns the tasks run. */
static uint64_t run_share(vl_worker_t *w, int is_worker)
{
    uint64_t ran = 0;
    for (;;) {
        uint64_t c = __atomic_load_n(&w->claim, __ATOMIC_ACQUIRE);
        const uint32_t next = (uint32_t)c, count = (uint32_t)(c >> 32);
        if (next >= count) {
            return ran;
        }
        /* A successful claim of an index below count means its loop is not finished, so the
           caller has not moved on: task and arg are that loop's. */
        if (!__atomic_compare_exchange_n(&w->claim, &c, c + 1u, 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE)) {
            continue;
        }
        const vl_parallel_task_fn task = __atomic_load_n(&w->task, __ATOMIC_RELAXED);
        void *arg = __atomic_load_n(&w->arg, __ATOMIC_RELAXED);
        task(arg, next);
        ++ran;
        if (is_worker) {
            __atomic_add_fetch(&w->worker_tasks, 1u, __ATOMIC_RELAXED);
        }
        __atomic_add_fetch(&w->completed, 1u, __ATOMIC_SEQ_CST);
        if (is_worker && __atomic_load_n(&w->caller_sleeping, __ATOMIC_SEQ_CST)) {
            futex_wake(&w->completed);
        }
    }
}

static void *worker_main(void *p)
{
    vl_worker_t *w = (vl_worker_t *)p;
    char a[96] = "", f[96] = "", s[64] = "";
    if (w->cpu >= 0 && vl_rt_set_affinity(w->cpu, a, sizeof(a)) != VL_RT_OK) {
        w->cpu = -1;
    }
    if (w->opt.priority > 0) {
        w->fifo = vl_rt_set_fifo(w->opt.priority, f, sizeof(f)) == VL_RT_OK;
    }
    vl_rt_prefault_stack(VL_WORKER_STACK_PREFAULT, s, sizeof(s));
    snprintf(w->msg, sizeof(w->msg), "worker thread: %s%s%s", a[0] ? a : "not pinned", f[0] ? "; " : "", f);
    uint32_t seen = __atomic_load_n(&w->generation, __ATOMIC_ACQUIRE);
    int64_t spin_ns = VL_WORKER_SPIN_NS;
    __atomic_store_n(&w->ready, 1, __ATOMIC_SEQ_CST);
    futex_wake(&w->ready);
    for (;;) {
        uint32_t g = __atomic_load_n(&w->generation, __ATOMIC_ACQUIRE);
        if (g == seen) {
            const int64_t until = vl_clock_monotonic_ns() + spin_ns;
            while (g == seen && vl_clock_monotonic_ns() < until) {
                vl_cpu_relax();
                g = __atomic_load_n(&w->generation, __ATOMIC_ACQUIRE);
            }
        }
        if (g == seen) {
            /* Announce the sleep, then look again: the caller bumps the generation and then
               reads this flag, so one of the two sees the other. */
            __atomic_store_n(&w->worker_sleeping, 1u, __ATOMIC_SEQ_CST);
            if (__atomic_load_n(&w->generation, __ATOMIC_SEQ_CST) == seen) {
                futex_wait(&w->generation, seen);
            }
            __atomic_store_n(&w->worker_sleeping, 0u, __ATOMIC_SEQ_CST);
            continue;
        }
        seen = g;
        if (__atomic_load_n(&w->stop, __ATOMIC_ACQUIRE)) {
            return NULL;
        }
        spin_ns = run_share(w, 1) > 0 ? VL_WORKER_SPIN_NS : VL_WORKER_READY_NS;
    }
}

/* Another CPU than the caller's when the caller is pinned to exactly one; else -1 (not pinned). */
static int other_cpu(void)
{
    cpu_set_t set;
    CPU_ZERO(&set);
    const long n = sysconf(_SC_NPROCESSORS_ONLN);
    if (n < 2 || sched_getaffinity(0, sizeof(set), &set) != 0 || CPU_COUNT(&set) != 1) {
        return -1;
    }
    for (int c = 0; c < CPU_SETSIZE; ++c) {
        if (CPU_ISSET(c, &set)) {
            return (int)((c + 1) % n);
        }
    }
    return -1;
}

int vl_worker_start(vl_worker_t *w, const vl_worker_options_t *o, char *msg, size_t msg_len)
{
    memset(w, 0, sizeof(*w));
    w->opt = *o;
    if (o->threads < 2) {
        if (msg != NULL && msg_len > 0) {
            snprintf(msg, msg_len, "one thread");
        }
        return 0;
    }
    w->cpu = o->cpu >= 0 ? o->cpu : other_cpu();
    const int rc = pthread_create(&w->thread, NULL, worker_main, w);
    if (rc != 0) {
        if (msg != NULL && msg_len > 0) {
            snprintf(msg, msg_len, "cannot start the worker thread: %s; one thread", strerror(rc));
        }
        return -1;
    }
    while (!__atomic_load_n(&w->ready, __ATOMIC_SEQ_CST)) {
        futex_wait(&w->ready, 0u);
    }
    w->running = 1;
    if (msg != NULL && msg_len > 0) {
        snprintf(msg, msg_len, "%s", w->msg);
    }
    return 0;
}

void vl_worker_parallel_for(void *ctx, vl_parallel_task_fn task, void *arg, uint32_t count)
{
    vl_worker_t *w = (vl_worker_t *)ctx;
    if (count == 0) {
        /* A loop is coming: wake the worker now, so that it spins ready instead of waking late. */
        if (w != NULL && w->running && __atomic_load_n(&w->worker_sleeping, __ATOMIC_SEQ_CST)) {
            __atomic_add_fetch(&w->generation, 1u, __ATOMIC_SEQ_CST);
            futex_wake(&w->generation);
        }
        return;
    }
    if (w == NULL || !w->running || count < 2) {
        for (uint32_t i = 0; i < count; ++i) {
            task(arg, i);
        }
        if (w != NULL) {
            w->loops++;
            w->tasks += count;
        }
        return;
    }
    __atomic_store_n(&w->task, task, __ATOMIC_RELAXED);
    __atomic_store_n(&w->arg, arg, __ATOMIC_RELAXED);
    __atomic_store_n(&w->completed, 0u, __ATOMIC_RELAXED);
    __atomic_store_n(&w->claim, (uint64_t)count << 32, __ATOMIC_RELEASE);
    __atomic_add_fetch(&w->generation, 1u, __ATOMIC_SEQ_CST);
    if (__atomic_load_n(&w->worker_sleeping, __ATOMIC_SEQ_CST)) {
        futex_wake(&w->generation);
    }
    (void)run_share(w, 0);
    /* Wait for the tasks the worker took: spin (they are short), then sleep, so that a worker
       sharing this CPU can run. */
    const int64_t until = vl_clock_monotonic_ns() + VL_WORKER_READY_NS;
    while (__atomic_load_n(&w->completed, __ATOMIC_ACQUIRE) != count) {
        if (vl_clock_monotonic_ns() < until) {
            vl_cpu_relax();
            continue;
        }
        __atomic_store_n(&w->caller_sleeping, 1u, __ATOMIC_SEQ_CST);
        const uint32_t done = __atomic_load_n(&w->completed, __ATOMIC_SEQ_CST);
        if (done != count) {
            futex_wait(&w->completed, done);
        }
        __atomic_store_n(&w->caller_sleeping, 0u, __ATOMIC_SEQ_CST);
    }
    w->loops++;
    w->tasks += count;
}

int vl_worker_running(const vl_worker_t *w)
{
    return w != NULL && w->running;
}

void vl_worker_counts(const vl_worker_t *w, uint64_t *loops, uint64_t *tasks, uint64_t *worker_tasks)
{
    *loops = w->loops;
    *tasks = w->tasks;
    *worker_tasks = __atomic_load_n(&w->worker_tasks, __ATOMIC_ACQUIRE);
}

void vl_worker_stop(vl_worker_t *w)
{
    if (w == NULL || !w->running) {
        return;
    }
    __atomic_store_n(&w->stop, 1, __ATOMIC_RELEASE);
    __atomic_add_fetch(&w->generation, 1u, __ATOMIC_SEQ_CST);
    futex_wake(&w->generation);
    pthread_join(w->thread, NULL);
    w->running = 0;
}
