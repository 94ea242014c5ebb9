/*
 * vislam-latency: the worst-case latency of vislam on this machine, in one run.
 *
 * 1. In-process: the estimator over the log through the same vl_session every
 *    program uses, on a pinned CPU (optionally SCHED_FIFO), at the sensor rate
 *    or as fast as possible, --passes times (a fresh estimator each pass). Every
 *    vl_update is timed (CLOCK_MONOTONIC, ns) and its work read from the core
 *    (vl_get_work: flops per stage, counted from the dimensions it used).
 * 2. End to end: vislamd (beside this program) as a child on the estimator's
 *    CPU, fed by vislam-replay --lockstep pinned to another CPU, over LCM: input
 *    published to pose received, per frame. A new daemon each pass. The LCM
 *    overhead of a frame is that minus vislamd's own time for its step
 *    (vislamd --step-samples), the two paired by the frame's utime.
 * 3. The jitter floor: a probe thread per CPU (vl_jitter) wakes at 1 kHz during
 *    both and records how late it wakes: what the machine alone costs.
 * Optional: a busy-loop and memory-churn child on the other CPU (--load),
 * cyclictest beside the probe (--cyclictest), callgrind's instruction count per
 * update on a re-run of the in-process pass (--callgrind), a CDF plot (--plot).
 */
#define _GNU_SOURCE /* sched_setaffinity, CPU_SET */

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "vislam/vislam.h"
#include "vl_awake.h"
#include "vl_channels.h"
#include "vl_cli.h"
#include "vl_clock.h"
#include "vl_config_file.h"
#include "vl_jitter.h"
#include "vl_latency.h"
#include "vl_log_reader.h"
#include "vl_rt.h"
#include "vl_session.h"
#include "vl_warm.h"
#include "vl_worker.h"

#define EXIT_INCOMPLETE 1
#define EXIT_USAGE 2

/* Memory the --load child keeps rewriting: larger than the caches, so it competes for memory bandwidth. */
#define LOAD_BYTES (64u << 20)
#define PATH_LEN 4096

typedef struct {
    const char *log_path;
    const char *json_path;
    const char *plot_path;
    const char *config_path;
    const char *lcm_url;
    const char *work_dir;
    int passes;
    int rate_max;
    int cpu;       /* the estimator's CPU (vislamd's in the end-to-end pass) */
    int other_cpu; /* the publisher's and the load's */
    int rt_priority;
    int load;
    int e2e;
    int callgrind;
    int cyclictest;
    int probe;
    long budget_us;
    long timeout_ms;
    const char *busy_poll_us;    /* end to end: vislamd's and the replay's --busy-poll-us, as given */
    int lcm_receive_thread;      /* end to end: both receive through liblcm's thread */
    const char *cpu_dma_latency; /* the PM QoS request (us) in-process and vislamd's, as given; NULL: none */
    int cpu_dma_latency_us;      /* the same, parsed; -1: none */
    const char *warm_us;         /* the predictive wake (us) in-process and vislamd's --warm-us, as given */
    long warm_us_n;              /* the same, parsed; 0: off */
    int supersede_imu_poses;     /* end to end: vislamd's --supersede-imu-poses */
    int keep_awake;              /* a SCHED_IDLE spinner on cpu in-process; vislamd's --keep-awake */
    int quiet;
    vl_worker_options_t worker;
} options_t;

/* One timed vl_update. */
typedef struct {
    int64_t ns;
    vl_work_t work;
    uint64_t frame_flops; /* work plus the IMU steps' since the previous frame: the frame period's work */
    int64_t deferred_ns;  /* vl_session_finish after the pose: the frame's work after it (0: none) */
    uint64_t deferred_flops;
    int64_t utime;
    int pass;
    uint32_t frame;
} step_t;

typedef struct {
    double min, p50, p99, p999, max, mean;
    size_t n;
} summary_t;

static options_t opt;
static char self_dir[PATH_LEN];
/* The in-process pass's worker (--threads 2), started once, after this thread's CPU and priority. */
static vl_worker_t g_worker;
/* --warm-us in-process: the periods warmed and what it cost (vl_warm_t's counts; no prediction
   here, the log gives each input's time). */
static vl_warm_t g_warm;
static uint64_t g_warm_sink; /* what vl_warm_touch read, kept so that the reads stay */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: vislam-latency LOG [options]\n"
            "Measures vislam's step latency on this machine: in-process (the core through vl_session) and\n"
            "end to end through vislamd over LCM (and the LCM overhead: end to end less vislamd's own\n"
            "step, per frame), beside the machine's own scheduling-jitter floor and the core's own count\n"
            "of each step's work.\n"
            "\n"
            "  --passes N          run the log N times, a fresh estimator (and daemon) each pass (default 1)\n"
            "  --rate sensor|max   feed inputs at their recorded times (default) or as fast as possible\n"
            "  --cpu K             the estimator's (and vislamd's) CPU (default 1, or 0 on one CPU)\n"
            "  --other-cpu J       the publisher's and --load's CPU (default: the next CPU)\n"
            "  --rt-priority N     SCHED_FIFO priority 1..99 for the estimator, vislamd and the publisher\n"
            "                      (the jitter probe runs at N+1); a refusal is a warning\n"
            "  --load              a busy-loop and memory-churn child on the other CPU while measuring\n"
            "  --threads N         1 (default) or 2: the update shared with a worker thread, in-process and\n"
            "                      in vislamd (the worker at --rt-priority too)\n"
            "  --worker-cpu K      the worker's CPU (default: --other-cpu, beside the publisher and --load)\n"
            "  --no-e2e            in-process only (no vislamd, no LCM)\n"
            "  --lcm-url URL       LCM provider of the end-to-end pass (default: $LCM_DEFAULT_URL, else\n"
            "                      LCM's default); udpm needs a multicast route (see the README)\n"
            "  --timeout-ms N      end to end: how long to wait for a pose (default 2000)\n"
            "  --busy-poll-us N    end to end: vislamd and the replay spin on their sockets up to N us for\n"
            "                      the next message before sleeping (their --busy-poll-us)\n"
            "  --cpu-dma-latency US  hold /dev/cpu_dma_latency at US us during the in-process pass and\n"
            "                      pass it to vislamd: no CPU enters an idle state slower to leave\n"
            "                      (system-wide, costs power; a refusal is a warning)\n"
            "  --warm-us N         the predictive wake: in-process, sleep until N us before an input due\n"
            "                      after an idle gap, read the estimator's memory and spin until it is\n"
            "                      due; end to end, vislamd's --warm-us N (0..%d; costs up to 2N us of\n"
            "                      CPU a frame period)\n"
            "  --keep-awake        keep --cpu from idling: in-process a thread pinned there spins at\n"
            "                      SCHED_IDLE (the estimator preempts it); end to end, vislamd's\n"
            "                      --keep-awake (costs that CPU at 100 %%)\n"
            "  --supersede-imu-poses  end to end: vislamd's --supersede-imu-poses (an IMU pose at a\n"
            "                      frame's time is not sent; the frame's pose is)\n"
            "  --lcm-receive-thread  end to end: both receive through liblcm's receive thread (their\n"
            "                      --lcm-receive-thread), not on the socket in their own loop\n"
            "  --config FILE       INI configuration (the estimator's and vislamd's)\n"
            "  --budget-us N       step budget for the overrun count (default: the log's frame period)\n"
            "  --cyclictest        also run cyclictest (if installed) on every CPU while measuring\n"
            "  --callgrind         re-run one in-process pass under valgrind --tool=callgrind and report\n"
            "                      the instructions per vl_update (needs a build valgrind can run:\n"
            "                      -DVL_NATIVE=OFF where the CPU has AVX-512)\n"
            "  --no-probe          no jitter probe\n"
            "  --json FILE         the figures as JSON (with the samples the plot draws)\n"
            "  --plot FILE.png     CDFs of the step and end-to-end latency and the LCM overhead with the\n"
            "                      jitter floor\n"
            "                      (Python: $VISLAM_PYTHON, else the project's .venv, else python3;\n"
            "                      vislam_tools from $VISLAM_TOOLS_DIR, else the source tree's tools/)\n"
            "  --work-dir DIR      where the end-to-end pass keeps vislamd's and the replay's outputs\n"
            "                      (default: a new directory under $TMPDIR, removed at the end)\n"
            "  --quiet             only the summary\n"
            "  --version           print the version and exit\n"
            "  --help              this text\n"
            "\n"
            "Exit status: 0 measured; 1 the end-to-end pass got no (or not every) pose back, or a helper\n"
            "failed; 2 usage error or unreadable log.\n",
            VL_WARM_MAX_US);
}

static int parse_long(const char *name, const char *v, long lo, long hi, long *out)
{
    char *end = NULL;
    errno = 0;
    const long n = strtol(v, &end, 10);
    if (end == v || *end != '\0' || errno != 0 || n < lo || n > hi) {
        fprintf(stderr, "vislam-latency: %s %s: expected an integer in %ld..%ld\n", name, v, lo, hi);
        return -1;
    }
    *out = n;
    return 0;
}

static int parse_args(int argc, char **argv, options_t *o)
{
    memset(o, 0, sizeof(*o));
    o->passes = 1;
    o->cpu = -1;
    o->cpu_dma_latency_us = -1;
    o->other_cpu = -1;
    o->e2e = 1;
    o->probe = 1;
    o->timeout_ms = 2000;
    vl_worker_options_default(&o->worker);
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = (i + 1 < argc) ? argv[i + 1] : NULL;
        long n = 0;
        const int worker_option = vl_worker_parse_option("vislam-latency", a, v, &o->worker);
        if (worker_option < 0) {
            return -1;
        } else if (worker_option > 0) {
            ++i;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(0);
        } else if (strcmp(a, "--version") == 0) {
            exit(vl_cli_print_version(stdout, "vislam-latency") == 0 ? 0 : 1);
        } else if (strcmp(a, "--load") == 0) {
            o->load = 1;
        } else if (strcmp(a, "--no-e2e") == 0) {
            o->e2e = 0;
        } else if (strcmp(a, "--callgrind") == 0) {
            o->callgrind = 1;
        } else if (strcmp(a, "--cyclictest") == 0) {
            o->cyclictest = 1;
        } else if (strcmp(a, "--no-probe") == 0) {
            o->probe = 0;
        } else if (strcmp(a, "--lcm-receive-thread") == 0) {
            o->lcm_receive_thread = 1;
        } else if (strcmp(a, "--supersede-imu-poses") == 0) {
            o->supersede_imu_poses = 1;
        } else if (strcmp(a, "--keep-awake") == 0) {
            o->keep_awake = 1;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
        } else if (a[0] != '-' || a[1] == '\0') {
            if (o->log_path != NULL) {
                fprintf(stderr, "vislam-latency: more than one log given (%s, %s)\n", o->log_path, a);
                return -1;
            }
            o->log_path = a;
        } else if (v == NULL) {
            fprintf(stderr, "vislam-latency: %s needs a value (or is unknown; see --help)\n", a);
            return -1;
        } else {
            ++i;
            if (strcmp(a, "--passes") == 0) {
                if (parse_long(a, v, 1, 1000, &n) != 0) {
                    return -1;
                }
                o->passes = (int)n;
            } else if (strcmp(a, "--rate") == 0) {
                if (strcmp(v, "sensor") != 0 && strcmp(v, "max") != 0) {
                    fprintf(stderr, "vislam-latency: --rate %s: expected sensor or max\n", v);
                    return -1;
                }
                o->rate_max = strcmp(v, "max") == 0;
            } else if (strcmp(a, "--cpu") == 0 || strcmp(a, "--other-cpu") == 0) {
                if (parse_long(a, v, 0, CPU_SETSIZE - 1, &n) != 0) {
                    return -1;
                }
                *(strcmp(a, "--cpu") == 0 ? &o->cpu : &o->other_cpu) = (int)n;
            } else if (strcmp(a, "--rt-priority") == 0) {
                if (parse_long(a, v, 1, 98, &n) != 0) {
                    return -1;
                }
                o->rt_priority = (int)n;
            } else if (strcmp(a, "--budget-us") == 0) {
                if (parse_long(a, v, 1, 100000000L, &o->budget_us) != 0) {
                    return -1;
                }
            } else if (strcmp(a, "--timeout-ms") == 0) {
                if (parse_long(a, v, 1, 3600000L, &o->timeout_ms) != 0) {
                    return -1;
                }
            } else if (strcmp(a, "--lcm-url") == 0) {
                o->lcm_url = v;
            } else if (strcmp(a, "--busy-poll-us") == 0) {
                if (parse_long(a, v, 0, 1000000L, &n) != 0) {
                    return -1;
                }
                o->busy_poll_us = v;
            } else if (strcmp(a, "--cpu-dma-latency") == 0) {
                if (parse_long(a, v, 0, 2000000000L, &n) != 0) {
                    return -1;
                }
                o->cpu_dma_latency = v;
                o->cpu_dma_latency_us = (int)n;
            } else if (strcmp(a, "--warm-us") == 0) {
                if (parse_long(a, v, 0, VL_WARM_MAX_US, &o->warm_us_n) != 0) {
                    return -1;
                }
                o->warm_us = v;
            } else if (strcmp(a, "--config") == 0) {
                o->config_path = v;
            } else if (strcmp(a, "--json") == 0) {
                o->json_path = v;
            } else if (strcmp(a, "--plot") == 0) {
                o->plot_path = v;
            } else if (strcmp(a, "--work-dir") == 0) {
                o->work_dir = v;
            } else {
                fprintf(stderr, "vislam-latency: unknown option %s (see --help)\n", a);
                return -1;
            }
        }
    }
    if (o->log_path == NULL) {
        fprintf(stderr, "vislam-latency: no LOG given (see --help)\n");
        return -1;
    }
    const long ncpu = sysconf(_SC_NPROCESSORS_ONLN);
    if (o->cpu < 0) {
        o->cpu = ncpu > 1 ? 1 : 0;
    }
    if (o->other_cpu < 0) {
        o->other_cpu = ncpu > 1 ? (int)((o->cpu + 1) % ncpu) : 0;
    }
    if (o->worker.cpu < 0) {
        o->worker.cpu = o->other_cpu;
    }
    return 0;
}

/* out = dir/name; an empty string when it does not fit (every later open of it then fails loudly). */
static void path_join(char *out, size_t len, const char *dir, const char *name)
{
    if (snprintf(out, len, "%s/%s", dir, name) >= (int)len) {
        out[0] = '\0';
    }
}

/* ---- statistics ---- */

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Nearest-rank percentile of sorted values. */
static double rank(const double *sorted, size_t n, double percent)
{
    if (n == 0) {
        return 0.0;
    }
    size_t k = (size_t)ceil(percent / 100.0 * (double)n);
    k = k < 1 ? 1 : (k > n ? n : k);
    return sorted[k - 1];
}

/* Sorts v in place and summarizes it. */
static summary_t summarize(double *v, size_t n)
{
    summary_t s;
    memset(&s, 0, sizeof(s));
    s.n = n;
    if (n == 0) {
        return s;
    }
    qsort(v, n, sizeof(double), cmp_double);
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
        sum += v[i];
    }
    s.min = v[0];
    s.p50 = rank(v, n, 50.0);
    s.p99 = rank(v, n, 99.0);
    s.p999 = rank(v, n, 99.9);
    s.max = v[n - 1];
    s.mean = sum / (double)n;
    return s;
}

static void print_summary(const char *label, const summary_t *s)
{
    fprintf(stderr, "  %-30s n %6zu  min %8.1f  p50 %8.1f  p99 %8.1f  p99.9 %8.1f  max %8.1f us\n", label, s->n, s->min,
            s->p50, s->p99, s->p999, s->max);
}

/* "key": {summary} or null, on a line of its own after indent. */
static void json_summary_at(FILE *f, const char *indent, const char *key, const summary_t *s, const char *tail)
{
    if (s == NULL || s->n == 0) {
        fprintf(f, "%s\"%s\": null%s\n", indent, key, tail);
        return;
    }
    fprintf(f,
            "%s\"%s\": {\"n\": %zu, \"min\": %.3f, \"p50\": %.3f, \"p99\": %.3f, \"p999\": %.3f, \"max\": %.3f, "
            "\"mean\": %.3f}%s\n",
            indent, key, s->n, s->min, s->p50, s->p99, s->p999, s->max, s->mean, tail);
}

static void json_summary(FILE *f, const char *key, const summary_t *s, const char *tail)
{
    json_summary_at(f, "  ", key, s, tail);
}

static void json_array_at(FILE *f, const char *indent, const char *key, const double *v, size_t n, const char *tail)
{
    fprintf(f, "%s\"%s\": [", indent, key);
    for (size_t i = 0; i < n; ++i) {
        fprintf(f, "%s%.3f", i == 0 ? "" : ",", v[i]);
    }
    fprintf(f, "]%s\n", tail);
}

static void json_array(FILE *f, const char *key, const double *v, size_t n, const char *tail)
{
    json_array_at(f, "    ", key, v, n, tail);
}

/* ---- the log ---- */

typedef struct {
    vl_log_event_t *events;
    size_t count;
    size_t frames;
    int64_t frame_period_us; /* median interval between frames */
} log_t;

static int cmp_i64(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Reads every usable event into memory once, so that the passes read no file. */
static int load_log(const char *path, log_t *lg)
{
    static vl_log_reader_t reader;
    char err[512];
    memset(lg, 0, sizeof(*lg));
    if (vl_log_reader_open(&reader, path, NULL, err, sizeof(err)) != 0) {
        fprintf(stderr, "vislam-latency: %s\n", err);
        return -1;
    }
    size_t cap = 1024;
    lg->events = (vl_log_event_t *)malloc(cap * sizeof(vl_log_event_t));
    vl_log_event_kind_t kind;
    while (lg->events != NULL && (kind = vl_log_reader_next(&reader, &lg->events[lg->count])) != VL_LOG_EVENT_END) {
        if (kind != VL_LOG_EVENT_IMU && kind != VL_LOG_EVENT_FRAME && kind != VL_LOG_EVENT_CALIBRATION) {
            continue;
        }
        lg->frames += kind == VL_LOG_EVENT_FRAME;
        if (++lg->count == cap) {
            cap *= 2;
            vl_log_event_t *p = (vl_log_event_t *)realloc(lg->events, cap * sizeof(vl_log_event_t));
            if (p == NULL) {
                free(lg->events);
                lg->events = NULL;
            }
            lg->events = p;
        }
    }
    const vl_log_reader_stats_t *rs = vl_log_reader_stats(&reader);
    if (rs->corrupt != 0 || rs->decode_errors != 0 || vl_log_reader_truncated(&reader)) {
        fprintf(stderr,
                "vislam-latency: %s is damaged (%" PRIu64 " unreadable spots, %" PRIu64
                " undecodable payloads); measuring what could be read\n",
                path, rs->corrupt, rs->decode_errors);
    }
    vl_log_reader_close(&reader);
    if (lg->events == NULL) {
        fprintf(stderr, "vislam-latency: out of memory reading %s\n", path);
        return -1;
    }
    if (lg->frames == 0) {
        fprintf(stderr, "vislam-latency: %s holds no stereo frame\n", path);
        return -1;
    }
    int64_t *dt = (int64_t *)calloc(lg->frames, sizeof(int64_t));
    size_t n = 0;
    int64_t prev = INT64_MIN;
    for (size_t i = 0; dt != NULL && i < lg->count; ++i) {
        if (lg->events[i].kind == VL_LOG_EVENT_FRAME) {
            if (prev != INT64_MIN && lg->events[i].log_utime > prev) {
                dt[n++] = lg->events[i].log_utime - prev;
            }
            prev = lg->events[i].log_utime;
        }
    }
    if (n > 0) {
        qsort(dt, n, sizeof(int64_t), cmp_i64);
        lg->frame_period_us = dt[n / 2];
    }
    free(dt);
    return 0;
}

/* ---- the in-process pass ---- */

static int build_config(vl_config_t *cfg, vl_config_file_info_t *info)
{
    vl_config_default(cfg);
    memset(info, 0, sizeof(*info));
    if (opt.config_path != NULL) {
        char err[512];
        if (vl_config_load_ini_ex(opt.config_path, cfg, info, err, sizeof(err)) != VL_OK) {
            fprintf(stderr, "vislam-latency: %s\n", err);
            return -1;
        }
    }
    return 0;
}

/*
 * Runs the log through a fresh session `passes` times on the calling thread;
 * fills steps (one per vl_update) and propagation times (us).
 */
static int run_in_process(const log_t *lg, step_t *steps, size_t *nsteps, double *prop_us, double *prop_work,
                          size_t *nprop)
{
    vl_config_t cfg;
    vl_config_file_info_t info;
    if (build_config(&cfg, &info) != 0) {
        return -1;
    }
    static vl_session_t session;
    void *mem = NULL;
    if (posix_memalign(&mem, VL_ESTIMATOR_ALIGN, sizeof(vl_estimator_t)) != 0) {
        fprintf(stderr, "vislam-latency: cannot allocate the estimator\n");
        return -1;
    }
    vl_estimator_t *est = (vl_estimator_t *)mem;
    *nsteps = 0;
    *nprop = 0;
    for (int pass = 0; pass < opt.passes; ++pass) {
        memset(est, 0, sizeof(*est)); /* every page touched before timing starts */
        vl_session_options_t so;
        memset(&so, 0, sizeof(so));
        so.program = "vislam-latency";
        so.quiet = 1;
        so.config_has_calibration = info.has_calibration;
        so.override_log = info.override_log;
        so.worker = vl_worker_running(&g_worker) ? &g_worker : NULL;
        if (vl_session_init(&session, est, &cfg, &so) != VL_OK) {
            fprintf(stderr, "vislam-latency: vl_init refused the configuration\n");
            free(mem);
            return -1;
        }
        const int64_t start = vl_clock_monotonic_us();
        const int64_t first = lg->events[0].log_utime;
        uint32_t frame = 0;
        uint64_t since_frame = 0; /* the IMU steps' work since the last frame step */
        for (size_t i = 0; i < lg->count; ++i) {
            const vl_log_event_t *ev = &lg->events[i];
            if (!opt.rate_max) {
                const int64_t deadline = start + (ev->log_utime - first);
                if (opt.warm_us_n > 0 && deadline - vl_clock_monotonic_us() > opt.warm_us_n) {
                    /* An idle gap before this input: wake warm_us early, read the state, spin. */
                    while (vl_clock_sleep_until_us(deadline - opt.warm_us_n) != 0) {
                    }
                    const int64_t w0 = vl_clock_monotonic_us();
                    g_warm_sink += vl_warm_touch(est, sizeof(*est));
                    const int64_t w1 = vl_clock_monotonic_us();
                    int64_t w2 = w1;
                    while (w2 < deadline) {
                        w2 = vl_clock_monotonic_us();
                    }
                    g_warm.windows++;
                    g_warm.touch_us += (uint64_t)(w1 - w0);
                    g_warm.spin_us += (uint64_t)(w2 - w1);
                }
                while (vl_clock_sleep_until_us(deadline) != 0) {
                }
            }
            const int64_t t0 = vl_clock_monotonic_ns();
            const vl_session_step_t step = vl_session_input(&session, ev, NULL);
            const int64_t t1 = vl_clock_monotonic_ns();
            if (step == VL_SESSION_STEP_UPDATE) {
                step_t *s = &steps[(*nsteps)++];
                s->ns = t1 - t0;
                vl_get_work(vl_session_estimator(&session), &s->work);
                s->frame_flops = s->work.flops + since_frame;
                since_frame = 0;
                s->deferred_ns = 0;
                s->deferred_flops = 0;
                if (vl_deferred_due(vl_session_estimator(&session))) {
                    const int64_t t2 = vl_clock_monotonic_ns();
                    (void)vl_session_finish(&session);
                    s->deferred_ns = vl_clock_monotonic_ns() - t2;
                    vl_work_t w;
                    vl_get_work(vl_session_estimator(&session), &w);
                    s->deferred_flops = w.flops;
                    s->frame_flops += w.flops;
                }
                s->utime = ev->frame.utime;
                s->pass = pass;
                s->frame = frame;
            } else if (step == VL_SESSION_STEP_PROPAGATE) {
                vl_work_t w;
                vl_get_work(vl_session_estimator(&session), &w);
                since_frame += w.flops;
                prop_work[*nprop] = (double)w.flops;
                prop_us[(*nprop)++] = (double)(t1 - t0) * 1e-3;
            }
            frame += ev->kind == VL_LOG_EVENT_FRAME;
        }
    }
    free(mem);
    return 0;
}

/* ---- child processes ---- */

/* In a child before exec: its CPU and priority; a refusal is a warning in the child's log. */
static void pin_self(int cpu, int priority)
{
    char msg[256];
    if (vl_rt_set_affinity(cpu, msg, sizeof(msg)) != VL_RT_OK) {
        fprintf(stderr, "vislam-latency: warning: %s\n", msg);
    }
    if (priority > 0 && vl_rt_set_fifo(priority, msg, sizeof(msg)) != VL_RT_OK) {
        fprintf(stderr, "vislam-latency: warning: %s\n", msg);
    }
}

/* In a child: it ends with this program, so that no helper outlives a killed measurement. */
static void die_with_parent(void)
{
    (void)prctl(PR_SET_PDEATHSIG, SIGTERM);
}

/* Starts argv with stdout and stderr to log_path (NULL: inherited), pinned to cpu (-1: not); -1 if fork failed. */
static pid_t spawn(char *const argv[], const char *log_path, int cpu, int priority)
{
    fflush(NULL);
    const pid_t pid = fork();
    if (pid != 0) {
        if (pid < 0) {
            fprintf(stderr, "vislam-latency: cannot start %s: %s\n", argv[0], strerror(errno));
        }
        return pid;
    }
    die_with_parent();
    if (log_path != NULL) {
        FILE *f = freopen(log_path, "w", stderr);
        if (f != NULL) {
            dup2(fileno(stderr), STDOUT_FILENO);
        }
    }
    if (cpu >= 0) {
        pin_self(cpu, priority);
    }
    execv(argv[0], argv);
    fprintf(stderr, "vislam-latency: cannot run %s: %s\n", argv[0], strerror(errno));
    _exit(127);
}

/* Waits for pid; its exit status, 128 + signal, or -1 (no such child). */
static int wait_child(pid_t pid)
{
    int status = 0;
    if (pid <= 0) {
        return -1;
    }
    while (waitpid(pid, &status, 0) < 0) {
        if (errno != EINTR) {
            return -1;
        }
    }
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

/* The --load child: spins and rewrites a buffer larger than the caches until killed. */
static pid_t start_load(int cpu)
{
    fflush(NULL);
    const pid_t pid = fork();
    if (pid != 0) {
        return pid;
    }
    die_with_parent();
    pin_self(cpu, 0);
    volatile unsigned char *buf = (volatile unsigned char *)malloc(LOAD_BYTES);
    unsigned v = 1;
    for (;;) {
        for (size_t i = 0; buf != NULL && i < LOAD_BYTES; i += 64) {
            buf[i] = (unsigned char)(buf[i] + v);
        }
        for (int k = 0; k < 100000; ++k) {
            v = v * 1664525u + 1013904223u;
        }
    }
}

static void stop_child(pid_t pid)
{
    if (pid > 0) {
        kill(pid, SIGTERM);
        (void)wait_child(pid);
    }
}

static int file_exists(const char *path)
{
    return access(path, X_OK) == 0;
}

/* Reads the integer after "key": in a small JSON file; -1 if absent. */
static long long json_int(const char *path, const char *key)
{
    FILE *f = fopen(path, "r");
    if (f == NULL) {
        return -1;
    }
    static char buf[65536];
    const size_t n = fread(buf, 1, sizeof(buf) - 1, f);
    fclose(f);
    buf[n] = '\0';
    char pat[128];
    snprintf(pat, sizeof(pat), "\"%s\":", key);
    const char *p = strstr(buf, pat);
    return p != NULL ? strtoll(p + strlen(pat), NULL, 10) : -1;
}

/* ---- the end-to-end pass ---- */

/*
 * Where a frame's LCM overhead goes, from CLOCK_REALTIME stamps the replay and vislamd take of the
 * same frame (one host, one clock; the kernel's receive stamps have microsecond resolution). Each
 * stage ends where the next begins, and "other" is what the stamps do not account for (end to end
 * less the step and the stages: clock reads, and the monotonic against the real-time clock).
 */
enum {
    STAGE_SEND, /* replay's lcm_publish called -> kernel receive stamp on vislamd's socket */
    /* -> vislamd done with the input before it (the IMU sample of the same instant), in three: */
    STAGE_QUEUED_WAKE,    /* until it started on that input (woke up for it, or inputs before) */
    STAGE_QUEUED_STEP,    /* that input's decode and step */
    STAGE_QUEUED_PUBLISH, /* publishing that input's poses */
    STAGE_WAKE,           /* -> its handler called (the wake-up; through liblcm's thread, also its pipe) */
    STAGE_DECODE,         /* -> vl_session_input called */
    STAGE_PUBLISH,        /* the step's end -> its VISLAM_POSE encoded and lcm_publish called */
    STAGE_RETURN,         /* -> kernel receive stamp on the replay's socket */
    STAGE_REPLAY_WAKE,    /* -> the replay's pose handler called (its wake-up) */
    STAGE_OTHER,
    STAGE_COUNT
};

static const char *const stage_name[STAGE_COUNT] = {"send",   "queued_wake", "queued_step", "queued_publish", "wake",
                                                    "decode", "publish",     "return",      "replay_wake",    "other"};

typedef struct {
    double *us;                    /* per frame answered, in order: frame published to pose received, us */
    int64_t *utime;                /* its frame's utime, us */
    int64_t *stamp[3];             /* the replay's CLOCK_REALTIME ns: published, pose received (kernel), handled */
    double *overhead_us;           /* us minus vislamd's step for the same frame (LCM's share), in order */
    double *stage_us[STAGE_COUNT]; /* per frame paired with full stamps, in order */
    size_t n, n_overhead, n_stages, cap;
    long long expected, returned;
    long long unpaired; /* frames answered that vislamd's step samples do not hold */
    int failed;         /* a helper failed */
} e2e_t;

/* Grows *p to cap elements of size bytes; 0, or -1 (and *p kept) when out of memory. */
static int grow(void **p, size_t cap, size_t size)
{
    void *q = realloc(*p, cap * size);
    if (q == NULL) {
        return -1;
    }
    *p = q;
    return 0;
}

/* Room for one more frame in every array of e; -1 when out of memory. */
static int e2e_reserve(e2e_t *e)
{
    if (e->n < e->cap) {
        return 0;
    }
    const size_t cap = e->cap ? 2 * e->cap : 4096;
    int bad = grow((void **)&e->us, cap, sizeof(double)) | grow((void **)&e->utime, cap, sizeof(int64_t)) |
              grow((void **)&e->overhead_us, cap, sizeof(double));
    for (int k = 0; k < 3; ++k) {
        bad |= grow((void **)&e->stamp[k], cap, sizeof(int64_t));
    }
    for (int k = 0; k < STAGE_COUNT; ++k) {
        bad |= grow((void **)&e->stage_us[k], cap, sizeof(double));
    }
    if (bad) {
        return -1;
    }
    e->cap = cap;
    return 0;
}

/* Appends the replay's --latency-samples (a line per frame: latency us, utime us, then its three
   stamps, ns; a line without them leaves them 0). */
static int read_samples(const char *path, e2e_t *e)
{
    FILE *f = fopen(path, "r");
    if (f == NULL) {
        return -1;
    }
    char line[256];
    while (fgets(line, sizeof(line), f) != NULL && e2e_reserve(e) == 0) {
        long long v, utime, t[3] = {0, 0, 0};
        if (sscanf(line, "%lld %lld %lld %lld %lld", &v, &utime, &t[0], &t[1], &t[2]) < 2) {
            continue;
        }
        e->us[e->n] = (double)v;
        e->utime[e->n] = (int64_t)utime;
        for (int k = 0; k < 3; ++k) {
            e->stamp[k][e->n] = (int64_t)t[k];
        }
        e->n++;
    }
    fclose(f);
    return 0;
}

/* One line of vislamd's --step-samples: utime us, step ns, then its stamps (ns, 0 when absent). */
typedef struct {
    int64_t utime, ns;
    int64_t rx, free, handler, step, sent;
    int64_t prev_handler, prev_sink;
} daemon_sample_t;

static int64_t clamp64(int64_t v, int64_t lo, int64_t hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

/* Frame i's stages from its stamps and the daemon's sample d, into e->stage_us; nothing when a
   stamp is missing. */
static void add_stages(e2e_t *e, size_t i, const daemon_sample_t *d)
{
    const int64_t pub = e->stamp[0][i], rx = e->stamp[1][i], handled = e->stamp[2][i];
    if (pub <= 0 || rx <= 0 || handled <= 0 || d->rx <= 0 || d->handler <= 0 || d->step <= 0 || d->sent <= 0) {
        return;
    }
    const int64_t ready = d->free > d->rx ? d->free : d->rx; /* the daemon could take the frame */
    /* The wait behind the previous input: before the daemon started on it, then its step, then
       its publishing (the end of its handling). */
    const int64_t queued = ready - d->rx;
    const int64_t q_wake = clamp64(d->prev_handler - d->rx, 0, queued);
    const int64_t q_publish = clamp64(d->prev_sink, 0, queued - q_wake);
    const double ns[STAGE_COUNT - 1] = {(double)(d->rx - pub),
                                        (double)q_wake,
                                        (double)(queued - q_wake - q_publish),
                                        (double)q_publish,
                                        (double)(d->handler - ready),
                                        (double)(d->step - d->handler),
                                        (double)(d->sent - d->step - d->ns),
                                        (double)(rx - d->sent),
                                        (double)(handled - rx)};
    const size_t j = e->n_stages++;
    double sum = 0.0;
    for (int k = 0; k < STAGE_COUNT - 1; ++k) {
        e->stage_us[k][j] = ns[k] * 1e-3;
        sum += ns[k] * 1e-3;
    }
    e->stage_us[STAGE_OTHER][j] = e->us[i] - (double)d->ns * 1e-3 - sum;
}

/*
 * Pairs the frames e[from..n) with vislamd's --step-samples (a line per frame it stepped, in its
 * order: utime us, step ns, stamps) by utime, in order (a utime repeated by a new timeline pairs
 * with the next step of that utime), and appends each frame's end to end minus step to
 * e->overhead_us, and its stages to e->stage_us.
 */
static void pair_steps(const char *path, e2e_t *e, size_t from)
{
    size_t m = 0, cap = 0;
    daemon_sample_t *ds = NULL;
    FILE *f = fopen(path, "r");
    char line[256];
    while (f != NULL && fgets(line, sizeof(line), f) != NULL) {
        long long v[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
        if (sscanf(line, "%lld %lld %lld %lld %lld %lld %lld %lld %lld", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5],
                   &v[6], &v[7], &v[8]) < 2) {
            continue;
        }
        if (m == cap) {
            cap = cap ? 2 * cap : 4096;
            if (grow((void **)&ds, cap, sizeof(*ds)) != 0) {
                break;
            }
        }
        const daemon_sample_t s = {v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]};
        ds[m++] = s;
    }
    if (f != NULL) {
        fclose(f);
    }
    size_t next = 0;
    for (size_t i = from; i < e->n; ++i) {
        size_t k = next;
        while (k < m && ds[k].utime != e->utime[i]) {
            ++k;
        }
        if (k == m) {
            e->unpaired++;
            continue;
        }
        e->overhead_us[e->n_overhead++] = e->us[i] - (double)ds[k].ns * 1e-3;
        add_stages(e, i, &ds[k]);
        next = k + 1;
    }
    free(ds);
}

/* The LCM options vislamd and the replay take alike, appended at argv[k]; returns the new count. */
static int add_lcm_args(const char **argv, int k, const options_t *o)
{
    if (o->lcm_url != NULL) {
        argv[k++] = "--lcm-url";
        argv[k++] = o->lcm_url;
    }
    if (o->busy_poll_us != NULL) {
        argv[k++] = "--busy-poll-us";
        argv[k++] = o->busy_poll_us;
    }
    if (o->lcm_receive_thread) {
        argv[k++] = "--lcm-receive-thread";
    }
    return k;
}

static void run_e2e(const char *dir, e2e_t *e)
{
    char vislamd[PATH_LEN], replay[PATH_LEN];
    path_join(vislamd, sizeof(vislamd), self_dir, "vislamd");
    path_join(replay, sizeof(replay), self_dir, "vislam-replay");
    if (!file_exists(vislamd) || !file_exists(replay)) {
        fprintf(stderr, "vislam-latency: vislamd and vislam-replay must be beside this program (%s)\n", self_dir);
        e->failed = 1;
        return;
    }
    char cpu[16], prio[16], timeout[24], worker_cpu[16];
    snprintf(cpu, sizeof(cpu), "%d", opt.cpu);
    snprintf(worker_cpu, sizeof(worker_cpu), "%d", opt.worker.cpu);
    snprintf(prio, sizeof(prio), "%d", opt.rt_priority);
    snprintf(timeout, sizeof(timeout), "%ld", opt.timeout_ms);
    for (int pass = 0; pass < opt.passes; ++pass) {
        char traj[PATH_LEN], dlog[PATH_LEN], rlog[PATH_LEN], json[PATH_LEN], samples[PATH_LEN], steps[PATH_LEN];
        char name[64];
        snprintf(name, sizeof(name), "vislamd_%d.tum", pass);
        path_join(traj, sizeof(traj), dir, name);
        snprintf(name, sizeof(name), "vislamd_%d.log", pass);
        path_join(dlog, sizeof(dlog), dir, name);
        snprintf(name, sizeof(name), "replay_%d.log", pass);
        path_join(rlog, sizeof(rlog), dir, name);
        snprintf(name, sizeof(name), "replay_%d.json", pass);
        path_join(json, sizeof(json), dir, name);
        snprintf(name, sizeof(name), "e2e_%d.txt", pass);
        path_join(samples, sizeof(samples), dir, name);
        snprintf(name, sizeof(name), "steps_%d.txt", pass);
        path_join(steps, sizeof(steps), dir, name);
        unlink(traj); /* vislamd appends */
        const char *dargv[28];
        int k = 0;
        dargv[k++] = vislamd;
        dargv[k++] = "--trajectory";
        dargv[k++] = traj;
        dargv[k++] = "--cpu";
        dargv[k++] = cpu;
        dargv[k++] = "--step-samples";
        dargv[k++] = steps;
        if (opt.rt_priority > 0) {
            dargv[k++] = "--rt-priority";
            dargv[k++] = prio;
        }
        k = add_lcm_args(dargv, k, &opt);
        if (opt.config_path != NULL) {
            dargv[k++] = "--config";
            dargv[k++] = opt.config_path;
        }
        if (opt.cpu_dma_latency != NULL) {
            dargv[k++] = "--cpu-dma-latency";
            dargv[k++] = opt.cpu_dma_latency;
        }
        if (opt.warm_us != NULL) {
            dargv[k++] = "--warm-us";
            dargv[k++] = opt.warm_us;
        }
        if (opt.supersede_imu_poses) {
            dargv[k++] = "--supersede-imu-poses";
        }
        if (opt.keep_awake) {
            dargv[k++] = "--keep-awake";
        }
        if (opt.worker.threads > 1) {
            dargv[k++] = "--threads";
            dargv[k++] = "2";
            dargv[k++] = "--worker-cpu";
            dargv[k++] = worker_cpu;
        }
        dargv[k] = NULL;
        const char *rargv[28];
        int r = 0;
        rargv[r++] = replay;
        rargv[r++] = opt.log_path;
        rargv[r++] = "--lockstep";
        if (opt.rate_max) {
            rargv[r++] = "--max";
        }
        rargv[r++] = "--wait-for";
        rargv[r++] = VL_CHANNEL_STATUS;
        rargv[r++] = "--wait-timeout-ms";
        rargv[r++] = "10000";
        rargv[r++] = "--timeout-ms";
        rargv[r++] = timeout;
        rargv[r++] = "--summary-json";
        rargv[r++] = json;
        rargv[r++] = "--latency-samples";
        rargv[r++] = samples;
        rargv[r++] = "--linger-ms";
        rargv[r++] = "0";
        r = add_lcm_args(rargv, r, &opt);
        rargv[r] = NULL;
        /* vislamd pins and schedules itself (its own warnings if refused); the replay is pinned here. */
        const pid_t daemon = spawn((char *const *)dargv, dlog, -1, 0);
        const pid_t player = spawn((char *const *)rargv, rlog, opt.other_cpu, opt.rt_priority);
        const int rc = wait_child(player);
        if (daemon > 0) {
            kill(daemon, SIGTERM);
        }
        const int drc = wait_child(daemon);
        const long long expected = json_int(json, "frames_expected");
        const long long returned = json_int(json, "frames_returned");
        if (!opt.quiet) {
            fprintf(stderr,
                    "vislam-latency: end-to-end pass %d: %lld of %lld poses back (replay exit %d, vislamd exit %d)\n",
                    pass + 1, returned, expected, rc, drc);
        }
        if (expected > 0 && returned > 0) {
            e->expected += expected;
            e->returned += returned;
            const size_t from = e->n;
            read_samples(samples, e);
            pair_steps(steps, e, from);
            continue;
        }
        fprintf(stderr,
                "vislam-latency: NO POSES came back from vislamd (LCM url %s)%s: is multicast routed? On a\n"
                "  host without a multicast route run inside `unshare --net` after `ip link set lo up multicast\n"
                "  on; ip route add 224.0.0.0/4 dev lo`, or pass a working --lcm-url. See %s and %s\n",
                opt.lcm_url != NULL ? opt.lcm_url : "default", expected < 0 ? " and the replay wrote no summary" : "",
                dlog, rlog);
        e->expected += expected > 0 ? expected : 0;
        e->failed = 1;
        break;
    }
}

/* ---- cyclictest ---- */

static pid_t start_cyclictest(const char *out, int cpus, int priority)
{
    static const char *const candidates[] = {"/usr/bin/cyclictest", "/usr/sbin/cyclictest",
                                             "/usr/local/bin/cyclictest"};
    const char *bin = NULL;
    for (size_t i = 0; i < sizeof(candidates) / sizeof(candidates[0]); ++i) {
        if (file_exists(candidates[i])) {
            bin = candidates[i];
        }
    }
    if (bin == NULL) {
        fprintf(stderr, "vislam-latency: --cyclictest: cyclictest not installed (Debian: rt-tests); skipped\n");
        return -1;
    }
    char threads[16], prio[16], affinity[32];
    snprintf(threads, sizeof(threads), "-t%d", cpus);
    snprintf(prio, sizeof(prio), "-p%d", priority > 0 ? priority + 1 : 1);
    snprintf(affinity, sizeof(affinity), "-a0-%d", cpus - 1);
    const char *argv[] = {bin, "-q", "-m", "-i1000", "-d0", threads, affinity, prio, NULL};
    return spawn((char *const *)argv, out, -1, 0);
}

/* The largest "Max:" of cyclictest's summary, us; -1 if none. */
static long cyclictest_max(const char *out)
{
    FILE *f = fopen(out, "r");
    if (f == NULL) {
        return -1;
    }
    char line[512];
    long best = -1;
    while (fgets(line, sizeof(line), f) != NULL) {
        const char *p = strstr(line, "Max:");
        if (p != NULL) {
            const long v = strtol(p + 4, NULL, 10);
            best = v > best ? v : best;
        }
    }
    fclose(f);
    return best;
}

/* ---- callgrind ---- */

/* Re-runs one in-process pass as fast as possible under callgrind, counting inside vl_update only. */
static double callgrind_per_update(const char *dir, size_t frames)
{
    char out[PATH_LEN], log[PATH_LEN], self[PATH_LEN + 32], toggle[] = "--toggle-collect=vl_update";
    path_join(out, sizeof(out), dir, "callgrind.out");
    path_join(log, sizeof(log), dir, "callgrind.log");
    path_join(self, sizeof(self), self_dir, "vislam-latency");
    char outarg[PATH_LEN + 32];
    snprintf(outarg, sizeof(outarg), "--callgrind-out-file=%s", out);
    const char *argv[20];
    int k = 0;
    argv[k++] = "/usr/bin/valgrind";
    argv[k++] = "--tool=callgrind";
    argv[k++] = outarg;
    argv[k++] = toggle;
    argv[k++] = self;
    argv[k++] = opt.log_path;
    argv[k++] = "--no-e2e";
    argv[k++] = "--no-probe";
    argv[k++] = "--rate";
    argv[k++] = "max";
    argv[k++] = "--quiet";
    if (opt.config_path != NULL) {
        argv[k++] = "--config";
        argv[k++] = opt.config_path;
    }
    argv[k] = NULL;
    if (!file_exists(argv[0])) {
        fprintf(stderr, "vislam-latency: --callgrind: valgrind not installed; skipped\n");
        return -1.0;
    }
    const int rc = wait_child(spawn((char *const *)argv, log, -1, 0));
    FILE *f = fopen(out, "r");
    if (rc != 0 || f == NULL) {
        fprintf(stderr,
                "vislam-latency: --callgrind: valgrind failed (exit %d; see %s): a build for the host CPU may use\n"
                "  instructions valgrind cannot run (AVX-512); build with -DVL_NATIVE=OFF\n",
                rc, log);
        if (f != NULL) {
            fclose(f);
        }
        return -1.0;
    }
    char line[512];
    double total = -1.0;
    while (fgets(line, sizeof(line), f) != NULL) {
        if (strncmp(line, "totals:", 7) == 0 || strncmp(line, "summary:", 8) == 0) {
            total = strtod(strchr(line, ':') + 1, NULL);
        }
    }
    fclose(f);
    return total >= 0.0 && frames > 0 ? total / (double)frames : -1.0;
}

/* ---- the plot ---- */

static int run_plot(const char *json, const char *png)
{
    char python[PATH_LEN], tools[PATH_LEN], pythonpath[PATH_LEN + 16];
    const char *env_python = getenv("VISLAM_PYTHON");
    const char *env_tools = getenv("VISLAM_TOOLS_DIR");
    snprintf(tools, sizeof(tools), "%s", env_tools != NULL && env_tools[0] != '\0' ? env_tools : VL_TOOLS_DIR);
    if (env_python != NULL && env_python[0] != '\0') {
        snprintf(python, sizeof(python), "%s", env_python);
    } else {
        path_join(python, sizeof(python), tools, "../.venv/bin/python");
        if (!file_exists(python)) {
            snprintf(python, sizeof(python), "/usr/bin/python3");
        }
    }
    snprintf(pythonpath, sizeof(pythonpath), "PYTHONPATH=%s", tools);
    putenv(pythonpath);
    const char *argv[] = {python, "-m", "vislam_tools.latency_plot", json, png, NULL};
    const int rc = wait_child(spawn((char *const *)argv, NULL, -1, 0));
    if (rc != 0) {
        fprintf(stderr, "vislam-latency: the plot failed (%s -m vislam_tools.latency_plot, exit %d)\n", python, rc);
        return -1;
    }
    return 0;
}

/* ---- output ---- */

typedef struct {
    summary_t step, prop, e2e, lcm, jitter_cpu[VL_JITTER_MAX_CPUS];
    summary_t stage[STAGE_COUNT]; /* the LCM overhead's stages */
    summary_t transport;          /* the LCM overhead less its queued stages: LCM's and the OS's own share */
    double jitter_max, jitter_p99;
    int jitter_cpus;
    uint64_t jitter_samples;
    double work_p50, work_max, work_mean;
    summary_t prop_work;     /* each IMU step's work */
    summary_t frame_work;    /* each frame step's work plus the IMU steps' before it */
    summary_t deferred;      /* the frame's work after the pose (vl_session_finish), where there was some: us */
    summary_t deferred_work; /* its work */
    const step_t *costliest; /* slowest step */
    const step_t *heaviest;  /* step with the most work */
    uint64_t overruns;       /* in-process steps over the budget */
    uint64_t e2e_overruns;   /* end-to-end latencies over the budget */
    long budget_us;
    uint32_t window;
    double callgrind;
    long cyclictest_max;
    int rt_granted;
    int cpu_latency_held;  /* the in-process pass held its --cpu-dma-latency request */
    int worker_running;    /* the in-process pass shared its updates with a worker */
    double worker_share;   /* of the blocks handed out, those the worker ran */
    uint64_t worker_loops; /* parallel loops handed out (two per joint update) */
    int awake_started;     /* --keep-awake: the in-process pass's spinner ran */
    uint64_t awake_loops;  /* its spin loops */
} results_t;

static void write_work(FILE *f, const vl_work_t *w)
{
    fprintf(f,
            "{\"flops\": %" PRIu64 ", \"predict\": %" PRIu64 ", \"gate\": %" PRIu64 ", \"ransac\": %" PRIu64
            ", \"update\": %" PRIu64 ", \"rescue\": %" PRIu64 ", \"window\": %" PRIu64
            ", \"state_dim\": %u, \"rows\": %u, \"hypotheses\": %u}",
            w->flops, w->predict, w->gate, w->ransac, w->update, w->rescue, w->window, (unsigned)w->state_dim,
            (unsigned)w->rows, (unsigned)w->hypotheses);
}

static void write_step(FILE *f, const char *key, const step_t *s, const results_t *res, const char *tail)
{
    fprintf(f,
            "  \"%s\": {\"pass\": %d, \"frame\": %u, \"utime\": %" PRId64 ", \"us\": %.3f, \"us_ratio_to_p50\": %.3f, "
            "\"work_ratio_to_p50\": %.3f, \"work\": ",
            key, s->pass + 1, (unsigned)s->frame, s->utime, (double)s->ns * 1e-3,
            res->step.p50 > 0 ? (double)s->ns * 1e-3 / res->step.p50 : 0.0,
            res->work_p50 > 0 ? (double)s->work.flops / res->work_p50 : 0.0);
    write_work(f, &s->work);
    fprintf(f, "}%s\n", tail);
}

static int write_json(const char *path, const log_t *lg, const results_t *res, const double *step_sorted,
                      const e2e_t *e, const vl_jitter_t *jit, const vl_latency_t *jmerged, size_t nsteps)
{
    FILE *f = fopen(path, "w");
    if (f == NULL) {
        fprintf(stderr, "vislam-latency: cannot write %s: %s\n", path, strerror(errno));
        return -1;
    }
    /* The path as given, or null when it would need escaping. */
    int plain = 1;
    for (const char *c = opt.log_path; *c != '\0'; ++c) {
        plain &= *c != '"' && *c != '\\' && (unsigned char)*c >= 0x20;
    }
    fprintf(f, plain ? "{\n  \"log\": \"%s\",\n" : "{\n  \"log\": null,\n", opt.log_path);
    fprintf(f, "  \"window\": %u,\n  \"passes\": %d,\n  \"frames_per_pass\": %zu,\n", (unsigned)res->window, opt.passes,
            lg->frames);
    fprintf(f, "  \"rate\": \"%s\",\n  \"cpu\": %d,\n  \"other_cpu\": %d,\n  \"rt_priority\": %d,\n",
            opt.rate_max ? "max" : "sensor", opt.cpu, opt.other_cpu, opt.rt_priority);
    fprintf(f, "  \"rt_granted\": %s,\n  \"load\": %s,\n  \"steps\": %zu,\n  \"budget_us\": %ld,\n",
            res->rt_granted ? "true" : "false", opt.load ? "true" : "false", nsteps, res->budget_us);
    if (opt.cpu_dma_latency_us >= 0) {
        fprintf(f, "  \"cpu_dma_latency_us\": %d,\n  \"cpu_dma_latency_held\": %s,\n", opt.cpu_dma_latency_us,
                res->cpu_latency_held ? "true" : "false");
    } else {
        fprintf(f, "  \"cpu_dma_latency_us\": null,\n  \"cpu_dma_latency_held\": false,\n");
    }
    fprintf(f,
            "  \"warm_us\": %ld,\n  \"warm\": {\"periods\": %" PRIu64 ", \"touch_us\": %" PRIu64
            ", \"spin_us\": %" PRIu64 "},\n  \"supersede_imu_poses\": %s,\n",
            opt.warm_us_n, g_warm.windows, g_warm.touch_us, g_warm.spin_us, opt.supersede_imu_poses ? "true" : "false");
    fprintf(f, "  \"keep_awake\": %s,\n  \"keep_awake_loops\": %" PRIu64 ",\n", opt.keep_awake ? "true" : "false",
            res->awake_loops);
    fprintf(f, "  \"threads\": %d,\n  \"worker_cpu\": ", res->worker_running ? 2 : 1);
    fprintf(f, res->worker_running ? "%d" : "null", opt.worker.cpu);
    fprintf(f, ",\n  \"worker_share\": %.4f,\n  \"worker_loops\": %" PRIu64 ",\n", res->worker_share,
            res->worker_loops);
    fprintf(f, "  \"overruns\": %" PRIu64 ",\n  \"e2e_overruns\": %" PRIu64 ",\n", res->overruns, res->e2e_overruns);
    json_summary(f, "step_us", &res->step, ",");
    json_summary(f, "propagate_us", &res->prop, ",");
    json_summary(f, "e2e_us", opt.e2e ? &res->e2e : NULL, ",");
    json_summary(f, "lcm_overhead_us", opt.e2e ? &res->lcm : NULL, ",");
    fprintf(f, "  \"e2e_frames\": {\"expected\": %lld, \"returned\": %lld, \"paired\": %zu},\n", e->expected,
            e->returned, e->n_overhead);
    json_summary(f, "lcm_transport_us", opt.e2e ? &res->transport : NULL, ",");
    if (!opt.e2e || e->n_stages == 0) {
        fprintf(f, "  \"lcm_stages_us\": null,\n");
    } else {
        fprintf(f, "  \"lcm_stages_us\": {\n");
        for (int k = 0; k < STAGE_COUNT; ++k) {
            json_summary_at(f, "    ", stage_name[k], &res->stage[k], k + 1 < STAGE_COUNT ? "," : "");
        }
        fprintf(f, "  },\n");
    }
    fprintf(f, "  \"jitter_floor_us\": ");
    if (res->jitter_samples == 0) {
        fprintf(f, "null,\n");
    } else {
        fprintf(f, "{\"max\": %.1f, \"p99\": %.1f, \"samples\": %" PRIu64 ", \"period_us\": %d, \"per_cpu\": [",
                res->jitter_max, res->jitter_p99, res->jitter_samples, VL_JITTER_PERIOD_US);
        for (int c = 0; c < jit->count; ++c) {
            const vl_latency_t *h = &jit->probes[c].late;
            fprintf(f, "%s{\"cpu\": %d, \"max\": %lld, \"p99\": %lld, \"p50\": %lld, \"samples\": %" PRIu64 "}",
                    c == 0 ? "" : ", ", jit->probes[c].cpu, (long long)vl_latency_max(h),
                    (long long)vl_latency_percentile(h, 99.0), (long long)vl_latency_percentile(h, 50.0),
                    vl_latency_count(h));
        }
        fprintf(f, "]},\n");
    }
    fprintf(f, "  \"cyclictest_max_us\": ");
    if (res->cyclictest_max >= 0) {
        fprintf(f, "%ld,\n", res->cyclictest_max);
    } else {
        fprintf(f, "null,\n");
    }
    fprintf(f, "  \"work\": {\"p50\": %.0f, \"max\": %.0f, \"mean\": %.0f, \"max_ratio_to_p50\": %.3f},\n",
            res->work_p50, res->work_max, res->work_mean, res->work_p50 > 0 ? res->work_max / res->work_p50 : 0.0);
    fprintf(f, "  \"propagate_work\": {\"p50\": %.0f, \"max\": %.0f, \"mean\": %.0f},\n", res->prop_work.p50,
            res->prop_work.max, res->prop_work.mean);
    fprintf(f, "  \"frame_work\": {\"p50\": %.0f, \"max\": %.0f, \"mean\": %.0f, \"max_ratio_to_p50\": %.3f},\n",
            res->frame_work.p50, res->frame_work.max, res->frame_work.mean,
            res->frame_work.p50 > 0 ? res->frame_work.max / res->frame_work.p50 : 0.0);
    json_summary(f, "deferred_us", res->deferred.n > 0 ? &res->deferred : NULL, ",");
    fprintf(f, "  \"deferred_work\": {\"p50\": %.0f, \"max\": %.0f, \"mean\": %.0f, \"n\": %zu},\n",
            res->deferred_work.p50, res->deferred_work.max, res->deferred_work.mean, res->deferred_work.n);
    write_step(f, "costliest_step", res->costliest, res, ",");
    write_step(f, "heaviest_step", res->heaviest, res, ",");
    fprintf(f, "  \"callgrind_instructions_per_update\": ");
    if (res->callgrind > 0) {
        fprintf(f, "%.0f,\n", res->callgrind);
    } else {
        fprintf(f, "null,\n");
    }
    /* The samples the plot draws: sorted step and end-to-end times, the LCM overhead per frame in
       frame order (pass after pass), and the jitter histogram. */
    fprintf(f, "  \"samples\": {\n");
    json_array(f, "step_us", step_sorted, nsteps, ",");
    json_array(f, "e2e_us", e->us, opt.e2e ? e->n : 0, ",");
    json_array(f, "lcm_overhead_us", e->overhead_us, opt.e2e ? e->n_overhead : 0, ",");
    fprintf(f, "    \"lcm_stages_us\": {\n");
    for (int k = 0; k < STAGE_COUNT; ++k) {
        json_array_at(f, "      ", stage_name[k], e->stage_us[k], opt.e2e ? e->n_stages : 0,
                      k + 1 < STAGE_COUNT ? "," : "");
    }
    fprintf(f, "    },\n");
    fprintf(f, "    \"jitter_hist_us\": [");
    int first = 1;
    for (size_t b = 0; b < VL_LATENCY_BUCKETS; ++b) {
        if (jmerged->buckets[b] != 0) {
            fprintf(f, "%s[%lld, %" PRIu64 "]", first ? "" : ",", (long long)vl_latency_bucket_upper(b),
                    jmerged->buckets[b]);
            first = 0;
        }
    }
    fprintf(f, "]\n  }\n}\n");
    const int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        fprintf(stderr, "vislam-latency: write error on %s\n", path);
        return -1;
    }
    return 0;
}

/* ---- main ---- */

static void find_self_dir(const char *argv0)
{
    char buf[PATH_LEN];
    const ssize_t n = readlink("/proc/self/exe", buf, sizeof(buf) - 1);
    if (n > 0) {
        buf[n] = '\0';
    } else {
        snprintf(buf, sizeof(buf), "%s", argv0);
    }
    char *slash = strrchr(buf, '/');
    if (slash != NULL) {
        *slash = '\0';
        snprintf(self_dir, sizeof(self_dir), "%s", buf);
    } else {
        snprintf(self_dir, sizeof(self_dir), ".");
    }
}

/* Back to normal scheduling on every CPU, so that the helpers started later (vislamd, valgrind,
   the plot) choose their own CPU and priority instead of inheriting the measurement's. */
static void release_rt(int cpus)
{
    (void)munlockall();
    struct sched_param sp;
    memset(&sp, 0, sizeof(sp));
    (void)sched_setscheduler(0, SCHED_OTHER, &sp);
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int c = 0; c < cpus && c < CPU_SETSIZE; ++c) {
        CPU_SET(c, &set);
    }
    (void)sched_setaffinity(0, sizeof(set), &set);
}

/* Removes the files of a directory this program made, then the directory. */
static void remove_work_dir(const char *dir)
{
    char cmd[PATH_LEN + 32];
    snprintf(cmd, sizeof(cmd), "%s", dir);
    const char *argv[] = {"/bin/rm", "-rf", cmd, NULL};
    (void)wait_child(spawn((char *const *)argv, NULL, -1, 0));
}

int main(int argc, char **argv)
{
    if (parse_args(argc, argv, &opt) != 0) {
        return EXIT_USAGE;
    }
    find_self_dir(argv[0]);
    static log_t lg;
    if (load_log(opt.log_path, &lg) != 0) {
        return EXIT_USAGE;
    }
    vl_config_t cfg;
    vl_config_file_info_t info;
    if (build_config(&cfg, &info) != 0) {
        return EXIT_USAGE;
    }
    results_t res;
    memset(&res, 0, sizeof(res));
    res.window = cfg.max_landmarks;
    res.budget_us = opt.budget_us > 0 ? opt.budget_us : (long)lg.frame_period_us;
    res.cyclictest_max = -1;

    char dir[PATH_LEN];
    int made_dir = 0;
    if (opt.work_dir != NULL) {
        snprintf(dir, sizeof(dir), "%s", opt.work_dir);
        mkdir(dir, 0755);
    } else {
        const char *tmp = getenv("TMPDIR");
        snprintf(dir, sizeof(dir), "%s/vislam-latency.XXXXXX", tmp != NULL && tmp[0] != '\0' ? tmp : "/tmp");
        if (mkdtemp(dir) == NULL) {
            fprintf(stderr, "vislam-latency: cannot create a work directory: %s\n", strerror(errno));
            return EXIT_INCOMPLETE;
        }
        made_dir = 1;
    }

    const size_t max_steps = lg.frames * (size_t)opt.passes;
    step_t *steps = (step_t *)calloc(max_steps, sizeof(step_t));
    double *prop_us = (double *)calloc(lg.count * (size_t)opt.passes, sizeof(double));
    double *step_us = (double *)calloc(max_steps, sizeof(double));
    double *work = (double *)calloc(max_steps, sizeof(double));
    double *prop_work = (double *)calloc(lg.count * (size_t)opt.passes, sizeof(double));
    if (steps == NULL || prop_us == NULL || step_us == NULL || work == NULL || prop_work == NULL) {
        fprintf(stderr, "vislam-latency: out of memory\n");
        return EXIT_INCOMPLETE;
    }

    /* The machine as measured: load on the other CPU, probes on every CPU, then this thread pinned. */
    const long online = sysconf(_SC_NPROCESSORS_ONLN);
    const int cpus = online > 0 ? (int)online : 1;
    pid_t load = -1, cyclic = -1;
    char cyclic_out[PATH_LEN];
    path_join(cyclic_out, sizeof(cyclic_out), dir, "cyclictest.txt");
    if (opt.load) {
        load = start_load(opt.other_cpu);
    }
    static vl_jitter_t jit;
    if (opt.probe) {
        vl_jitter_start(&jit, cpus, opt.rt_priority > 0 ? opt.rt_priority + 1 : 0);
    }
    if (opt.cyclictest) {
        cyclic = start_cyclictest(cyclic_out, cpus, opt.rt_priority);
    }
    char msg[256];
    if (vl_rt_set_affinity(opt.cpu, msg, sizeof(msg)) != VL_RT_OK) {
        fprintf(stderr, "vislam-latency: warning: %s\n", msg);
    }
    int cpu_latency_fd = -1;
    if (opt.cpu_dma_latency_us >= 0) {
        res.cpu_latency_held =
            vl_rt_request_cpu_latency(opt.cpu_dma_latency_us, &cpu_latency_fd, msg, sizeof(msg)) == VL_RT_OK;
        if (!res.cpu_latency_held) {
            fprintf(stderr, "vislam-latency: warning: %s\n", msg);
        } else if (!opt.quiet) {
            fprintf(stderr, "vislam-latency: %s\n", msg);
        }
    }
    if (opt.rt_priority > 0) {
        res.rt_granted = vl_rt_set_fifo(opt.rt_priority, msg, sizeof(msg)) == VL_RT_OK;
        if (!res.rt_granted) {
            fprintf(stderr, "vislam-latency: warning: %s; measuring at normal priority\n", msg);
        }
        if (vl_rt_lock_memory(msg, sizeof(msg)) != VL_RT_OK) {
            fprintf(stderr, "vislam-latency: warning: %s\n", msg);
        }
    }

    if (opt.worker.threads > 1) {
        opt.worker.priority = res.rt_granted ? opt.rt_priority : 0;
        if (vl_worker_start(&g_worker, &opt.worker, msg, sizeof(msg)) != 0) {
            fprintf(stderr, "vislam-latency: warning: %s\n", msg);
        } else if (!opt.quiet) {
            fprintf(stderr, "vislam-latency: %s\n", msg);
        }
        res.worker_running = vl_worker_running(&g_worker);
    }
    static vl_awake_t awake;
    if (opt.keep_awake) {
        /* vl_awake pins the spinner and sets its policy itself: it inherits nothing from this thread. */
        res.awake_started = vl_awake_start(&awake, opt.cpu, msg, sizeof(msg)) == 0;
        if (!res.awake_started || !opt.quiet) {
            fprintf(stderr, "vislam-latency: %s%s\n", res.awake_started ? "" : "warning: ", msg);
        }
    }

    size_t nsteps = 0, nprop = 0;
    if (!opt.quiet) {
        fprintf(stderr, "vislam-latency: %s: %zu frames x %d pass(es), rate %s, CPU %d (other %d)%s\n", opt.log_path,
                lg.frames, opt.passes, opt.rate_max ? "max" : "sensor", opt.cpu, opt.other_cpu,
                opt.load ? ", load on the other CPU" : "");
    }
    const int ip_rc = run_in_process(&lg, steps, &nsteps, prop_us, prop_work, &nprop);
    {
        uint64_t tasks = 0, worker_tasks = 0;
        vl_worker_counts(&g_worker, &res.worker_loops, &tasks, &worker_tasks);
        res.worker_share = tasks > 0 ? (double)worker_tasks / (double)tasks : 0.0;
    }
    vl_worker_stop(&g_worker);
    vl_awake_stop(&awake);
    res.awake_loops = vl_awake_loops(&awake);
    release_rt(cpus);
    /* The end-to-end pass is measured with vislamd's own request only. */
    vl_rt_release_cpu_latency(&cpu_latency_fd);
    /* The end-to-end pass's processes pin and schedule themselves; this thread only waits. */
    static e2e_t e2e;
    if (ip_rc == 0 && opt.e2e) {
        run_e2e(dir, &e2e);
    }
    if (opt.probe) {
        vl_jitter_stop(&jit);
    }
    if (cyclic > 0) {
        kill(cyclic, SIGINT);
        (void)wait_child(cyclic);
        res.cyclictest_max = cyclictest_max(cyclic_out);
    }
    stop_child(load);
    if (ip_rc != 0) {
        return EXIT_INCOMPLETE;
    }

    /* Statistics. */
    size_t slowest = 0, heaviest = 0;
    for (size_t i = 0; i < nsteps; ++i) {
        step_us[i] = (double)steps[i].ns * 1e-3;
        work[i] = (double)steps[i].work.flops;
        slowest = steps[i].ns > steps[slowest].ns ? i : slowest;
        heaviest = steps[i].work.flops > steps[heaviest].work.flops ? i : heaviest;
        res.overruns += step_us[i] > (double)res.budget_us;
    }
    res.costliest = &steps[slowest];
    res.heaviest = &steps[heaviest];
    res.step = summarize(step_us, nsteps);
    res.prop = summarize(prop_us, nprop);
    for (size_t i = 0; i < e2e.n; ++i) {
        res.e2e_overruns += e2e.us[i] > (double)res.budget_us;
    }
    res.e2e = summarize(e2e.us, e2e.n);
    double *lcm_sorted = (double *)malloc((e2e.n_overhead > 0 ? e2e.n_overhead : 1) * sizeof(double));
    if (lcm_sorted != NULL && e2e.n_overhead > 0) {
        memcpy(lcm_sorted, e2e.overhead_us, e2e.n_overhead * sizeof(double));
        res.lcm = summarize(lcm_sorted, e2e.n_overhead);
    }
    free(lcm_sorted);
    double *stage_sorted = (double *)malloc((e2e.n_stages > 0 ? e2e.n_stages : 1) * sizeof(double));
    for (int k = 0; k < STAGE_COUNT && stage_sorted != NULL && e2e.n_stages > 0; ++k) {
        memcpy(stage_sorted, e2e.stage_us[k], e2e.n_stages * sizeof(double));
        res.stage[k] = summarize(stage_sorted, e2e.n_stages);
    }
    for (size_t j = 0; j < e2e.n_stages && stage_sorted != NULL; ++j) {
        stage_sorted[j] = 0.0;
        for (int k = 0; k < STAGE_COUNT; ++k) {
            const int queued = k == STAGE_QUEUED_WAKE || k == STAGE_QUEUED_STEP || k == STAGE_QUEUED_PUBLISH;
            stage_sorted[j] += queued ? 0.0 : e2e.stage_us[k][j];
        }
    }
    res.transport = summarize(stage_sorted, stage_sorted != NULL ? e2e.n_stages : 0);
    free(stage_sorted);
    const summary_t w = summarize(work, nsteps);
    res.work_p50 = w.p50;
    res.work_max = w.max;
    res.work_mean = w.mean;
    res.prop_work = summarize(prop_work, nprop);
    for (size_t i = 0; i < nsteps; ++i) {
        work[i] = (double)steps[i].frame_flops;
    }
    res.frame_work = summarize(work, nsteps);
    size_t ndeferred = 0;
    for (size_t i = 0; i < nsteps; ++i) {
        if (steps[i].deferred_ns > 0) {
            step_us[ndeferred] = (double)steps[i].deferred_ns * 1e-3;
            work[ndeferred++] = (double)steps[i].deferred_flops;
        }
    }
    res.deferred = summarize(step_us, ndeferred);
    res.deferred_work = summarize(work, ndeferred);
    for (size_t i = 0; i < nsteps; ++i) { /* step_us again: the sorted step times the JSON and plot read */
        step_us[i] = (double)steps[i].ns * 1e-3;
    }
    res.step = summarize(step_us, nsteps);
    static vl_latency_t jmerged;
    vl_jitter_merged(&jit, &jmerged);
    res.jitter_samples = vl_latency_count(&jmerged);
    res.jitter_max = (double)vl_latency_max(&jmerged);
    res.jitter_p99 = (double)vl_latency_percentile(&jmerged, 99.0);
    if (opt.callgrind) {
        res.callgrind = callgrind_per_update(dir, lg.frames);
    }

    /* Report. */
    fprintf(stderr, "vislam-latency: %s, window %u, %zu steps (%zu frames x %d), rate %s, CPU %d%s%s\n", opt.log_path,
            (unsigned)res.window, nsteps, lg.frames, opt.passes, opt.rate_max ? "max" : "sensor", opt.cpu,
            res.rt_granted ? ", SCHED_FIFO" : "", opt.load ? ", loaded" : "");
    if (opt.cpu_dma_latency_us >= 0) {
        fprintf(stderr, "  cpu_dma_latency: %d us, %s in-process\n", opt.cpu_dma_latency_us,
                res.cpu_latency_held ? "held" : "refused");
    }
    if (opt.warm_us_n > 0) {
        fprintf(stderr,
                "  warm: %ld us before each input after an idle gap, in-process: %" PRIu64
                " periods, reading the state %.0f us"
                " and spinning %.0f us a period\n",
                opt.warm_us_n, g_warm.windows,
                g_warm.windows > 0 ? (double)g_warm.touch_us / (double)g_warm.windows : 0.0,
                g_warm.windows > 0 ? (double)g_warm.spin_us / (double)g_warm.windows : 0.0);
    }
    if (opt.keep_awake) {
        if (res.awake_started) {
            fprintf(stderr, "  keep awake: CPU %d, a SCHED_IDLE thread spun %" PRIu64 " loops in-process\n", opt.cpu,
                    res.awake_loops);
        } else {
            fprintf(stderr, "  keep awake: CPU %d, refused in-process\n", opt.cpu);
        }
    }
    if (res.worker_running) {
        fprintf(stderr, "  threads: 2 (worker on CPU %d ran %.1f%% of the update's blocks in-process)\n",
                opt.worker.cpu, 100.0 * res.worker_share);
    } else {
        fprintf(stderr, "  threads: 1\n");
    }
    print_summary("step (vl_update, in-process)", &res.step);
    print_summary("vl_propagate (in-process)", &res.prop);
    if (res.deferred.n > 0) {
        print_summary("deferred, after the pose", &res.deferred);
    }
    if (opt.e2e) {
        if (e2e.n > 0) {
            print_summary("end to end (vislamd, LCM)", &res.e2e);
        }
        if (res.lcm.n > 0) {
            print_summary("LCM overhead (e2e - its step)", &res.lcm);
        }
        for (int k = 0; k < STAGE_COUNT && e2e.n_stages > 0; ++k) {
            char label[48];
            snprintf(label, sizeof(label), "  stage %s", stage_name[k]);
            print_summary(label, &res.stage[k]);
        }
        if (res.transport.n > 0) {
            print_summary("LCM overhead less queued", &res.transport);
        }
        fprintf(stderr, "  end to end: %lld of %lld poses came back\n", e2e.returned, e2e.expected);
        if (e2e.unpaired > 0) {
            fprintf(stderr, "  end to end: %lld frame(s) answered without a step in vislamd's samples: no overhead\n",
                    e2e.unpaired);
        }
    }
    if (res.jitter_samples > 0) {
        fprintf(stderr, "  jitter floor (1 kHz probe, %d CPUs, %" PRIu64 " wake-ups): p99 %.0f  max %.0f us\n",
                jit.count, res.jitter_samples, res.jitter_p99, res.jitter_max);
    }
    if (res.cyclictest_max >= 0) {
        fprintf(stderr, "  cyclictest in the same run: max %ld us\n", res.cyclictest_max);
    }
    fprintf(stderr, "  budget %ld us: %" PRIu64 " step(s) over it in-process, %" PRIu64 " end to end\n", res.budget_us,
            res.overruns, res.e2e_overruns);
    fprintf(stderr, "  work per step (core's count): p50 %.3g  max %.3g flops (max/p50 %.2f)\n", res.work_p50,
            res.work_max, res.work_p50 > 0 ? res.work_max / res.work_p50 : 0.0);
    fprintf(
        stderr,
        "  work per IMU step: p50 %.3g  max %.3g flops; per frame with the IMU steps before it: p50 %.3g  max %.3g\n",
        res.prop_work.p50, res.prop_work.max, res.frame_work.p50, res.frame_work.max);
    if (res.deferred_work.n > 0) {
        fprintf(stderr, "  work after the pose (%zu frames): p50 %.3g  max %.3g flops\n", res.deferred_work.n,
                res.deferred_work.p50, res.deferred_work.max);
    }
    const step_t *c = res.costliest;
    fprintf(stderr,
            "  costliest step: pass %d frame %u, %.1f us = %.2fx the median; its work %.3g flops = %.2fx the median "
            "(n %u, m %u)\n",
            c->pass + 1, (unsigned)c->frame, (double)c->ns * 1e-3,
            res.step.p50 > 0 ? (double)c->ns * 1e-3 / res.step.p50 : 0.0, (double)c->work.flops,
            res.work_p50 > 0 ? (double)c->work.flops / res.work_p50 : 0.0, (unsigned)c->work.state_dim,
            (unsigned)c->work.rows);
    if (res.callgrind > 0) {
        fprintf(stderr, "  callgrind: %.4g instructions per vl_update (mean)\n", res.callgrind);
    }

    int rc = 0;
    if (opt.json_path != NULL || opt.plot_path != NULL) {
        char json[PATH_LEN];
        snprintf(json, sizeof(json), "%s", opt.json_path != NULL ? opt.json_path : "");
        if (opt.json_path == NULL) {
            path_join(json, sizeof(json), dir, "latency.json");
        }
        if (write_json(json, &lg, &res, step_us, &e2e, &jit, &jmerged, nsteps) != 0) {
            rc = EXIT_INCOMPLETE;
        } else if (opt.plot_path != NULL && run_plot(json, opt.plot_path) != 0) {
            rc = EXIT_INCOMPLETE;
        }
    }
    if (opt.e2e && (e2e.failed || e2e.returned < e2e.expected || e2e.expected == 0)) {
        rc = EXIT_INCOMPLETE;
    }
    const int helper_failed = (opt.e2e && e2e.failed) || (opt.callgrind && res.callgrind <= 0);
    if (made_dir && helper_failed) {
        fprintf(stderr, "vislam-latency: the helpers' logs are kept in %s\n", dir);
    } else if (made_dir) {
        remove_work_dir(dir);
    }
    free(steps);
    free(prop_us);
    free(prop_work);
    free(step_us);
    free(work);
    free(e2e.us);
    free(e2e.utime);
    free(e2e.overhead_us);
    for (int k = 0; k < 3; ++k) {
        free(e2e.stamp[k]);
    }
    for (int k = 0; k < STAGE_COUNT; ++k) {
        free(e2e.stage_us[k]);
    }
    free(lg.events);
    return rc;
}
