/*
 * vl_bench_update N K [REPS] [--threads 2] [--worker-cpu C]: the wall time of one
 * joint update (vl_la_update) with K observations on N states, on a fixed random
 * covariance, the minimum, median and mean over REPS calls (default 60). The
 * minimum is the figure to compare on a shared machine: preemption only ever
 * adds time. With --threads 2 the update's blocks are shared with a vl_worker
 * (this thread pinned to CPU 1 - C, the worker to C; default C = 0). Prints a
 * checksum of the result so that two builds, or serial and parallel runs, can
 * be compared for equal bits.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vislam/vislam.h"
#include "vl_clock.h"
#include "vl_linalg.h"
#include "vl_random_update.h"
#include "vl_work.h"
#include "vl_rt.h"
#include "vl_worker.h"

#define LD VL_COV_LD
#define MAX_REPS 100000

static double P0[LD * LD], P[LD * LD], G[LD * VL_RANDOM_FACTOR_RANK];
static double PHt[LD * VL_OBS_DIM * VL_MAX_LANDMARKS];
static double S[(VL_OBS_DIM * VL_MAX_LANDMARKS) * (VL_OBS_DIM * VL_MAX_LANDMARKS)];
static double dx[LD];
static vl_obs_row_t obs[VL_MAX_LANDMARKS];
static int64_t times_us[MAX_REPS];
static vl_worker_t worker;

static int cmp_i64(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    int positional[3] = {0, 0, 60}, npos = 0;
    vl_worker_options_t wopt;
    vl_worker_options_default(&wopt);
    for (int i = 1; i < argc; ++i) {
        const int w = vl_worker_parse_option("vl_bench_update", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &wopt);
        if (w < 0) {
            return 2;
        } else if (w > 0) {
            ++i;
        } else if (npos < 3) {
            positional[npos++] = atoi(argv[i]);
        } else {
            npos = 4;
        }
    }
    if (npos < 2 || npos > 3) {
        fprintf(stderr,
                "usage: vl_bench_update N K [REPS] [--threads 2] [--worker-cpu C]: N states (%d..%d), K observations "
                "(1..%d)\n",
                VL_CORE_DIM + 3, VL_STATE_DIM_MAX, VL_MAX_LANDMARKS);
        return 2;
    }
    const int n = positional[0], k = positional[1], reps = positional[2];
    if (n < VL_CORE_DIM + 3 || n > VL_STATE_DIM_MAX || (n - VL_CORE_DIM) % 3 != 0 || k < 1 || k > VL_MAX_LANDMARKS ||
        reps < 1 || reps > MAX_REPS) {
        fprintf(stderr, "vl_bench_update: N must be 12 + 3 landmarks, at most %d; K in 1..%d; REPS in 1..%d\n",
                VL_STATE_DIM_MAX, VL_MAX_LANDMARKS, MAX_REPS);
        return 2;
    }
    char msg[256];
    if (wopt.threads > 1) {
        if (wopt.cpu < 0) {
            wopt.cpu = 0;
        }
        if (vl_rt_set_affinity(wopt.cpu == 0 ? 1 : 0, msg, sizeof(msg)) != VL_RT_OK) {
            fprintf(stderr, "vl_bench_update: warning: %s\n", msg);
        }
    }
    if (vl_worker_start(&worker, &wopt, msg, sizeof(msg)) != 0) {
        fprintf(stderr, "vl_bench_update: warning: %s\n", msg);
    }
    unsigned state = 1u;
    vl_la_configure();
    vl_random_covariance(P0, LD, n, G, &state);
    vl_random_observations(obs, n, k, &state);
    const vl_la_workspace_t ws = {PHt, S, dx, vl_worker_parallel_for, &worker};
    int64_t total = 0;
    for (int r = 0; r < reps; ++r) {
        memcpy(P, P0, sizeof(double) * (size_t)LD * (size_t)n);
        const int64_t t0 = vl_clock_monotonic_us();
        if (vl_la_update(P, LD, n, obs, k, &ws, NULL) != 0) {
            fprintf(stderr, "vl_bench_update: S not positive definite\n");
            return 1;
        }
        times_us[r] = vl_clock_monotonic_us() - t0;
        total += times_us[r];
    }
    uint64_t loops = 0, tasks = 0, worker_tasks = 0;
    vl_worker_counts(&worker, &loops, &tasks, &worker_tasks);
    vl_worker_stop(&worker);
    qsort(times_us, (size_t)reps, sizeof(times_us[0]), cmp_i64);
    double checksum = 0.0;
    for (int j = 0; j < n; ++j) {
        checksum += P[(size_t)j * LD + j] + dx[j];
    }
    printf("n %d k %d, %d thread(s): min %lld us, median %lld us, mean %.1f us over %d calls; %.3g Mflop; worker ran "
           "%llu of %llu blocks (checksum %.17g)\n",
           n, k, wopt.threads, (long long)times_us[0], (long long)times_us[reps / 2], (double)total / reps, reps,
           (double)vl_work_joint_update((uint32_t)n, (uint32_t)k) * 1e-6, (unsigned long long)worker_tasks,
           (unsigned long long)tasks, checksum);
    return 0;
}
