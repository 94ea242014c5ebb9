/*
 * vl_log_inspect LOG [--after UTIME] [--map-out MAP.ply]: summarizes what vislamd published, from
 * a log recorded with lcm-logger, as "key value" lines for tests/test_daemon.sh:
 *
 *   channel.NAME N                 events per channel
 *   pose.count / pose.imu / pose.features / pose.decode_errors
 *   pose.sequence_ok 1|0           sequences are 0, 1, 2, ... in order
 *   pose.last_features_utime U     utime of the last FEATURES pose
 *   bot.count / bot.decode_errors / bot.matches_pose 1|0 (same utime and position as VISLAM_POSE, in order)
 *   status.count / status.decode_errors / status.utime_increasing 1|0
 *   status.first.FIELD V / status.last.FIELD V   every field of the first and last vislam.status_t
 *   status.health_any V            the OR of every status' health bits
 *   pose.non_finite N               poses with a NaN or infinite position, orientation or covariance
 *   pose.features_after N           with --after: distinct utimes > UTIME of finite FEATURES poses
 *   map.batches / map.landmarks / map.decode_errors   VISLAM_LANDMARKS messages and their entries
 *   map.sequence_ok 1|0            batch sequences are 0, 1, 2, ... and each first_index counts the
 *                                  landmarks of the batches before it
 *   map.well_formed 1|0            every batch holds 1..MAX_LANDMARKS entries and zeros past them
 *   map.world_last W / map.worlds_ordered 1|0   the last batch's world; worlds never go back
 *   log.damaged N / log.truncated 0|1   damaged spots in the recorded log itself (vl_log_guard)
 * With --map-out, the landmarks in the order received as the PLY vislam-run --map writes.
 */
#include <inttypes.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>

#include <lcm/lcm.h>

#include "vl_channels.h"
#include "vl_log_guard.h"
#include "vl_map_file.h"
#include "vl_msg.h"

#include "bot_core_pose_t.h"
#include "vislam_landmarks_t.h"
#include "vislam_pose_t.h"
#include "vislam_status_t.h"

#define MAX_CH 32
#define MAX_POSES 100000

typedef struct {
    char name[64];
    uint64_t n;
} ch_t;

static ch_t channels[MAX_CH];
static int num_channels;
/* Pose utimes and positions, to compare the bot_core stream against. */
static int64_t pose_utime[MAX_POSES];
static double pose_x[MAX_POSES];

static void count_channel(const char *name)
{
    for (int i = 0; i < num_channels; ++i) {
        if (strcmp(channels[i].name, name) == 0) {
            channels[i].n++;
            return;
        }
    }
    if (num_channels < MAX_CH) {
        snprintf(channels[num_channels].name, sizeof(channels[num_channels].name), "%s", name);
        channels[num_channels++].n = 1;
    }
}

static void print_status(const char *which, const vislam_status_t *s)
{
#define F64(f) printf("status.%s.%s %" PRId64 "\n", which, #f, (int64_t)s->f)
    F64(utime);
    F64(last_input_utime);
    F64(health);
    F64(imu_in);
    F64(frames_in);
    F64(poses_out);
    F64(inputs_rejected);
    F64(observations_gated);
    F64(window_landmarks);
    F64(window_capacity);
    F64(landmarks_mapped);
    F64(budget_us);
    F64(budget_overruns);
    F64(steps);
    F64(latency_p50_us);
    F64(latency_p99_us);
    F64(latency_p999_us);
    F64(latency_max_us);
    F64(frames_repeated);
    F64(time_jumps);
    F64(timeline_changes);
    F64(divergence_resets);
    F64(resets);
    F64(imu_implausible);
    F64(observations_implausible);
    F64(frames_imu_silent);
#undef F64
#define FDBL(f) printf("status.%s.%s %.9g\n", which, #f, s->f)
    FDBL(linear_velocity_noise);
    FDBL(angular_velocity_noise);
    FDBL(pixel_noise);
    FDBL(innovation_ratio);
#undef FDBL
}

/* 1 when every entry past m->count is zero, as the message type promises. */
static int batch_tail_zero(const vislam_landmarks_t *m)
{
    for (int32_t i = m->count; i < VISLAM_LANDMARKS_T_MAX_LANDMARKS; ++i) {
        if (m->id[i] != 0 || m->observations[i] != 0 || m->first_utime[i] != 0 || m->last_utime[i] != 0) {
            return 0;
        }
        for (int k = 0; k < 6; ++k) {
            if ((k < 3 && m->position[i][k] != 0.0) || m->covariance[i][k] != 0.0) {
                return 0;
            }
        }
    }
    return 1;
}

static int pose_finite(const vislam_pose_t *p)
{
    double sum = 0.0;
    for (int i = 0; i < 3; ++i) {
        sum += p->position[i];
    }
    for (int i = 0; i < 4; ++i) {
        sum += p->orientation[i];
    }
    for (int i = 0; i < 36; ++i) {
        sum += p->covariance[i];
    }
    return isfinite(sum);
}

int main(int argc, char **argv)
{
    int have_after = 0;
    int64_t after = 0;
    const char *map_out = NULL;
    int bad_args = argc < 2 || argc % 2 != 0;
    for (int i = 2; i + 1 < argc && !bad_args; i += 2) {
        if (strcmp(argv[i], "--after") == 0) {
            have_after = 1;
            after = strtoll(argv[i + 1], NULL, 10);
        } else if (strcmp(argv[i], "--map-out") == 0) {
            map_out = argv[i + 1];
        } else {
            bad_args = 1;
        }
    }
    if (bad_args) {
        fprintf(stderr, "usage: vl_log_inspect LOG [--after UTIME] [--map-out MAP.ply]\n");
        return 2;
    }
    lcm_eventlog_t *log = lcm_eventlog_create(argv[1], "r");
    if (log == NULL) {
        fprintf(stderr, "vl_log_inspect: cannot read %s\n", argv[1]);
        return 2;
    }
    static vislam_pose_t pose;
    static bot_core_pose_t bot;
    static vislam_status_t status, first_status, last_status;
    static vislam_landmarks_t batch;
    uint64_t batches = 0, landmarks = 0, map_err = 0;
    int map_sequence_ok = 1, map_well_formed = 1, worlds_ordered = 1;
    int64_t world_last = 0;
    vl_map_point_t *points = NULL;
    size_t capacity = 0;
    uint64_t poses = 0, imu = 0, features = 0, pose_err = 0, bots = 0, bot_err = 0, statuses = 0, status_err = 0;
    int sequence_ok = 1, bot_match = 1, status_increasing = 1;
    int32_t health_any = 0;
    int64_t last_features_utime = 0;
    uint64_t non_finite = 0, features_after = 0;
    int64_t last_after_utime = INT64_MIN;
    vl_log_guard_t guard;
    if (vl_log_guard_init(&guard, log->f) != 0) {
        fprintf(stderr, "vl_log_inspect: cannot seek in %s\n", argv[1]);
        return 2;
    }
    lcm_eventlog_event_t *ev;
    for (;;) {
        const vl_log_guard_result_t g = vl_log_guard_next(&guard, log->f);
        if (g == VL_LOG_GUARD_DAMAGED) {
            fprintf(stderr, "vl_log_inspect: %s: %s\n", argv[1], guard.error);
            continue;
        }
        if (g == VL_LOG_GUARD_END || (ev = lcm_eventlog_read_next_event(log)) == NULL) {
            break;
        }
        count_channel(ev->channel);
        if (strcmp(ev->channel, VL_CHANNEL_POSE) == 0) {
            if (!vl_msg_decoded_whole(vislam_pose_t_decode(ev->data, 0, ev->datalen, &pose), ev->datalen)) {
                pose_err++;
            } else {
                if (pose.sequence != (int64_t)poses) {
                    sequence_ok = 0;
                }
                if (poses < MAX_POSES) {
                    pose_utime[poses] = pose.utime;
                    pose_x[poses] = pose.position[0];
                }
                poses++;
                if (pose.source == VISLAM_POSE_T_SOURCE_IMU) {
                    imu++;
                } else if (pose.source == VISLAM_POSE_T_SOURCE_FEATURES) {
                    features++;
                    last_features_utime = pose.utime;
                }
                const int finite = pose_finite(&pose);
                non_finite += !finite;
                /* Distinct utimes: a frame answered twice (two daemons, a repeat) counts once. */
                if (have_after && finite && pose.source == VISLAM_POSE_T_SOURCE_FEATURES && pose.utime > after &&
                    pose.utime != last_after_utime) {
                    features_after++;
                    last_after_utime = pose.utime;
                }
            }
        } else if (strcmp(ev->channel, VL_CHANNEL_BOT_POSE) == 0) {
            if (!vl_msg_decoded_whole(bot_core_pose_t_decode(ev->data, 0, ev->datalen, &bot), ev->datalen)) {
                bot_err++;
            } else {
                if (bots >= poses || bots >= MAX_POSES || pose_utime[bots] != bot.utime || pose_x[bots] != bot.pos[0]) {
                    bot_match = 0;
                }
                bots++;
            }
        } else if (strcmp(ev->channel, VL_CHANNEL_LANDMARKS) == 0) {
            if (!vl_msg_decoded_whole(vislam_landmarks_t_decode(ev->data, 0, ev->datalen, &batch), ev->datalen)) {
                map_err++;
            } else {
                if (batch.sequence != (int64_t)batches || batch.first_index != (int64_t)landmarks) {
                    map_sequence_ok = 0;
                }
                if (batch.count < 1 || batch.count > VISLAM_LANDMARKS_T_MAX_LANDMARKS || !batch_tail_zero(&batch)) {
                    map_well_formed = 0;
                }
                if (batch.world < world_last) {
                    worlds_ordered = 0;
                }
                world_last = batch.world;
                vl_landmark_t lm;
                for (int32_t i = 0; vl_msg_to_landmark(&batch, i, &lm) == VL_MSG_OK; ++i) {
                    if (landmarks == capacity) {
                        capacity = capacity == 0 ? 1024 : 2 * capacity;
                        points = (vl_map_point_t *)realloc(points, capacity * sizeof(*points));
                        if (points == NULL) {
                            fprintf(stderr, "vl_log_inspect: out of memory\n");
                            return 2;
                        }
                    }
                    vl_map_point_from_landmark(&lm, &points[landmarks++]);
                }
                batches++;
            }
        } else if (strcmp(ev->channel, VL_CHANNEL_STATUS) == 0) {
            if (!vl_msg_decoded_whole(vislam_status_t_decode(ev->data, 0, ev->datalen, &status), ev->datalen)) {
                status_err++;
            } else {
                if (statuses == 0) {
                    first_status = status;
                } else if (status.utime <= last_status.utime) {
                    status_increasing = 0;
                }
                last_status = status;
                health_any |= status.health;
                statuses++;
            }
        }
        lcm_eventlog_free_event(ev);
    }
    lcm_eventlog_destroy(log);
    for (int i = 0; i < num_channels; ++i) {
        printf("channel.%s %" PRIu64 "\n", channels[i].name, channels[i].n);
    }
    printf("pose.count %" PRIu64 "\npose.imu %" PRIu64 "\npose.features %" PRIu64 "\npose.decode_errors %" PRIu64
           "\npose.sequence_ok %d\npose.last_features_utime %" PRId64 "\n",
           poses, imu, features, pose_err, sequence_ok, last_features_utime);
    printf("bot.count %" PRIu64 "\nbot.decode_errors %" PRIu64 "\nbot.matches_pose %d\n", bots, bot_err,
           bot_match && bots == poses);
    printf("status.count %" PRIu64 "\nstatus.decode_errors %" PRIu64 "\nstatus.utime_increasing %d\n", statuses,
           status_err, status_increasing);
    printf("status.health_any %d\n", (int)health_any);
    printf("pose.non_finite %" PRIu64 "\n", non_finite);
    if (have_after) {
        printf("pose.features_after %" PRIu64 "\n", features_after);
    }
    printf("map.batches %" PRIu64 "\nmap.landmarks %" PRIu64 "\nmap.decode_errors %" PRIu64
           "\nmap.sequence_ok %d\nmap.well_formed %d\nmap.world_last %" PRId64 "\nmap.worlds_ordered %d\n",
           batches, landmarks, map_err, map_sequence_ok, map_well_formed, world_last, worlds_ordered);
    printf("log.damaged %" PRIu64 "\nlog.truncated %d\n", guard.damaged, guard.truncated);
    if (map_out != NULL) {
        FILE *f = fopen(map_out, "w");
        if (f == NULL || vl_map_write_ply(f, points, landmarks) != 0 || fclose(f) != 0) {
            fprintf(stderr, "vl_log_inspect: cannot write %s\n", map_out);
            free(points);
            return 2;
        }
    }
    free(points);
    if (statuses > 0) {
        print_status("first", &first_status);
        print_status("last", &last_status);
    }
    return 0;
}
