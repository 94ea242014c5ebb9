#define _GNU_SOURCE /* pthread_attr_setaffinity_np, SCHED_IDLE, CPU_SET */

#include "vl_awake.h"

#include <sched.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

static void *spin_main(void *p)
{
    vl_awake_t *a = (vl_awake_t *)p;
    uint64_t n = 0;
    /* A relaxed store, not an atomic add: a plain move on x86, so the loop stays a pause and a
       load; readers only want to see the count grow. */
    while (!__atomic_load_n(&a->stop, __ATOMIC_ACQUIRE)) {
        vl_cpu_relax();
        __atomic_store_n(&a->loops, ++n, __ATOMIC_RELAXED);
    }
    return NULL;
}

int vl_awake_start(vl_awake_t *a, int cpu, char *msg, size_t msg_len)
{
    char scratch[1];
    if (msg == NULL || msg_len == 0) {
        msg = scratch;
        msg_len = sizeof(scratch);
    }
    memset(a, 0, sizeof(*a));
    a->cpu = cpu;
    const long ncpu = sysconf(_SC_NPROCESSORS_CONF);
    if (cpu < 0 || cpu >= CPU_SETSIZE || (ncpu > 0 && cpu >= ncpu)) {
        snprintf(msg, msg_len, "keep awake: CPU %d outside 0..%ld", cpu, ncpu > 0 ? ncpu - 1 : (long)CPU_SETSIZE - 1);
        return -1;
    }
    /* Pinned before it runs (the attribute), at SCHED_OTHER rather than the caller's SCHED_FIFO
       until it is made SCHED_IDLE below (glibc's attributes take no SCHED_IDLE). */
    pthread_attr_t attr;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    struct sched_param sp;
    memset(&sp, 0, sizeof(sp));
    int rc = pthread_attr_init(&attr);
    if (rc == 0) {
        rc = pthread_attr_setaffinity_np(&attr, sizeof(set), &set);
        rc = rc != 0 ? rc : pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
        rc = rc != 0 ? rc : pthread_attr_setschedpolicy(&attr, SCHED_OTHER);
        rc = rc != 0 ? rc : pthread_attr_setschedparam(&attr, &sp);
        rc = rc != 0 ? rc : pthread_attr_setstacksize(&attr, VL_AWAKE_STACK_BYTES);
        rc = rc != 0 ? rc : pthread_create(&a->thread, &attr, spin_main, a);
        pthread_attr_destroy(&attr);
    }
    if (rc != 0) {
        snprintf(msg, msg_len, "keep awake: cannot start a thread on CPU %d: %s (outside this process's cpuset?)", cpu,
                 strerror(rc));
        return -1;
    }
    a->running = 1;
    rc = pthread_setschedparam(a->thread, SCHED_IDLE, &sp);
    if (rc != 0) {
        vl_awake_stop(a);
        snprintf(msg, msg_len, "keep awake: cannot make the thread on CPU %d SCHED_IDLE: %s", cpu, strerror(rc));
        return -1;
    }
    snprintf(msg, msg_len, "keep awake: a SCHED_IDLE thread spinning on CPU %d", cpu);
    return 0;
}

int vl_awake_running(const vl_awake_t *a)
{
    return a != NULL && a->running;
}

uint64_t vl_awake_loops(const vl_awake_t *a)
{
    return a != NULL ? __atomic_load_n(&a->loops, __ATOMIC_RELAXED) : 0;
}

void vl_awake_stop(vl_awake_t *a)
{
    if (a == NULL || !a->running) {
        return;
    }
    __atomic_store_n(&a->stop, 1, __ATOMIC_RELEASE);
    pthread_join(a->thread, NULL);
    a->running = 0;
}
