/*
 * vl_bench_update N K [REPS]: the wall time of one joint update (vl_la_update)
 * with K observations on N states, on a fixed random covariance, the minimum
 * and the mean over REPS calls (default 60). The minimum is the figure to
 * compare on a shared machine: preemption only ever adds time. Prints a
 * checksum of the result so that two builds can be compared for equal bits.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vislam/vislam.h"
#include "vl_clock.h"
#include "vl_linalg.h"

#define LD VL_STATE_DIM_MAX
#define FACTOR_RANK 64

static double P0[LD * LD], P[LD * LD], G[LD * FACTOR_RANK];
static double PHt[LD * VL_OBS_DIM * VL_MAX_LANDMARKS];
static double S[(VL_OBS_DIM * VL_MAX_LANDMARKS) * (VL_OBS_DIM * VL_MAX_LANDMARKS)];
static double dx[LD];
static vl_obs_row_t obs[VL_MAX_LANDMARKS];

/* Uniform in [-0.5, 0.5): a fixed sequence, so every run times the same numbers. */
static double next_uniform(unsigned *state)
{
    *state = *state * 1103515245u + 12345u;
    return (double)((*state >> 8) & 0xffffu) / 65536.0 - 0.5;
}

/* P0 = G G^T + I with G n x FACTOR_RANK: symmetric positive definite, dense. */
static void make_covariance(int n, unsigned *state)
{
    for (int i = 0; i < n * FACTOR_RANK; ++i) {
        G[i] = next_uniform(state);
    }
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
            double a = (i == j) ? 1.0 : 0.0;
            for (int q = 0; q < FACTOR_RANK; ++q) {
                a += G[q * n + i] * G[q * n + j];
            }
            P0[(size_t)j * LD + i] = a;
        }
    }
}

/* k observations spread over the window's landmarks, with random Jacobians. */
static void make_observations(int n, int k, unsigned *state)
{
    const int landmarks = (n - VL_CORE_DIM) / 3;
    for (int o = 0; o < k; ++o) {
        for (int q = 0; q < 18; ++q) {
            obs[o].H_pose[q] = next_uniform(state);
        }
        for (int q = 0; q < 9; ++q) {
            obs[o].H_landmark[q] = next_uniform(state);
        }
        for (int q = 0; q < 3; ++q) {
            obs[o].residual[q] = next_uniform(state);
            obs[o].noise_var[q] = 2.0;
        }
        obs[o].landmark_col = VL_CORE_DIM + 3 * (o % landmarks);
    }
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: vl_bench_update N K [REPS]: N states (%d..%d), K observations (1..%d)\n",
                VL_CORE_DIM + 3, VL_STATE_DIM_MAX, VL_MAX_LANDMARKS);
        return 2;
    }
    const int n = atoi(argv[1]), k = atoi(argv[2]), reps = (argc > 3) ? atoi(argv[3]) : 60;
    if (n < VL_CORE_DIM + 3 || n > VL_STATE_DIM_MAX || (n - VL_CORE_DIM) % 3 != 0 || k < 1 || k > VL_MAX_LANDMARKS ||
        reps < 1) {
        fprintf(stderr, "vl_bench_update: N must be 12 + 3 landmarks, at most %d; K in 1..%d\n", VL_STATE_DIM_MAX,
                VL_MAX_LANDMARKS);
        return 2;
    }
    unsigned state = 1u;
    vl_la_configure();
    make_covariance(n, &state);
    make_observations(n, k, &state);
    const vl_la_workspace_t ws = {PHt, S, dx, NULL, NULL};
    int64_t best = INT64_MAX, total = 0;
    for (int r = 0; r < reps; ++r) {
        memcpy(P, P0, sizeof(double) * (size_t)LD * (size_t)n);
        const int64_t t0 = vl_clock_monotonic_us();
        if (vl_la_update(P, LD, n, obs, k, &ws) != 0) {
            fprintf(stderr, "vl_bench_update: S not positive definite\n");
            return 1;
        }
        const int64_t us = vl_clock_monotonic_us() - t0;
        best = (us < best) ? us : best;
        total += us;
    }
    double checksum = 0.0;
    for (int j = 0; j < n; ++j) {
        checksum += P[(size_t)j * LD + j] + dx[j];
    }
    printf("n %d k %d: min %lld us, mean %.1f us over %d calls (checksum %.17g)\n", n, k, (long long)best,
           (double)total / reps, reps, checksum);
    return 0;
}
