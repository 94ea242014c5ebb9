/*
 * vislam-run: runs the estimator over an LCM log as fast as possible.
 *
 * Outputs (trajectory, map, stats JSON without --timing) depend only on the
 * log and the configuration: the core never reads a clock, and wall-clock
 * timing is printed to stderr only.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vislam/vislam.h"
#include "vl_cli.h"
#include "vl_clock.h"
#include "vl_config_file.h"
#include "vl_latency.h"
#include "vl_log_reader.h"
#include "vl_map_file.h"
#include "vl_msg.h"
#include "vl_session.h"
#include "vl_stats_json.h"
#include "vl_trajectory_file.h"

#define EXIT_USAGE 2
#define EXIT_LOG_DAMAGED 3

/* Damage reports printed before only the counts are kept. */
#define DAMAGE_REPORTS 5

typedef struct {
    const char *log_path;
    const char *trajectory_path;
    const char *map_path;
    const char *config_path;
    const char *stats_path;
    const char *covariance_path;
    const char *frame_stats_path;
    const char *mode;
    const char *preset;
    const char *max_landmarks;
    int quiet;
    int timing;
    int print_config;
    vl_worker_options_t worker;
} options_t;

typedef struct {
    vl_map_point_t *points;
    size_t count;
    size_t capacity;
    int oom;
} map_t;

/* What the session's sinks write to. */
typedef struct {
    map_t map;
    vl_trajectory_file_t traj;
    FILE *cov_file;
    FILE *frame_stats_file;
    const vl_estimator_t *est; /* read by the frame-stats sink */
    uint64_t trajectory_lines;
} sinks_t;

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
            "  --frame-stats FILE   one line per trajectory line: time, every core counter (running\n"
            "                       totals, named in the header line) and the per-sample noises in\n"
            "                       use (linear m/s, angular rad/s, pixel px), the estimated\n"
            "                       input offsets (linear m/s, angular rad/s; x y z each) and the\n"
            "                       update's normalized innovation squared per row and its rows\n"
            "  --config FILE        INI configuration on top of the defaults (see tools/vislam.ini)\n"
            "  --preset NAME        default|seed: start from this preset (conflicts with a different\n"
            "                       [estimator] preset in the config file)\n"
            "  --mode MODE          imu_only|mapping|slam (overrides the config file)\n"
            "  --max-landmarks N    active window, 1..%d (overrides the config file)\n"
            "  --stats-json FILE    counters (and timing with --timing) as JSON\n"
            "  --timing             per-step wall time of vl_update and vl_propagate on stderr\n",
            VL_MAX_LANDMARKS);
    fputs(VL_WORKER_USAGE("    "), f);
    fprintf(f, "  --quiet              no summary and no core warnings on stderr\n"
               "  --print-config       print the effective configuration (INI) to stdout and exit\n"
               "  --version            print the version and exit\n"
               "  --help               this text\n"
               "\n"
               "Every event header is checked before it is read: a damaged spot (bad sync word, absurd\n"
               "length, junk) is reported with its file offset and skipped to the next valid event.\n"
               "\n"
               "Exit status: 0 done, 1 I/O error or no frame processed, 2 usage or configuration error,\n"
               "3 the log is damaged (unreadable spots, a cut end, payloads that do not decode, or no\n"
               "event at all); the outputs then hold every event that could be read.\n");
}

static int parse_args(int argc, char **argv, options_t *o)
{
    memset(o, 0, sizeof(*o));
    vl_worker_options_default(&o->worker);
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char **target = NULL;
        const int worker_option =
            vl_worker_parse_option("vislam-run", a, i + 1 < argc ? argv[i + 1] : NULL, &o->worker);
        if (worker_option != 0) {
            if (worker_option < 0) {
                return -1;
            }
            ++i;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(0);
        } else if (strcmp(a, "--version") == 0) {
            exit(vl_cli_print_version(stdout, "vislam-run") == 0 ? 0 : 1);
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
        } else if (strcmp(a, "--frame-stats") == 0) {
            target = &o->frame_stats_path;
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

/* ---- session sinks ---- */

static void map_sink(void *user, const vl_landmark_t *lm)
{
    map_t *m = &((sinks_t *)user)->map;
    if (m->count == m->capacity) {
        size_t cap = m->capacity == 0 ? 1024 : 2 * m->capacity;
        vl_map_point_t *p = (vl_map_point_t *)realloc(m->points, cap * sizeof(*p));
        if (p == NULL) {
            m->oom = 1;
            return;
        }
        m->points = p;
        m->capacity = cap;
    }
    vl_map_point_from_landmark(lm, &m->points[m->count++]);
}

/* ---- outputs ---- */

/* A time exactly as the TUM writer prints it (s, 6 decimals), so the per-frame files pair by time. */
static void write_time(FILE *f, int64_t utime)
{
    char t[VL_TRAJECTORY_TIME_MAX];
    vl_trajectory_format_time(t, sizeof(t), utime);
    fputs(t, f);
}

/* One line per pose: the time exactly as the TUM writer prints it, so the two files pair by
   time, then the diagonal of the 6x6 pose covariance. Write errors are found by ferror at close. */
static void write_covariance_line(FILE *f, int64_t utime, const vl_pose_t *pose)
{
    write_time(f, utime);
    for (int i = 0; i < 6; ++i) {
        char v[VL_CLI_DOUBLE_MAX];
        vl_cli_format_double(v, sizeof(v), pose->covariance[i * 6 + i]);
        fprintf(f, " %s", v);
    }
    fputc('\n', f);
}

/* The frame-stats header: the column names, counters in VL_COUNTERS order. */
static void write_frame_stats_header(FILE *f)
{
    fputs("# time", f);
#define VL_FRAME_STATS_NAME_(type, name, meaning) fputs(" " #name, f);
    VL_COUNTERS(VL_FRAME_STATS_NAME_)
#undef VL_FRAME_STATS_NAME_
    fputs(" linear_velocity_noise angular_velocity_noise pixel_noise linear_offset_x linear_offset_y linear_offset_z"
          " angular_offset_x angular_offset_y angular_offset_z innovation_ratio innovation_rows"
          " velocity_sensor_x velocity_sensor_y velocity_sensor_z\n",
          f);
}

/* One frame-stats line: the time as the TUM writer prints it, the running core counters, the
   noises in use and the estimated input offsets after the frame's update, the update's
   normalized innovation squared per row with its rows, and the velocity sensor's estimated position. */
static void write_frame_stats_line(FILE *f, int64_t utime, const vl_counters_t *c, const vl_pose_t *pose)
{
    write_time(f, utime);
#define VL_FRAME_STATS_VALUE_(type, name, meaning) fprintf(f, " %llu", (unsigned long long)c->name);
    VL_COUNTERS(VL_FRAME_STATS_VALUE_)
#undef VL_FRAME_STATS_VALUE_
    const double tail[10] = {pose->linear_velocity_noise, pose->angular_velocity_noise, pose->pixel_noise,
                             pose->linear_offset[0],      pose->linear_offset[1],       pose->linear_offset[2],
                             pose->angular_offset[0],     pose->angular_offset[1],      pose->angular_offset[2],
                             pose->innovation_ratio};
    for (int i = 0; i < 10; ++i) {
        char v[VL_CLI_DOUBLE_MAX];
        vl_cli_format_double(v, sizeof(v), tail[i]);
        fprintf(f, " %s", v);
    }
    fprintf(f, " %u", (unsigned)pose->innovation_rows);
    for (int i = 0; i < 3; ++i) {
        char v[VL_CLI_DOUBLE_MAX];
        vl_cli_format_double(v, sizeof(v), pose->velocity_sensor[i]);
        fprintf(f, " %s", v);
    }
    fputc('\n', f);
}

/* Session sink: one TUM line (and covariance and frame-stats lines) per frame the core used. */
static void on_pose(void *user, vl_session_step_t step, int64_t utime, uint64_t sequence, const vl_pose_t *pose)
{
    sinks_t *k = (sinks_t *)user;
    (void)sequence;
    if (step != VL_SESSION_STEP_UPDATE) {
        return;
    }
    vl_trajectory_write(&k->traj, utime, pose);
    if (k->cov_file != NULL) {
        write_covariance_line(k->cov_file, utime, pose);
    }
    if (k->frame_stats_file != NULL) {
        write_frame_stats_line(k->frame_stats_file, utime, vl_get_counters(k->est), pose);
    }
    k->trajectory_lines++;
}

/* Opens an optional per-frame output for writing; NULL (reported) when it cannot. */
static FILE *open_output(const char *path)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-run: cannot write %s: %s\n", path, strerror(errno));
    }
    return f;
}

/* Closes an optional per-frame output; -1 (reported) on a write error. NULL: nothing to close. */
static int close_checked(FILE *f, const char *path)
{
    if (f == NULL) {
        return 0;
    }
    const int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-run: write error on %s\n", path);
        return -1;
    }
    return 0;
}

/* Closes the optional per-frame outputs on an early exit (their contents no longer matter). */
static void close_optional(sinks_t *k)
{
    if (k->cov_file != NULL) {
        fclose(k->cov_file);
    }
    if (k->frame_stats_file != NULL) {
        fclose(k->frame_stats_file);
    }
}

static int write_ply(const char *path, const map_t *m)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-run: cannot write map %s: %s\n", path, strerror(errno));
        return -1;
    }
    const int bad = vl_map_write_ply(f, m->points, m->count);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-run: write error on map %s\n", path);
        return -1;
    }
    return 0;
}

/* The log reader's counts, then the session's (named once, in vl_session.h), then the lines written. */
static size_t run_counter_list(const vl_session_t *ss, const vl_log_reader_stats_t *rs, int truncated,
                               uint64_t trajectory_lines, vl_counter_entry_t *out)
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
#undef RUN_COUNT
    n += vl_session_counter_list(ss, out + n);
    out[n].name = "trajectory_lines";
    out[n].value = trajectory_lines;
    return n + 1;
}

static int write_stats_json(const char *path, const options_t *o, const vl_session_t *ss,
                            const vl_log_reader_stats_t *rs, int truncated, const sinks_t *k,
                            const vl_latency_t *t_update, const vl_latency_t *t_propagate,
                            const vl_latency_t *t_deferred)
{
    const vl_config_t *cfg = vl_session_config(ss);
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-run: cannot write stats %s: %s\n", path, strerror(errno));
        return -1;
    }
    vl_counter_entry_t list[64];
    fprintf(f, "{\n  \"log\": ");
    vl_json_string(f, o->log_path);
    fprintf(f, ",\n  \"mode\": \"%s\",\n  \"max_landmarks\": %u,\n", vl_mode_name(cfg->mode),
            (unsigned)cfg->max_landmarks);
    fprintf(f, "  \"calibration_source\": \"%s\",\n", vl_session_calibration_source(ss));
    fprintf(f, "  \"landmarks_mapped\": %zu,\n", k->map.count);
    fprintf(f, "  \"health\": %d,\n", (int)vl_session_health(ss));
    fprintf(f, "  \"innovation_ratio\": %.9g,\n", vl_session_innovation_ratio(ss, 0));
    fprintf(f, "  \"run\": {\n");
    vl_json_counts(f, "    ", list, run_counter_list(ss, rs, truncated, k->trajectory_lines, list));
    fprintf(f, "  },\n  \"core_counters\": {\n");
    vl_json_counts(f, "    ", list, vl_counters_list(vl_session_core_counters(ss), list));
    fprintf(f, "  },\n");
    vl_json_core_status(f, "  ", ss);
    if (o->timing) {
        fprintf(f, ",\n  \"timing\": {\n");
        vl_json_latency(f, "    ", "vl_update", t_update, 0);
        vl_json_latency(f, "    ", "vl_propagate", t_propagate, 0);
        vl_json_latency(f, "    ", "vl_update_deferred", t_deferred, 1);
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
        return vl_config_write_ini(stdout, &cfg, info.has_calibration) == 0 ? 0 : 1;
    }

    static sinks_t sinks;
    static vl_session_t session;
    static vl_latency_t t_update;
    static vl_latency_t t_propagate;
    static vl_latency_t t_deferred; /* after a frame's pose: its work after the pose (vl_session_finish) */
    static vl_log_reader_t reader;
    static vl_log_event_t ev;
    vl_latency_reset(&t_update);
    vl_latency_reset(&t_propagate);
    vl_latency_reset(&t_deferred);

    /* Several MB: heap, once, aligned as vl_init requires (VL_ESTIMATOR_ALIGN). */
    const size_t est_bytes =
        (sizeof(vl_estimator_t) + VL_ESTIMATOR_ALIGN - 1) / VL_ESTIMATOR_ALIGN * VL_ESTIMATOR_ALIGN;
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
    if (vl_trajectory_open(&sinks.traj, o.trajectory_path, err, sizeof(err)) != 0) {
        fprintf(stderr, "vislam-run: %s\n", err);
        vl_log_reader_close(&reader);
        free(est);
        return 1;
    }
    int open_failed = 0;
    if (o.covariance_path != NULL) {
        sinks.cov_file = open_output(o.covariance_path);
        open_failed |= sinks.cov_file == NULL;
    }
    if (o.frame_stats_path != NULL) {
        sinks.frame_stats_file = open_output(o.frame_stats_path);
        open_failed |= sinks.frame_stats_file == NULL;
        if (sinks.frame_stats_file != NULL) {
            write_frame_stats_header(sinks.frame_stats_file);
        }
    }
    if (open_failed) {
        close_optional(&sinks);
        vl_trajectory_close(&sinks.traj);
        vl_log_reader_close(&reader);
        free(est);
        return 1;
    }

    static vl_worker_t worker;
    char wmsg[256];
    if (vl_worker_start(&worker, &o.worker, wmsg, sizeof(wmsg)) != 0 || (o.worker.threads > 1 && !o.quiet)) {
        fprintf(stderr, "vislam-run: %s\n", wmsg);
    }
    vl_session_options_t so;
    memset(&so, 0, sizeof(so));
    so.program = "vislam-run";
    so.worker = &worker;
    so.quiet = o.quiet;
    so.config_has_calibration = info.has_calibration;
    so.override_log = info.override_log;
    so.callbacks.on_pose = on_pose;
    so.callbacks.on_landmark = map_sink;
    so.callbacks.user = &sinks;
    sinks.est = est;
    if (vl_session_init(&session, est, &cfg, &so) != VL_OK) {
        fprintf(stderr, "vislam-run: vl_init refused the configuration\n");
        vl_worker_stop(&worker);
        close_optional(&sinks);
        vl_trajectory_close(&sinks.traj);
        vl_log_reader_close(&reader);
        free(est);
        return EXIT_USAGE;
    }

    vl_log_event_kind_t kind;
    while ((kind = vl_log_reader_next(&reader, &ev)) != VL_LOG_EVENT_END) {
        if (kind == VL_LOG_EVENT_DECODE_ERROR || kind == VL_LOG_EVENT_CORRUPT) {
            const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
            if (kind == VL_LOG_EVENT_DECODE_ERROR && rs->decode_errors <= DAMAGE_REPORTS) {
                fprintf(stderr, "vislam-run: %s\n", ev.error);
            } else if (kind == VL_LOG_EVENT_CORRUPT && rs->corrupt <= DAMAGE_REPORTS) {
                fprintf(stderr, "vislam-run: %s: %s\n", o.log_path, ev.error);
            }
        }
        const int64_t t0 = o.timing ? vl_clock_monotonic_us() : 0;
        const vl_session_step_t step = vl_session_input(&session, &ev, NULL);
        const int64_t t1 = o.timing ? vl_clock_monotonic_us() : 0;
        if (o.timing && step != VL_SESSION_STEP_NONE) {
            vl_latency_record(step == VL_SESSION_STEP_UPDATE ? &t_update : &t_propagate, t1 - t0);
        }
        const int deferred = vl_deferred_due(est);
        (void)vl_session_finish(&session);
        if (o.timing && deferred) {
            vl_latency_record(&t_deferred, vl_clock_monotonic_us() - t1);
        }
    }
    vl_session_flush(&session);
    vl_worker_stop(&worker);

    int io_error = 0;
    if (vl_trajectory_close(&sinks.traj) != 0) {
        fprintf(stderr, "vislam-run: write error on trajectory %s\n", o.trajectory_path);
        io_error = 1;
    }
    if (close_checked(sinks.cov_file, o.covariance_path) != 0 ||
        close_checked(sinks.frame_stats_file, o.frame_stats_path) != 0) {
        io_error = 1;
    }
    if (sinks.map.oom) {
        fprintf(stderr, "vislam-run: out of memory collecting the map; it is incomplete\n");
        io_error = 1;
    }
    if (o.map_path != NULL && write_ply(o.map_path, &sinks.map) != 0) {
        io_error = 1;
    }

    const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
    const int truncated = vl_log_reader_truncated(&reader);
    const vl_session_counters_t *n = vl_session_counters(&session);

    if (o.stats_path != NULL && write_stats_json(o.stats_path, &o, &session, rs, truncated, &sinks, &t_update,
                                                 &t_propagate, &t_deferred) != 0) {
        io_error = 1;
    }

    if (!o.quiet) {
        vl_counter_entry_t list[64];
        const vl_config_t *used = vl_session_config(&session);
        fprintf(stderr, "vislam-run: %s (mode %s, window %u, calibration from %s)\n", o.log_path,
                vl_mode_name(used->mode), (unsigned)used->max_landmarks, vl_session_calibration_source(&session));
        const uint64_t imu_steps = n->imu_used + n->imu_rejected;
        const uint64_t frame_steps = n->frames_used + n->frames_rejected;
        fprintf(stderr, "  steps %llu (imu %llu, frames %llu), trajectory lines %llu, landmarks mapped %zu\n",
                (unsigned long long)(imu_steps + frame_steps), (unsigned long long)imu_steps,
                (unsigned long long)frame_steps, (unsigned long long)sinks.trajectory_lines, sinks.map.count);
        size_t k = run_counter_list(&session, rs, truncated, sinks.trajectory_lines, list);
        fprintf(stderr, "  run:");
        for (size_t i = 0; i < k; ++i) {
            if (list[i].value != 0) {
                fprintf(stderr, " %s %llu", list[i].name, (unsigned long long)list[i].value);
            }
        }
        fprintf(stderr, "\n  core:");
        if (!vl_session_initialized(&session)) {
            fprintf(stderr, " (estimator never initialized)");
        }
        k = vl_counters_list(vl_session_core_counters(&session), list);
        for (size_t i = 0; i < k; ++i) {
            if (list[i].value != 0) {
                fprintf(stderr, " %s %llu", list[i].name, (unsigned long long)list[i].value);
            }
        }
        fprintf(stderr, "\n  health over the run: 0x%x (vislam.status_t HEALTH_* bits)\n",
                (unsigned)vl_session_health(&session));
        vl_pose_t last;
        const vl_estimator_t *e = vl_session_estimator(&session);
        if (e != NULL && vl_get_pose(e, &last) == VL_OK) {
            fprintf(stderr, "  noise in use: linear_velocity %.3g m/s, angular_velocity %.3g rad/s, pixel %.3g px\n",
                    last.linear_velocity_noise, last.angular_velocity_noise, last.pixel_noise);
            fprintf(stderr,
                    "  innovation ratio over the run: %.3g (normalized innovation squared per row; 1 when the noise "
                    "model fits)\n",
                    vl_session_innovation_ratio(&session, 0));
        }
        for (int which = 0; which < 2; ++which) {
            for (int s = (int)VL_STATUS_MIN; s <= (int)VL_STATUS_MAX; ++s) {
                const uint64_t v = vl_session_status_count(&session, which, (vl_status_t)s);
                if (s != VL_OK && v != 0) {
                    fprintf(stderr, "  %s returned %d x%llu (%s)\n", which == 0 ? "vl_propagate" : "vl_update", s,
                            (unsigned long long)v, vl_status_str((vl_status_t)s));
                }
            }
        }
        if (truncated) {
            fprintf(stderr, "  warning: the log ends inside an event (cut)\n");
        }
        if (vl_session_log_suppressed(&session) != 0) {
            fprintf(stderr, "  core log lines suppressed by the rate limit: %llu\n",
                    (unsigned long long)vl_session_log_suppressed(&session));
        }
    }
    if (o.timing) {
        fprintf(stderr, "  step time (CLOCK_MONOTONIC, us; vl_latency buckets, <= 6.25%% above the true value):\n");
        vl_latency_print(&t_update, stderr, "    vl_update   ");
        vl_latency_print(&t_propagate, stderr, "    vl_propagate");
        vl_latency_print(&t_deferred, stderr, "    deferred    ");
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
    free(sinks.map.points);
    free(est);

    if (io_error) {
        return 1;
    }
    if (damaged) {
        return EXIT_LOG_DAMAGED;
    }
    if (sinks.trajectory_lines == 0) {
        fprintf(stderr, "vislam-run: no frame could be processed\n");
        return 1;
    }
    return 0;
}
