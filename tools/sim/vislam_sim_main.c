/**
 * @file vislam_sim_main.c
 * @brief vislam-sim: writes a synthetic scenario as an LCM event log plus its truth.
 *
 * The log has the layout of a converted dataset: VISLAM_CALIB first, then per
 * step VISLAM_IMU and VISLAM_FEATURES, each event stamped with its message's
 * utime. The truth is a TUM trajectory of the IMU frame in the world.
 */
#include <errno.h>
#include <lcm/eventlog.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vl_channels.h"
#include "vl_cli.h"
#include "vl_msg.h"
#include "vl_sim.h"
#include "vl_trajectory_file.h"

/* Static: the simulator and a frame are too large to be polite on the stack. */
static vl_sim_t g_sim;
static vl_stereo_frame_t g_frame;
static vislam_stereo_frame_t g_msg_frame;
static unsigned char g_buf[16384];

static void usage(FILE *f)
{
    fprintf(f, "usage: vislam-sim --out LOG.lcmlog --truth TRUTH.tum [options]\n"
               "Writes a deterministic synthetic visual-inertial scenario as an LCM log\n"
               "(VISLAM_CALIB, then VISLAM_IMU + VISLAM_FEATURES per step) and its true\n"
               "IMU trajectory in TUM format (time tx ty tz qx qy qz qw).\n"
               "options (defaults in brackets):\n"
               "  --truth-map MAP.ply     also write the true position of every track id\n"
               "  --steps N               steps at 10 Hz [300]\n"
               "  --seed S                world seed: path, points, tracks [1]\n"
               "  --noise-seed S          measurement noise seed [0]\n"
               "  --pixel-noise PX        pixel std on each coordinate [1.0]\n"
               "  --linear-noise MPS      linear velocity std [0.5]\n"
               "  --angular-noise RPS     angular velocity std [0.05]\n"
               "  --linear-offset X,Y,Z   constant linear velocity offset, m/s [0,0,0]\n"
               "  --angular-offset X,Y,Z  constant angular velocity offset, rad/s [0.005,0.005,0.005]\n"
               "  --velocity-sensor X,Y,Z the linear velocity sensor's position in the IMU frame, m:\n"
               "                          its samples are the velocity there, v + w x p [0,0,0]\n"
               "  --interval-velocities   the velocity is constant from one step to the next (each\n"
               "                          sample holds); default: it varies smoothly and each sample\n"
               "                          is the instantaneous velocity at its step\n"
               "  --speed MPS             mean forward speed [8]\n"
               "  --points-per-meter N    world point density along the path [2.5]\n"
               "  --max-observations N    observations per frame, 1..256 [256]\n"
               "  --start-utime US        time of step 0, microseconds [1317384000000000]\n"
               "realistic conditions (all off by default; see tools/sim/vl_sim.h):\n"
               "  --realistic             every condition below at the rate measured on the seed\n"
               "                          drives, with --max-observations 95 --points-per-meter 4\n"
               "                          --pixel-noise 0.3; explicit options override it\n"
               "  --stale-probability P   per frame: repeat the last frame's tracks exactly, which\n"
               "                          then lose one step of motion [0]\n"
               "  --detect-below F        start tracks only after a frame with fewer than\n"
               "                          F x max-observations observations; such frames are stale [0]\n"
               "  --detect-new F          at most F x max-observations new tracks per frame [0: no limit]\n"
               "  --reassoc-probability P per frame: hand continued ids to other points [0]\n"
               "  --reassoc-fraction F    share of the continued tracks handed over in such a frame [0]\n"
               "  --reassoc-radius PX     farthest jump of a handed-over id [0]\n"
               "  --moving-fraction F     share of points moving at a constant world velocity [0]\n"
               "  --moving-speed MPS      speed of the moving points [0]\n"
               "  --mismatch-probability P  per observation: pixels of a random location [0]\n"
               "  --far-fraction F        share of points placed far ahead [0]\n"
               "  --far-disparity MIN,MAX disparity range of far points, px [0,0]\n"
               "  --calib-rotation-error X,Y,Z  deg, camera-frame rotation of the cam_T_imu the\n"
               "                          observations use (the log carries the nominal one) [0,0,0]\n"
               "  --calib-translation-error X,Y,Z  m, added to that cam_T_imu's translation [0,0,0]\n"
               "  --baseline-error REL    relative error of the baseline the observations use [0]\n"
               "  --stale-jump PX[,DISP]  std of each carried track's jump across a stale frame in u and\n"
               "                          v (and in disparity) [0,0]\n"
               "  --quiet                 no summary on stderr\n"
               "  --version               print the version and exit\n"
               "  --help                  this text\n");
}

/* Whether a takes a value: the options of the chain in main, checked before the value is taken,
   so that an unknown option is named as such and not as one missing its value. */
static int takes_value(const char *a)
{
    static const char *const names[] = {"--out",
                                        "--truth",
                                        "--truth-map",
                                        "--steps",
                                        "--seed",
                                        "--noise-seed",
                                        "--pixel-noise",
                                        "--linear-noise",
                                        "--angular-noise",
                                        "--linear-offset",
                                        "--angular-offset",
                                        "--velocity-sensor",
                                        "--speed",
                                        "--points-per-meter",
                                        "--max-observations",
                                        "--stale-probability",
                                        "--detect-below",
                                        "--detect-new",
                                        "--reassoc-probability",
                                        "--reassoc-fraction",
                                        "--reassoc-radius",
                                        "--moving-fraction",
                                        "--moving-speed",
                                        "--mismatch-probability",
                                        "--far-fraction",
                                        "--far-disparity",
                                        "--calib-rotation-error",
                                        "--calib-translation-error",
                                        "--baseline-error",
                                        "--stale-jump",
                                        "--start-utime"};
    for (size_t k = 0; k < sizeof(names) / sizeof(names[0]); ++k) {
        if (strcmp(a, names[k]) == 0) {
            return 1;
        }
    }
    return 0;
}

static int parse_double(const char *s, double *out)
{
    char *end = NULL;
    double v;
    errno = 0;
    v = strtod(s, &end);
    if (errno != 0 || end == s || *end != '\0' || !isfinite(v)) {
        return -1;
    }
    *out = v;
    return 0;
}

static int parse_u64(const char *s, unsigned long long *out)
{
    char *end = NULL;
    unsigned long long v;
    if (*s == '-') {
        return -1;
    }
    errno = 0;
    v = strtoull(s, &end, 0);
    if (errno != 0 || end == s || *end != '\0') {
        return -1;
    }
    *out = v;
    return 0;
}

/** "min,max" */
static int parse_pair(const char *s, double *lo, double *hi)
{
    char tmp[256];
    char *a;
    if (strlen(s) >= sizeof(tmp)) {
        return -1;
    }
    strcpy(tmp, s);
    a = strchr(tmp, ',');
    if (a == NULL) {
        return -1;
    }
    *a++ = '\0';
    return (parse_double(tmp, lo) == 0 && parse_double(a, hi) == 0) ? 0 : -1;
}

/** "x,y,z" or a single value for all three axes. */
static int parse_vec3(const char *s, double v[3])
{
    char tmp[256];
    char *a, *b;
    if (strlen(s) >= sizeof(tmp)) {
        return -1;
    }
    strcpy(tmp, s);
    a = strchr(tmp, ',');
    if (a == NULL) {
        if (parse_double(tmp, &v[0]) != 0) {
            return -1;
        }
        v[1] = v[2] = v[0];
        return 0;
    }
    *a++ = '\0';
    b = strchr(a, ',');
    if (b == NULL) {
        return -1;
    }
    *b++ = '\0';
    return (parse_double(tmp, &v[0]) == 0 && parse_double(a, &v[1]) == 0 && parse_double(b, &v[2]) == 0) ? 0 : -1;
}

static int write_event(lcm_eventlog_t *log, const char *channel, int64_t utime, int len)
{
    lcm_eventlog_event_t ev;
    memset(&ev, 0, sizeof(ev));
    ev.timestamp = utime;
    ev.channellen = (int32_t)strlen(channel);
    ev.channel = (char *)channel;
    ev.datalen = len;
    ev.data = g_buf;
    return lcm_eventlog_write_event(log, &ev);
}

int main(int argc, char **argv)
{
    vl_sim_config_t cfg;
    const char *out_path = NULL, *truth_path = NULL, *map_path = NULL;
    int quiet = 0, i, rc = 0;
    lcm_eventlog_t *log = NULL;
    FILE *truth = NULL;
    vislam_calibration_t calib_msg;
    uint64_t steps = 0, observations = 0;
    double R[9], p[3];

    vl_sim_config_default(&cfg);
    /* The preset first, wherever it stands, so that every explicit option overrides it. */
    for (i = 1; i < argc; ++i) {
        if (strcmp(argv[i], "--realistic") == 0) {
            vl_sim_config_realistic(&cfg);
        }
    }
    for (i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = (i + 1 < argc) ? argv[i + 1] : NULL;
        unsigned long long u = 0;
        int bad = 0;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return 0;
        } else if (strcmp(a, "--version") == 0) {
            return vl_cli_print_version(stdout, "vislam-sim") == 0 ? 0 : 1;
        } else if (strcmp(a, "--quiet") == 0) {
            quiet = 1;
            continue;
        } else if (strcmp(a, "--realistic") == 0) {
            continue;
        } else if (strcmp(a, "--interval-velocities") == 0) {
            cfg.interval_velocities = 1;
            continue;
        }
        if (!takes_value(a)) {
            fprintf(stderr, "vislam-sim: unknown option %s (see --help)\n", a);
            return 2;
        }
        if (v == NULL) {
            fprintf(stderr, "vislam-sim: %s needs a value\n", a);
            return 2;
        }
        ++i;
        if (strcmp(a, "--out") == 0) {
            out_path = v;
        } else if (strcmp(a, "--truth") == 0) {
            truth_path = v;
        } else if (strcmp(a, "--truth-map") == 0) {
            map_path = v;
        } else if (strcmp(a, "--steps") == 0) {
            bad = parse_u64(v, &u) != 0 || u == 0 || u > 100000000ULL;
            cfg.num_steps = (uint32_t)u;
        } else if (strcmp(a, "--seed") == 0) {
            bad = parse_u64(v, &u) != 0;
            cfg.seed = u;
        } else if (strcmp(a, "--noise-seed") == 0) {
            bad = parse_u64(v, &u) != 0;
            cfg.noise_seed = u;
        } else if (strcmp(a, "--pixel-noise") == 0) {
            bad = parse_double(v, &cfg.pixel_noise) != 0;
        } else if (strcmp(a, "--linear-noise") == 0) {
            bad = parse_double(v, &cfg.linear_noise) != 0;
        } else if (strcmp(a, "--angular-noise") == 0) {
            bad = parse_double(v, &cfg.angular_noise) != 0;
        } else if (strcmp(a, "--linear-offset") == 0) {
            bad = parse_vec3(v, cfg.linear_offset) != 0;
        } else if (strcmp(a, "--angular-offset") == 0) {
            bad = parse_vec3(v, cfg.angular_offset) != 0;
        } else if (strcmp(a, "--velocity-sensor") == 0) {
            bad = parse_vec3(v, cfg.velocity_sensor) != 0;
        } else if (strcmp(a, "--speed") == 0) {
            bad = parse_double(v, &cfg.speed) != 0;
        } else if (strcmp(a, "--points-per-meter") == 0) {
            bad = parse_double(v, &cfg.points_per_meter) != 0;
        } else if (strcmp(a, "--max-observations") == 0) {
            bad = parse_u64(v, &u) != 0 || u > VL_MAX_FRAME_FEATURES;
            cfg.max_observations = (uint32_t)u;
        } else if (strcmp(a, "--stale-probability") == 0) {
            bad = parse_double(v, &cfg.stale_probability) != 0;
        } else if (strcmp(a, "--detect-below") == 0) {
            bad = parse_double(v, &cfg.detect_below_fraction) != 0;
        } else if (strcmp(a, "--detect-new") == 0) {
            bad = parse_double(v, &cfg.detect_new_fraction) != 0;
        } else if (strcmp(a, "--reassoc-probability") == 0) {
            bad = parse_double(v, &cfg.reassoc_probability) != 0;
        } else if (strcmp(a, "--reassoc-fraction") == 0) {
            bad = parse_double(v, &cfg.reassoc_fraction) != 0;
        } else if (strcmp(a, "--reassoc-radius") == 0) {
            bad = parse_double(v, &cfg.reassoc_radius) != 0;
        } else if (strcmp(a, "--moving-fraction") == 0) {
            bad = parse_double(v, &cfg.moving_fraction) != 0;
        } else if (strcmp(a, "--moving-speed") == 0) {
            bad = parse_double(v, &cfg.moving_speed) != 0;
        } else if (strcmp(a, "--mismatch-probability") == 0) {
            bad = parse_double(v, &cfg.mismatch_probability) != 0;
        } else if (strcmp(a, "--far-fraction") == 0) {
            bad = parse_double(v, &cfg.far_fraction) != 0;
        } else if (strcmp(a, "--far-disparity") == 0) {
            bad = parse_pair(v, &cfg.far_disparity_min, &cfg.far_disparity_max) != 0;
        } else if (strcmp(a, "--calib-rotation-error") == 0) {
            bad = parse_vec3(v, cfg.calib_rotation_error) != 0;
        } else if (strcmp(a, "--calib-translation-error") == 0) {
            bad = parse_vec3(v, cfg.calib_translation_error) != 0;
        } else if (strcmp(a, "--baseline-error") == 0) {
            bad = parse_double(v, &cfg.baseline_error) != 0;
        } else if (strcmp(a, "--stale-jump") == 0) {
            if (strchr(v, ',') != NULL) {
                bad = parse_pair(v, &cfg.stale_jump, &cfg.stale_jump_disparity) != 0;
            } else {
                bad = parse_double(v, &cfg.stale_jump) != 0;
                cfg.stale_jump_disparity = 0.0;
            }
        } else if (strcmp(a, "--start-utime") == 0) {
            bad = parse_u64(v, &u) != 0 || u > (unsigned long long)INT64_MAX / 2;
            cfg.start_utime = (int64_t)u;
        } else {
            fprintf(stderr, "vislam-sim: unknown option %s\n", a);
            usage(stderr);
            return 2;
        }
        if (bad) {
            fprintf(stderr, "vislam-sim: bad value for %s: '%s'\n", a, v);
            return 2;
        }
    }
    if (out_path == NULL || truth_path == NULL) {
        fprintf(stderr, "vislam-sim: --out and --truth are required\n");
        usage(stderr);
        return 2;
    }
    if (vl_sim_init(&g_sim, &cfg) != 0) {
        fprintf(stderr, "vislam-sim: configuration out of range (check noise >= 0, max-observations >= 1,\n"
                        "probabilities and fractions in [0, 1], far disparities 0 < MIN <= MAX)\n");
        return 2;
    }

    log = lcm_eventlog_create(out_path, "w");
    if (log == NULL) {
        fprintf(stderr, "vislam-sim: cannot create %s: %s\n", out_path, strerror(errno));
        return 1;
    }
    truth = fopen(truth_path, "w");
    if (truth == NULL) {
        fprintf(stderr, "vislam-sim: cannot create %s: %s\n", truth_path, strerror(errno));
        lcm_eventlog_destroy(log);
        return 1;
    }

    vl_msg_from_calibration(&cfg.calibration, cfg.start_utime, &calib_msg);
    {
        const int len = vislam_calibration_t_encode(g_buf, 0, (int)sizeof(g_buf), &calib_msg);
        if (len < 0 || write_event(log, VL_CHANNEL_CALIBRATION, calib_msg.utime, len) != 0) {
            fprintf(stderr, "vislam-sim: writing %s failed\n", out_path);
            rc = 1;
        }
    }

    while (rc == 0) {
        vl_imu_sample_t imu;
        vislam_imu_t imu_msg;
        char line[VL_TRAJECTORY_LINE_MAX];
        int len;
        if (vl_sim_step(&g_sim, &imu, &g_frame, R, p) != 0) {
            break;
        }
        vl_msg_from_imu(&imu, &imu_msg);
        len = vislam_imu_t_encode(g_buf, 0, (int)sizeof(g_buf), &imu_msg);
        if (len < 0 || write_event(log, VL_CHANNEL_IMU, imu_msg.utime, len) != 0) {
            rc = 1;
            break;
        }

        vl_msg_from_stereo_frame(&g_frame, &g_msg_frame); /* zeroes the unused slots */
        len = vislam_stereo_frame_t_encode(g_buf, 0, (int)sizeof(g_buf), &g_msg_frame);
        if (len < 0 || write_event(log, VL_CHANNEL_FEATURES, g_msg_frame.utime, len) != 0) {
            rc = 1;
            break;
        }

        /* the truth in exactly the lines vislam-run writes */
        vl_pose_t truth_pose;
        memset(&truth_pose, 0, sizeof(truth_pose));
        memcpy(truth_pose.rotation, R, sizeof(truth_pose.rotation));
        memcpy(truth_pose.position, p, sizeof(truth_pose.position));
        if (vl_trajectory_format_line(line, sizeof(line), imu.utime, &truth_pose) < 0 || fputs(line, truth) < 0) {
            rc = 1;
            break;
        }
        ++steps;
        observations += g_frame.count;
    }
    if (rc != 0) {
        fprintf(stderr, "vislam-sim: writing %s failed\n", out_path);
    }
    lcm_eventlog_destroy(log);
    if (fclose(truth) != 0) {
        fprintf(stderr, "vislam-sim: writing %s failed\n", truth_path);
        rc = 1;
    }

    if (rc == 0 && map_path != NULL) {
        FILE *m = fopen(map_path, "w");
        const int32_t n = vl_sim_tracks_issued(&g_sim);
        const int32_t first = n > VL_SIM_MAX_TRACKS ? n - VL_SIM_MAX_TRACKS : 0;
        int32_t id;
        if (m == NULL) {
            fprintf(stderr, "vislam-sim: cannot create %s: %s\n", map_path, strerror(errno));
            return 1;
        }
        fprintf(m,
                "ply\nformat ascii 1.0\ncomment vislam-sim true landmark per track id\n"
                "element vertex %ld\nproperty double x\nproperty double y\nproperty double z\n"
                "property int id\nend_header\n",
                (long)(n - first));
        for (id = first; id < n; ++id) {
            double x[3];
            if (vl_sim_landmark(&g_sim, id, x) == 0) {
                char c[3][VL_CLI_DOUBLE_MAX];
                for (int k = 0; k < 3; ++k) {
                    vl_cli_format_double(c[k], sizeof(c[k]), x[k]);
                }
                fprintf(m, "%s %s %s %ld\n", c[0], c[1], c[2], (long)id);
            }
        }
        if (fclose(m) != 0) {
            fprintf(stderr, "vislam-sim: writing %s failed\n", map_path);
            rc = 1;
        }
    }

    if (rc == 0 && !quiet) {
        vl_sim_counts_t counts;
        fprintf(stderr, "vislam-sim: %llu steps, %.1f observations/frame, %ld track ids, %.1f m driven\n",
                (unsigned long long)steps, steps ? (double)observations / (double)steps : 0.0,
                (long)vl_sim_tracks_issued(&g_sim), vl_sim_distance(&g_sim));
        vl_sim_counts(&g_sim, &counts);
        if (counts.stale_frames + counts.reassociations + counts.mismatches > 0) {
            fprintf(stderr, "vislam-sim: %llu stale frames, %llu ids re-associated, %llu mismatched observations\n",
                    (unsigned long long)counts.stale_frames, (unsigned long long)counts.reassociations,
                    (unsigned long long)counts.mismatches);
        }
    }
    return rc;
}
