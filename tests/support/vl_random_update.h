/**
 * @file vl_random_update.h
 * @brief A fixed random joint update: covariance and observations (vl_bench_update, test_worker,
 *        test_estimator).
 */
#ifndef VISLAM_TESTS_VL_RANDOM_UPDATE_H
#define VISLAM_TESTS_VL_RANDOM_UPDATE_H

#include "vislam/vislam.h"

/** Rank of the random factor of the covariance. */
#define VL_RANDOM_FACTOR_RANK 64

/** Uniform in [-0.5, 0.5): a fixed sequence from *state, so every run draws the same numbers. */
static inline double vl_random_uniform(unsigned *state)
{
    *state = *state * 1103515245u + 12345u;
    return (double)((*state >> 8) & 0xffffu) / 65536.0 - 0.5;
}

/**
 * P = G G^T + I (n x n, column-major, leading dimension ld) with G n x VL_RANDOM_FACTOR_RANK
 * random: symmetric positive definite and dense. @p G holds n * VL_RANDOM_FACTOR_RANK doubles.
 */
static inline void vl_random_covariance(double *P, int ld, int n, double *G, unsigned *state)
{
    for (int i = 0; i < n * VL_RANDOM_FACTOR_RANK; ++i) {
        G[i] = vl_random_uniform(state);
    }
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
            double a = (i == j) ? 1.0 : 0.0;
            for (int q = 0; q < VL_RANDOM_FACTOR_RANK; ++q) {
                a += G[q * n + i] * G[q * n + j];
            }
            P[(size_t)j * (size_t)ld + (size_t)i] = a;
        }
    }
}

/** k observations spread over the window's landmarks of an n-state covariance, with random Jacobians. */
static inline void vl_random_observations(vl_obs_row_t *obs, int n, int k, unsigned *state)
{
    const int landmarks = (n - VL_CORE_DIM) / 3;
    for (int o = 0; o < k; ++o) {
        for (int q = 0; q < 18; ++q) {
            obs[o].H_pose[q] = vl_random_uniform(state);
        }
        for (int q = 0; q < 9; ++q) {
            obs[o].H_landmark[q] = vl_random_uniform(state);
        }
        for (int q = 0; q < 3; ++q) {
            obs[o].residual[q] = vl_random_uniform(state);
            obs[o].noise_var[q] = 2.0;
        }
        obs[o].landmark_col = VL_CORE_DIM + 3 * (o % landmarks);
    }
}

#endif /* VISLAM_TESTS_VL_RANDOM_UPDATE_H */
