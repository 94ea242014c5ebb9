/*
 * vislam-run: runs the estimator over an LCM log as fast as possible.
 *
 * Outputs (trajectory, map, stats JSON without --timing) depend only on the
 * log and the configuration: the core never reads a clock, and wall-clock
 * timing is printed to stderr only.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "vislam/vislam.h"
#include "vl_config_file.h"
#include "vl_log_reader.h"
#include "vl_msg.h"
#include "vl_trajectory_file.h"

#define EXIT_USAGE 2
#define EXIT_LOG_DAMAGED 3

/* Damage reports printed before only the counts are kept. */
#define DAMAGE_REPORTS 5

/* Statuses run from VL_ERR_CAPACITY (-7) to VL_FRAME_TRUNCATED (1). */
#define STATUS_MIN ((int)VL_STATUS_MIN)
#define STATUS_MAX ((int)VL_STATUS_MAX)
#define STATUS_SLOTS (STATUS_MAX - STATUS_MIN + 1)

/* Core log lines printed per level before rate limiting kicks in, then one in this many. */
#define LOG_BURST 20
#define LOG_EVERY 1000

typedef struct {
    const char *log_path;
    const char *trajectory_path;
    const char *map_path;
    const char *config_path;
    const char *stats_path;
    const char *covariance_path;
    const char *mode;
    const char *preset;
    const char *max_landmarks;
    int quiet;
    int timing;
    int print_config;
} options_t;

/* Compact map entry: what the PLY needs. */
typedef struct {
    int32_t id;
    float position[3];
    float sigma;
    uint32_t observations;
    int64_t first_utime;
} map_point_t;

typedef struct {
    map_point_t *points;
    size_t count;
    size_t capacity;
    int oom;
} map_t;

typedef struct {
    double *us;
    size_t count;
    size_t capacity;
} samples_t;

typedef struct {
    int quiet;
    uint64_t seen[4];
    uint64_t suppressed;
} logger_t;

typedef struct {
    uint64_t imu_processed;            /* IMU events handed to vl_propagate */
    uint64_t frames_processed;         /* frames handed to vl_update */
    uint64_t trajectory_lines;         /* accepted frames written */
    uint64_t imu_before_calibration;   /* skipped: no calibration yet */
    uint64_t frames_before_calibration;/* skipped (an error): no calibration yet */
    uint64_t calibrations_used;        /* calibration messages that (re)initialized the estimator */
    uint64_t calibrations_ignored;     /* repeats, or the config file overrides the log */
    uint64_t calibrations_changed;     /* a different calibration after inputs: ignored */
    uint64_t calibrations_invalid;     /* rejected by vl_config_check */
    uint64_t propagate_status[STATUS_SLOTS];
    uint64_t update_status[STATUS_SLOTS];
} run_stats_t;

static const char *status_name(int status)
{
    switch (status) {
    case VL_OK:
        return "VL_OK";
    case VL_FRAME_TRUNCATED:
        return "VL_FRAME_TRUNCATED";
    case VL_ERR_NULL:
        return "VL_ERR_NULL";
    case VL_ERR_CONFIG:
        return "VL_ERR_CONFIG";
    case VL_ERR_NOT_READY:
        return "VL_ERR_NOT_READY";
    case VL_ERR_NON_FINITE:
        return "VL_ERR_NON_FINITE";
    case VL_ERR_TIME_ORDER:
        return "VL_ERR_TIME_ORDER";
    case VL_ERR_NOT_POSITIVE_DEFINITE:
        return "VL_ERR_NOT_POSITIVE_DEFINITE";
    case VL_ERR_CAPACITY:
        return "VL_ERR_CAPACITY";
    case VL_ERR_MISALIGNED:
        return "VL_ERR_MISALIGNED";
    case VL_RESET:
        return "VL_RESET";
    case VL_ERR_TIME_JUMP:
        return "VL_ERR_TIME_JUMP";
    case VL_ERR_IMPLAUSIBLE:
        return "VL_ERR_IMPLAUSIBLE";
    case VL_ERR_IMU_SILENT:
        return "VL_ERR_IMU_SILENT";
    }
    return "VL_STATUS_UNKNOWN";
}

static void count_status(uint64_t *slots, vl_status_t status)
{
    int s = (int)status;
    if (s < STATUS_MIN || s > STATUS_MAX) {
        s = STATUS_MIN; /* an unknown status: keep the count rather than drop it */
    }
    slots[s - STATUS_MIN]++;
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: vislam-run LOG --trajectory OUT.tum [options]\n"
            "Runs the vislam estimator over an LCM log (channels VISLAM_IMU, VISLAM_FEATURES,\n"
            "VISLAM_CALIB) as fast as possible; same log and options -> byte-identical outputs.\n"
            "\n"
            "  --trajectory FILE    TUM trajectory, one line per accepted frame:\n"
            "                       time tx ty tz qx qy qz qw (IMU frame in world, time in s)\n"
            "  --map FILE           ASCII PLY of the marginalized landmarks\n"
            "                       (x y z id sigma observations first_time)\n"
            "  --covariance FILE    the pose covariance's diagonal, one line per trajectory line:\n"
            "                       time var_rho_x var_rho_y var_rho_z var_phi_x var_phi_y var_phi_z\n"
            "                       (body-frame right perturbation, m^2 and rad^2, see vislam.h)\n"
            "  --config FILE        INI configuration on top of the defaults (see tools/vislam.ini)\n"
            "  --preset NAME        default|seed: start from this preset (conflicts with a different\n"
            "                       [estimator] preset in the config file)\n"
            "  --mode MODE          imu_only|mapping|slam (overrides the config file)\n"
            "  --max-landmarks N    active window, 1..%d (overrides the config file)\n"
            "  --stats-json FILE    counters (and timing with --timing) as JSON\n"
            "  --timing             per-step wall time of vl_update and vl_propagate on stderr\n"
            "  --quiet              no summary and no core warnings on stderr\n"
            "  --print-config       print the effective configuration (INI) to stdout and exit\n"
            "  --help               this text\n"
            "\n"
            "Every event header is checked before it is read: a damaged spot (bad sync word, absurd\n"
            "length, junk) is reported with its file offset and skipped to the next valid event.\n"
            "\n"
            "Exit status: 0 done, 1 I/O error or no frame processed, 2 usage or configuration error,\n"
            "3 the log is damaged (unreadable spots, a cut end, payloads that do not decode, or no\n"
            "event at all); the outputs then hold every event that could be read.\n",
            VL_MAX_LANDMARKS);
}

static int parse_args(int argc, char **argv, options_t *o)
{
    memset(o, 0, sizeof(*o));
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char **target = NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(0);
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
        } else if (strcmp(a, "--timing") == 0) {
            o->timing = 1;
        } else if (strcmp(a, "--print-config") == 0) {
            o->print_config = 1;
        } else if (strcmp(a, "--trajectory") == 0) {
            target = &o->trajectory_path;
        } else if (strcmp(a, "--map") == 0) {
            target = &o->map_path;
        } else if (strcmp(a, "--config") == 0) {
            target = &o->config_path;
        } else if (strcmp(a, "--covariance") == 0) {
            target = &o->covariance_path;
        } else if (strcmp(a, "--stats-json") == 0) {
            target = &o->stats_path;
        } else if (strcmp(a, "--mode") == 0) {
            target = &o->mode;
        } else if (strcmp(a, "--preset") == 0) {
            target = &o->preset;
        } else if (strcmp(a, "--max-landmarks") == 0) {
            target = &o->max_landmarks;
        } else if (a[0] == '-' && a[1] != '\0') {
            fprintf(stderr, "vislam-run: unknown option %s (see --help)\n", a);
            return -1;
        } else if (o->log_path == NULL) {
            o->log_path = a;
        } else {
            fprintf(stderr, "vislam-run: more than one log given (%s, %s)\n", o->log_path, a);
            return -1;
        }
        if (target != NULL) {
            if (i + 1 >= argc) {
                fprintf(stderr, "vislam-run: %s needs a value\n", a);
                return -1;
            }
            *target = argv[++i];
        }
    }
    if (o->print_config) {
        return 0;
    }
    if (o->log_path == NULL || o->trajectory_path == NULL) {
        fprintf(stderr, "vislam-run: a LOG and --trajectory FILE are required (see --help)\n");
        return -1;
    }
    return 0;
}

/* ---- core callbacks ---- */

static void map_sink(void *user, const vl_landmark_t *lm)
{
    map_t *m = (map_t *)user;
    if (m->count == m->capacity) {
        size_t cap = m->capacity == 0 ? 1024 : 2 * m->capacity;
        map_point_t *p = (map_point_t *)realloc(m->points, cap * sizeof(*p));
        if (p == NULL) {
            m->oom = 1;
            return;
        }
        m->points = p;
        m->capacity = cap;
    }
    map_point_t *pt = &m->points[m->count++];
    pt->id = lm->id;
    for (int i = 0; i < 3; ++i) {
        pt->position[i] = (float)lm->position[i];
    }
    double trace = lm->covariance[0] + lm->covariance[4] + lm->covariance[8];
    pt->sigma = (float)sqrt(trace > 0.0 ? trace : 0.0);
    pt->observations = lm->observations;
    pt->first_utime = lm->first_utime;
}

static const char *level_name(vl_log_level_t level)
{
    switch (level) {
    case VL_LOG_DEBUG:
        return "DEBUG";
    case VL_LOG_INFO:
        return "INFO";
    case VL_LOG_WARN:
        return "WARN";
    case VL_LOG_ERROR:
        return "ERROR";
    }
    return "?";
}

static void core_log(void *user, vl_log_level_t level, int64_t utime, const char *message)
{
    logger_t *lg = (logger_t *)user;
    if (level < VL_LOG_WARN || (lg->quiet && level < VL_LOG_ERROR)) {
        return;
    }
    int l = (int)level & 3;
    uint64_t n = ++lg->seen[l];
    /* Rate limit by count, not by wall time, so what is printed is reproducible too. */
    if (n > LOG_BURST && n % LOG_EVERY != 0) {
        lg->suppressed++;
        return;
    }
    fprintf(stderr, "vislam-run: core %s at utime %lld: %s%s\n", level_name(level), (long long)utime,
            message != NULL ? message : "", n > LOG_BURST ? " (rate limited)" : "");
}

/* ---- timing ---- */

static double now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec * 1e-3;
}

static void samples_add(samples_t *s, double us)
{
    if (s->count == s->capacity) {
        size_t cap = s->capacity == 0 ? 4096 : 2 * s->capacity;
        double *p = (double *)realloc(s->us, cap * sizeof(*p));
        if (p == NULL) {
            return; /* timing is best effort */
        }
        s->us = p;
        s->capacity = cap;
    }
    s->us[s->count++] = us;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a;
    double y = *(const double *)b;
    return (x > y) - (x < y);
}

typedef struct {
    size_t count;
    double median, p99, p999, max;
} timing_summary_t;

/* Nearest-rank percentile of sorted samples. */
static double percentile(const double *sorted, size_t n, double q)
{
    if (n == 0) {
        return 0.0;
    }
    size_t rank = (size_t)ceil(q * (double)n);
    if (rank < 1) {
        rank = 1;
    }
    if (rank > n) {
        rank = n;
    }
    return sorted[rank - 1];
}

static timing_summary_t summarize(samples_t *s)
{
    timing_summary_t t;
    memset(&t, 0, sizeof(t));
    t.count = s->count;
    if (s->count == 0) {
        return t;
    }
    qsort(s->us, s->count, sizeof(double), cmp_double);
    t.median = percentile(s->us, s->count, 0.5);
    t.p99 = percentile(s->us, s->count, 0.99);
    t.p999 = percentile(s->us, s->count, 0.999);
    t.max = s->us[s->count - 1];
    return t;
}

/* ---- outputs ---- */

/* One line per pose: the time exactly as the TUM writer prints it, so the two files pair by
   time, then the diagonal of the 6x6 pose covariance. Write errors are found by ferror at close. */
static void write_covariance_line(FILE *f, int64_t utime, const vl_pose_t *pose)
{
    const char *sign = utime < 0 ? "-" : "";
    const uint64_t mag = utime < 0 ? (uint64_t)0 - (uint64_t)utime : (uint64_t)utime;
    fprintf(f, "%s%llu.%06llu", sign, (unsigned long long)(mag / 1000000u), (unsigned long long)(mag % 1000000u));
    for (int i = 0; i < 6; ++i) {
        fprintf(f, " %.9g", pose->covariance[i * 6 + i]);
    }
    fputc('\n', f);
}

static int write_ply(const char *path, const map_t *m)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-run: cannot write map %s: %s\n", path, strerror(errno));
        return -1;
    }
    fprintf(f,
            "ply\n"
            "format ascii 1.0\n"
            "comment vislam-run map: marginalized landmarks, world frame, m; sigma = sqrt(trace(cov))\n"
            "element vertex %zu\n"
            "property float x\n"
            "property float y\n"
            "property float z\n"
            "property int id\n"
            "property float sigma\n"
            "property uint observations\n"
            "property double first_time\n"
            "end_header\n",
            m->count);
    for (size_t i = 0; i < m->count; ++i) {
        const map_point_t *p = &m->points[i];
        fprintf(f, "%.9g %.9g %.9g %d %.9g %u %lld.%06lld\n", (double)p->position[0], (double)p->position[1],
                (double)p->position[2], (int)p->id, (double)p->sigma, (unsigned)p->observations,
                (long long)(p->first_utime / 1000000), (long long)(p->first_utime % 1000000));
    }
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-run: write error on map %s\n", path);
        return -1;
    }
    return 0;
}

static void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s != '\0'; ++s) {
        unsigned char c = (unsigned char)*s;
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

typedef struct {
    const char *name;
    uint64_t value;
} named_count_t;

/* The core counters in declaration order. */
static size_t core_counter_list(const vl_counters_t *c, named_count_t *out)
{
    vl_counter_entry_t entries[VL_NUM_COUNTERS];
    const size_t n = vl_counters_list(c, entries);
    for (size_t i = 0; i < n; ++i) {
        out[i].name = entries[i].name;
        out[i].value = entries[i].value;
    }
    return n;
}

static size_t run_counter_list(const run_stats_t *r, const vl_log_reader_stats_t *rs, int truncated,
                               named_count_t *out)
{
    size_t n = 0;
#define RUN_COUNT(label, expr) out[n].name = label, out[n].value = (uint64_t)(expr), ++n
    RUN_COUNT("log_events", rs->events);
    RUN_COUNT("log_imu", rs->imu);
    RUN_COUNT("log_frames", rs->frames);
    RUN_COUNT("log_calibrations", rs->calibrations);
    RUN_COUNT("log_decode_errors", rs->decode_errors);
    RUN_COUNT("log_skipped_channels", rs->skipped);
    RUN_COUNT("log_corrupt", rs->corrupt);
    RUN_COUNT("log_bytes_skipped", rs->bytes_skipped);
    RUN_COUNT("log_truncated", truncated);
    RUN_COUNT("imu_processed", r->imu_processed);
    RUN_COUNT("frames_processed", r->frames_processed);
    RUN_COUNT("trajectory_lines", r->trajectory_lines);
    RUN_COUNT("imu_before_calibration", r->imu_before_calibration);
    RUN_COUNT("frames_before_calibration", r->frames_before_calibration);
    RUN_COUNT("calibrations_used", r->calibrations_used);
    RUN_COUNT("calibrations_ignored", r->calibrations_ignored);
    RUN_COUNT("calibrations_changed", r->calibrations_changed);
    RUN_COUNT("calibrations_invalid", r->calibrations_invalid);
#undef RUN_COUNT
    return n;
}

static void json_counts(FILE *f, const char *indent, const named_count_t *c, size_t n)
{
    for (size_t i = 0; i < n; ++i) {
        fprintf(f, "%s\"%s\": %llu%s\n", indent, c[i].name, (unsigned long long)c[i].value, i + 1 < n ? "," : "");
    }
}

static void json_status(FILE *f, const char *name, const uint64_t *slots, int last)
{
    fprintf(f, "    \"%s\": {", name);
    int first = 1;
    for (int s = STATUS_MIN; s <= STATUS_MAX; ++s) {
        uint64_t v = slots[s - STATUS_MIN];
        if (v != 0) {
            fprintf(f, "%s\"%s\": %llu", first ? "" : ", ", status_name(s), (unsigned long long)v);
            first = 0;
        }
    }
    fprintf(f, "}%s\n", last ? "" : ",");
}

static void json_timing(FILE *f, const char *name, const timing_summary_t *t, int last)
{
    fprintf(f,
            "    \"%s\": {\"count\": %zu, \"median_us\": %.3f, \"p99_us\": %.3f, \"p999_us\": %.3f, "
            "\"max_us\": %.3f}%s\n",
            name, t->count, t->median, t->p99, t->p999, t->max, last ? "" : ",");
}

static int write_stats_json(const char *path, const options_t *o, const vl_config_t *cfg, const char *calib_source,
                            const run_stats_t *run, const vl_log_reader_stats_t *rs, int truncated,
                            const vl_counters_t *counters, size_t landmarks_mapped, const timing_summary_t *t_update,
                            const timing_summary_t *t_propagate)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-run: cannot write stats %s: %s\n", path, strerror(errno));
        return -1;
    }
    named_count_t list[32];
    fprintf(f, "{\n  \"log\": ");
    json_string(f, o->log_path);
    fprintf(f, ",\n  \"mode\": \"%s\",\n  \"max_landmarks\": %u,\n", vl_mode_name(cfg->mode),
            (unsigned)cfg->max_landmarks);
    fprintf(f, "  \"calibration_source\": \"%s\",\n", calib_source);
    fprintf(f, "  \"landmarks_mapped\": %zu,\n", landmarks_mapped);
    fprintf(f, "  \"run\": {\n");
    json_counts(f, "    ", list, run_counter_list(run, rs, truncated, list));
    fprintf(f, "  },\n  \"core_counters\": {\n");
    json_counts(f, "    ", list, core_counter_list(counters, list));
    fprintf(f, "  },\n  \"core_status\": {\n");
    json_status(f, "vl_propagate", run->propagate_status, 0);
    json_status(f, "vl_update", run->update_status, 1);
    fprintf(f, "  }");
    if (o->timing) {
        fprintf(f, ",\n  \"timing\": {\n");
        json_timing(f, "vl_update", t_update, 0);
        json_timing(f, "vl_propagate", t_propagate, 1);
        fprintf(f, "  }");
    }
    fprintf(f, "\n}\n");
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-run: write error on stats %s\n", path);
        return -1;
    }
    return 0;
}

/* ---- configuration ---- */

static int build_config(const options_t *o, vl_config_t *cfg, vl_config_file_info_t *info)
{
    vl_config_default(cfg);
    memset(info, 0, sizeof(*info));
    info->preset = VL_PRESET_NONE;
    vl_preset_t cli_preset = VL_PRESET_NONE;
    if (o->preset != NULL) {
        if (vl_preset_from_name(o->preset, &cli_preset) != 0) {
            fprintf(stderr, "vislam-run: --preset %s: expected default or seed\n", o->preset);
            return -1;
        }
        vl_config_apply_preset(cfg, cli_preset);
    }
    if (o->config_path != NULL) {
        char err[512];
        if (vl_config_load_ini_ex(o->config_path, cfg, info, err, sizeof(err)) != VL_OK) {
            fprintf(stderr, "vislam-run: %s\n", err);
            return -1;
        }
        if (cli_preset != VL_PRESET_NONE && info->preset != VL_PRESET_NONE && info->preset != cli_preset) {
            fprintf(stderr, "vislam-run: --preset %s conflicts with preset = %s in %s\n", o->preset,
                    vl_preset_name(info->preset), o->config_path);
            return -1;
        }
    }
    if (o->mode != NULL && vl_mode_from_name(o->mode, &cfg->mode) != 0) {
        fprintf(stderr, "vislam-run: --mode %s: expected imu_only, mapping or slam\n", o->mode);
        return -1;
    }
    if (o->max_landmarks != NULL) {
        char *end = NULL;
        errno = 0;
        long n = strtol(o->max_landmarks, &end, 10);
        if (end == o->max_landmarks || *end != '\0' || errno != 0 || n < 1 || n > VL_MAX_LANDMARKS) {
            fprintf(stderr, "vislam-run: --max-landmarks %s: expected an integer in 1..%d\n", o->max_landmarks,
                    VL_MAX_LANDMARKS);
            return -1;
        }
        cfg->max_landmarks = (uint32_t)n;
    }
    return 0;
}

/* ---- main ---- */

int main(int argc, char **argv)
{
    options_t o;
    if (parse_args(argc, argv, &o) != 0) {
        return EXIT_USAGE;
    }
    vl_config_t cfg;
    vl_config_file_info_t info;
    if (build_config(&o, &cfg, &info) != 0) {
        return EXIT_USAGE;
    }
    if (o.print_config) {
        vl_config_write_ini(stdout, &cfg, info.has_calibration);
        return 0;
    }

    static map_t map;
    static logger_t logger;
    static run_stats_t run;
    static samples_t t_update;
    static samples_t t_propagate;
    static vl_log_reader_t reader;
    static vl_log_event_t ev;

    logger.quiet = o.quiet;
    cfg.landmark_sink = map_sink;
    cfg.landmark_sink_user = &map;
    cfg.log = core_log;
    cfg.log_user = &logger;

    /* Several MB: heap, once. */
    /* aligned as vl_init requires: see VL_ESTIMATOR_ALIGN */
    const size_t est_bytes = (sizeof(vl_estimator_t) + VL_ESTIMATOR_ALIGN - 1) / VL_ESTIMATOR_ALIGN * VL_ESTIMATOR_ALIGN;
    void *est_mem = NULL;
    vl_estimator_t *est = NULL;
    if (posix_memalign(&est_mem, VL_ESTIMATOR_ALIGN, est_bytes) == 0) {
        memset(est_mem, 0, est_bytes);
        est = (vl_estimator_t *)est_mem;
    }
    if (est == NULL) {
        fprintf(stderr, "vislam-run: cannot allocate the estimator (%zu bytes)\n", sizeof(*est));
        return 1;
    }

    char err[512];
    if (vl_log_reader_open(&reader, o.log_path, NULL, err, sizeof(err)) != 0) {
        fprintf(stderr, "vislam-run: %s\n", err);
        free(est);
        return 1;
    }
    /* The writer vislamd uses too, so both programs print identical lines. */
    static vl_trajectory_file_t traj;
    if (vl_trajectory_open(&traj, o.trajectory_path, err, sizeof(err)) != 0) {
        fprintf(stderr, "vislam-run: %s\n", err);
        vl_log_reader_close(&reader);
        free(est);
        return 1;
    }

    FILE *cov_file = NULL;
    if (o.covariance_path != NULL) {
        cov_file = fopen(o.covariance_path, "w");
        if (cov_file == NULL) {
            fprintf(stderr, "vislam-run: cannot write covariance %s: %s\n", o.covariance_path, strerror(errno));
            vl_trajectory_close(&traj);
            vl_log_reader_close(&reader);
            free(est);
            return 1;
        }
    }

    int initialized = 0;
    int inputs_fed = 0; /* once inputs reached the estimator, a new calibration cannot restart it */
    const char *calib_source = "none";
    if (info.has_calibration) {
        /* The file's rig is used from the start; unless override_log, a log calibration
           that arrives before any input replaces it. */
        if (vl_init(est, &cfg) != VL_OK) {
            fprintf(stderr, "vislam-run: vl_init refused the configuration\n");
            if (cov_file != NULL) {
                fclose(cov_file);
            }
            vl_trajectory_close(&traj);
            vl_log_reader_close(&reader);
            free(est);
            return EXIT_USAGE;
        }
        initialized = 1;
        calib_source = "config";
    }

    vl_log_event_kind_t kind;
    while ((kind = vl_log_reader_next(&reader, &ev)) != VL_LOG_EVENT_END) {
        switch (kind) {
        case VL_LOG_EVENT_CALIBRATION: {
            if (info.override_log) {
                run.calibrations_ignored++;
                break;
            }
            if (initialized && vl_calibration_equal(&cfg.calibration, &ev.calibration)) {
                /* Nothing to redo; the first one still counts as the rig's source. */
                if (strcmp(calib_source, "log") != 0) {
                    calib_source = "log";
                    run.calibrations_used++;
                } else {
                    run.calibrations_ignored++;
                }
                break;
            }
            if (inputs_fed) {
                run.calibrations_changed++;
                if (!o.quiet && run.calibrations_changed == 1) {
                    fprintf(stderr, "vislam-run: event %lld: calibration changed after inputs; ignored\n",
                            (long long)ev.event_number);
                }
                break;
            }
            vl_config_t candidate = cfg;
            candidate.calibration = ev.calibration;
            if (vl_config_check(&candidate) != VL_OK || vl_init(est, &candidate) != VL_OK) {
                run.calibrations_invalid++;
                fprintf(stderr, "vislam-run: event %lld: calibration message rejected by vl_config_check\n",
                        (long long)ev.event_number);
                break;
            }
            cfg = candidate;
            initialized = 1;
            calib_source = "log";
            run.calibrations_used++;
            break;
        }
        case VL_LOG_EVENT_IMU: {
            if (!initialized) {
                run.imu_before_calibration++;
                break;
            }
            inputs_fed = 1;
            double t0 = o.timing ? now_us() : 0.0;
            vl_status_t s = vl_propagate(est, &ev.imu);
            if (o.timing) {
                samples_add(&t_propagate, now_us() - t0);
            }
            count_status(run.propagate_status, s);
            run.imu_processed++;
            break;
        }
        case VL_LOG_EVENT_FRAME: {
            if (!initialized) {
                run.frames_before_calibration++;
                if (run.frames_before_calibration == 1) {
                    fprintf(stderr, "vislam-run: event %lld: frame before any calibration; skipped\n",
                            (long long)ev.event_number);
                }
                break;
            }
            inputs_fed = 1;
            double t0 = o.timing ? now_us() : 0.0;
            vl_status_t s = vl_update(est, &ev.frame);
            if (o.timing) {
                samples_add(&t_update, now_us() - t0);
            }
            count_status(run.update_status, s);
            run.frames_processed++;
            if (s >= 0) { /* used: VL_OK, or an event (truncated, re-initialized) */
                vl_pose_t pose;
                if (vl_get_pose(est, &pose) == VL_OK) {
                    vl_trajectory_write(&traj, ev.frame.utime, &pose);
                    if (cov_file != NULL) {
                        write_covariance_line(cov_file, ev.frame.utime, &pose);
                    }
                    run.trajectory_lines++;
                }
            }
            break;
        }
        case VL_LOG_EVENT_DECODE_ERROR: {
            const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
            if (rs->decode_errors <= DAMAGE_REPORTS) {
                fprintf(stderr, "vislam-run: %s\n", ev.error);
            }
            break;
        }
        case VL_LOG_EVENT_CORRUPT: {
            const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
            if (rs->corrupt <= DAMAGE_REPORTS) {
                fprintf(stderr, "vislam-run: %s: %s\n", o.log_path, ev.error);
            }
            break;
        }
        case VL_LOG_EVENT_END:
            break;
        }
    }
    if (initialized) {
        vl_flush_landmarks(est);
    }

    int io_error = 0;
    if (vl_trajectory_close(&traj) != 0) {
        fprintf(stderr, "vislam-run: write error on trajectory %s\n", o.trajectory_path);
        io_error = 1;
    }
    if (cov_file != NULL) {
        int bad = ferror(cov_file);
        if (fclose(cov_file) != 0 || bad) {
            fprintf(stderr, "vislam-run: write error on covariance %s\n", o.covariance_path);
            io_error = 1;
        }
    }
    if (map.oom) {
        fprintf(stderr, "vislam-run: out of memory collecting the map; it is incomplete\n");
        io_error = 1;
    }
    if (o.map_path != NULL && write_ply(o.map_path, &map) != 0) {
        io_error = 1;
    }

    static vl_counters_t zero_counters;
    const vl_counters_t *counters = initialized ? vl_get_counters(est) : &zero_counters;
    const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
    const int truncated = vl_log_reader_truncated(&reader);
    timing_summary_t tu = summarize(&t_update);
    timing_summary_t tp = summarize(&t_propagate);

    if (o.stats_path != NULL &&
        write_stats_json(o.stats_path, &o, &cfg, calib_source, &run, rs, truncated, counters, map.count, &tu, &tp) !=
            0) {
        io_error = 1;
    }

    if (!o.quiet) {
        named_count_t list[32];
        fprintf(stderr, "vislam-run: %s (mode %s, window %u, calibration from %s)\n", o.log_path,
                vl_mode_name(cfg.mode), (unsigned)cfg.max_landmarks, calib_source);
        fprintf(stderr, "  steps %llu (imu %llu, frames %llu), trajectory lines %llu, landmarks mapped %zu\n",
                (unsigned long long)(run.imu_processed + run.frames_processed),
                (unsigned long long)run.imu_processed, (unsigned long long)run.frames_processed,
                (unsigned long long)run.trajectory_lines, map.count);
        size_t n = run_counter_list(&run, rs, truncated, list);
        fprintf(stderr, "  run:");
        for (size_t i = 0; i < n; ++i) {
            if (list[i].value != 0) {
                fprintf(stderr, " %s %llu", list[i].name, (unsigned long long)list[i].value);
            }
        }
        fprintf(stderr, "\n  core:");
        if (!initialized) {
            fprintf(stderr, " (estimator never initialized)");
        }
        n = core_counter_list(counters, list);
        for (size_t i = 0; i < n; ++i) {
            if (list[i].value != 0) {
                fprintf(stderr, " %s %llu", list[i].name, (unsigned long long)list[i].value);
            }
        }
        fprintf(stderr, "\n");
        vl_pose_t last;
        if (initialized && vl_get_pose(est, &last) == VL_OK) {
            fprintf(stderr, "  noise in use: linear_velocity %.3g m/s, angular_velocity %.3g rad/s, pixel %.3g px\n",
                    last.linear_velocity_noise, last.angular_velocity_noise, last.pixel_noise);
        }
        for (int which = 0; which < 2; ++which) {
            const uint64_t *slots = which == 0 ? run.propagate_status : run.update_status;
            for (int s = STATUS_MIN; s <= STATUS_MAX; ++s) {
                if (s != VL_OK && slots[s - STATUS_MIN] != 0) {
                    fprintf(stderr, "  %s returned %s x%llu (%s)\n", which == 0 ? "vl_propagate" : "vl_update",
                            status_name(s), (unsigned long long)slots[s - STATUS_MIN],
                            vl_status_str((vl_status_t)s));
                }
            }
        }
        if (truncated) {
            fprintf(stderr, "  warning: the log ends inside an event (cut)\n");
        }
        if (logger.suppressed != 0) {
            fprintf(stderr, "  core log lines suppressed by the rate limit: %llu\n",
                    (unsigned long long)logger.suppressed);
        }
    }
    if (o.timing) {
        fprintf(stderr, "  timing (wall, us)      count     median        p99      p99.9        max\n");
        const char *names[2] = {"vl_update", "vl_propagate"};
        const timing_summary_t *ts[2] = {&tu, &tp};
        for (int i = 0; i < 2; ++i) {
            fprintf(stderr, "  %-20s %8zu %10.1f %10.1f %10.1f %10.1f\n", names[i], ts[i]->count, ts[i]->median,
                    ts[i]->p99, ts[i]->p999, ts[i]->max);
        }
    }

    /* Said even with --quiet: a damaged log must not pass for a clean one. */
    const int damaged = truncated || rs->corrupt != 0 || rs->decode_errors != 0 || rs->events == 0;
    if (damaged) {
        fprintf(stderr,
                "vislam-run: %s is damaged: %llu unreadable spot(s) (%llu bytes skipped), %llu payload(s) that do "
                "not decode, %s%s\n",
                o.log_path, (unsigned long long)rs->corrupt, (unsigned long long)rs->bytes_skipped,
                (unsigned long long)rs->decode_errors, truncated ? "cut inside an event" : "not cut",
                rs->events == 0 ? "; no event at all (empty or not an LCM log)" : "");
    }
    vl_log_reader_close(&reader);
    free(map.points);
    free(t_update.us);
    free(t_propagate.us);
    free(est);

    if (io_error) {
        return 1;
    }
    if (damaged) {
        return EXIT_LOG_DAMAGED;
    }
    if (run.trajectory_lines == 0) {
        fprintf(stderr, "vislam-run: no frame could be processed\n");
        return 1;
    }
    return 0;
}
