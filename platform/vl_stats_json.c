/*
 * Exit statistics as JSON, written the same way by every program that has them.
 */
#include "vl_stats_json.h"

#include <inttypes.h>

void vl_json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s != '\0'; ++s) {
        const unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') {
            fprintf(f, "\\%c", c);
        } else if (c < 0x20) {
            fprintf(f, "\\u%04x", c);
        } else {
            fputc(c, f);
        }
    }
    fputc('"', f);
}

void vl_json_counts(FILE *f, const char *indent, const vl_counter_entry_t *c, size_t n)
{
    for (size_t i = 0; i < n; ++i) {
        fprintf(f, "%s", indent);
        vl_json_string(f, c[i].name);
        fprintf(f, ": %" PRIu64 "%s\n", c[i].value, i + 1 < n ? "," : "");
    }
}

void vl_json_latency(FILE *f, const char *indent, const char *name, const vl_latency_t *t, int last)
{
    fprintf(f, "%s", indent);
    vl_json_string(f, name);
    fprintf(f,
            ": {\"count\": %" PRIu64 ", \"median_us\": %" PRId64 ", \"p90_us\": %" PRId64 ", \"p99_us\": %" PRId64
            ", \"p999_us\": %" PRId64 ", \"max_us\": %" PRId64 ", \"mean_us\": %.1f}%s\n",
            vl_latency_count(t), vl_latency_percentile(t, 50.0), vl_latency_percentile(t, 90.0),
            vl_latency_percentile(t, 99.0), vl_latency_percentile(t, 99.9), vl_latency_max(t), vl_latency_mean(t),
            last ? "" : ",");
}

/* The statuses one core call returned, keyed by vl_status_str. */
static void call_status(FILE *f, const char *indent, const char *name, const vl_session_t *ss, int update, int last)
{
    fprintf(f, "%s  \"%s\": {", indent, name);
    int first = 1;
    for (int s = (int)VL_STATUS_MIN; s <= (int)VL_STATUS_MAX; ++s) {
        const uint64_t v = vl_session_status_count(ss, update, (vl_status_t)s);
        if (v != 0) {
            fprintf(f, "%s", first ? "" : ", ");
            vl_json_string(f, vl_status_str((vl_status_t)s));
            fprintf(f, ": %" PRIu64, v);
            first = 0;
        }
    }
    fprintf(f, "}%s\n", last ? "" : ",");
}

void vl_json_core_status(FILE *f, const char *indent, const vl_session_t *ss)
{
    fprintf(f, "%s\"core_status\": {\n", indent);
    call_status(f, indent, "vl_propagate", ss, 0, 0);
    call_status(f, indent, "vl_update", ss, 1, 1);
    fprintf(f, "%s}", indent);
}
