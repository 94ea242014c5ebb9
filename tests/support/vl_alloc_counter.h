/**
 * @file vl_alloc_counter.h
 * @brief The heap allocation counter's query API, for a test that links the counter in-process
 *        (tests/support/vl_alloc_counter.c; the daemon tests preload the same file instead).
 */
#ifndef VISLAM_TESTS_VL_ALLOC_COUNTER_H
#define VISLAM_TESTS_VL_ALLOC_COUNTER_H

#include <stdint.h>

/** malloc-family calls (every thread) since the process started. */
uint64_t vl_alloc_counter_allocations(void);

/** free calls with a non-NULL pointer (every thread) since the process started. */
uint64_t vl_alloc_counter_frees(void);

#endif /* VISLAM_TESTS_VL_ALLOC_COUNTER_H */
