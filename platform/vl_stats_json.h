/**
 * @file vl_stats_json.h
 * @brief The pieces of a program's exit statistics as JSON (vislam-run --stats-json, vislamd
 *        --stats-json): strings, named counts, a latency histogram's percentiles and the
 *        statuses the core returned, written alike by every program.
 */
#ifndef VISLAM_PLATFORM_VL_STATS_JSON_H
#define VISLAM_PLATFORM_VL_STATS_JSON_H

#include <stddef.h>
#include <stdio.h>

#include "vislam/vislam.h"
#include "vl_latency.h"
#include "vl_session.h"

#ifdef __cplusplus
extern "C" {
#endif

/** s as a JSON string literal (quotes, backslashes and control characters escaped). */
void vl_json_string(FILE *f, const char *s);

/** One `"name": value` line per entry, each after indent, comma-separated. */
void vl_json_counts(FILE *f, const char *indent, const vl_counter_entry_t *c, size_t n);

/**
 * `"name": {"count", "median_us", "p90_us", "p99_us", "p999_us", "max_us", "mean_us"}` on one line
 * after indent, then a comma unless last. Percentiles as vl_latency_percentile gives them (at most
 * 6.25 % above the true value), us.
 */
void vl_json_latency(FILE *f, const char *indent, const char *name, const vl_latency_t *t, int last);

/**
 * `"core_status": {"vl_propagate": {...}, "vl_update": {...}}` after indent, without a trailing
 * comma: for each core call, the statuses it returned (keyed by vl_status_str) and their counts.
 */
void vl_json_core_status(FILE *f, const char *indent, const vl_session_t *ss);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_STATS_JSON_H */
