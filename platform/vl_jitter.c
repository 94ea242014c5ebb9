#define _GNU_SOURCE /* pthread_setaffinity_np, CPU_SET */

#include "vl_jitter.h"

#include <pthread.h>
#include <sched.h>
#include <string.h>
#include <time.h>

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static void *probe_main(void *arg)
{
    vl_jitter_probe_t *p = (vl_jitter_probe_t *)arg;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(p->cpu, &set);
    p->pinned = pthread_setaffinity_np(pthread_self(), sizeof(set), &set) == 0;
    if (p->priority > 0) {
        struct sched_param sp;
        memset(&sp, 0, sizeof(sp));
        sp.sched_priority = p->priority;
        p->fifo = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
    }
    const int64_t period_ns = (int64_t)VL_JITTER_PERIOD_US * 1000;
    int64_t deadline = now_ns() + period_ns;
    while (!*p->stop) {
        struct timespec ts;
        ts.tv_sec = (time_t)(deadline / 1000000000);
        ts.tv_nsec = (long)(deadline % 1000000000);
        if (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) != 0) {
            continue; /* a signal: sleep again to the same deadline */
        }
        const int64_t late_ns = now_ns() - deadline;
        vl_latency_record(&p->late, (late_ns + 500) / 1000);
        deadline += period_ns;
        /* After a long stall, resume the schedule rather than count every missed tick. */
        const int64_t now = now_ns();
        if (deadline < now) {
            deadline = now + period_ns;
        }
    }
    return NULL;
}

int vl_jitter_start(vl_jitter_t *j, int cpus, int priority)
{
    memset(j, 0, sizeof(*j));
    if (cpus > VL_JITTER_MAX_CPUS) {
        cpus = VL_JITTER_MAX_CPUS;
    }
    for (int c = 0; c < cpus; ++c) {
        vl_jitter_probe_t *p = &j->probes[j->count];
        p->cpu = c;
        p->priority = priority;
        p->stop = &j->stop;
        vl_latency_reset(&p->late);
        if (pthread_create(&p->thread, NULL, probe_main, p) != 0) {
            break;
        }
        p->running = 1;
        j->count++;
    }
    return j->count;
}

void vl_jitter_stop(vl_jitter_t *j)
{
    j->stop = 1;
    for (int i = 0; i < j->count; ++i) {
        if (j->probes[i].running) {
            pthread_join(j->probes[i].thread, NULL);
            j->probes[i].running = 0;
        }
    }
}

void vl_jitter_merged(const vl_jitter_t *j, vl_latency_t *out)
{
    vl_latency_reset(out);
    for (int i = 0; i < j->count; ++i) {
        const vl_latency_t *h = &j->probes[i].late;
        if (h->count == 0) {
            continue;
        }
        for (size_t b = 0; b < VL_LATENCY_BUCKETS; ++b) {
            out->buckets[b] += h->buckets[b];
        }
        out->overflow += h->overflow;
        out->min = (out->count == 0 || h->min < out->min) ? h->min : out->min;
        out->max = h->max > out->max ? h->max : out->max;
        out->count += h->count;
        out->sum += h->sum;
    }
}
