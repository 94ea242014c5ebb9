#define _POSIX_C_SOURCE 200809L

#include "vl_trajectory_file.h"

#include <errno.h>
#include <string.h>

#include "vl_msg.h"

int vl_trajectory_format_time(char *buf, size_t len, int64_t utime)
{
    const char *sign = utime < 0 ? "-" : "";
    const uint64_t mag = utime < 0 ? (uint64_t)0 - (uint64_t)utime : (uint64_t)utime;
    const int n = snprintf(buf, len, "%s%llu.%06llu", sign, (unsigned long long)(mag / 1000000u),
                           (unsigned long long)(mag % 1000000u));
    return (n < 0 || (size_t)n >= len) ? -1 : n;
}

int vl_trajectory_format_line(char *buf, size_t len, int64_t utime, const vl_pose_t *pose)
{
    double q[4];
    /* The conversion the pose messages use, so every output prints the same quaternion. */
    vl_rotation_to_quaternion(pose->rotation, q);
    char t[VL_TRAJECTORY_TIME_MAX];
    vl_trajectory_format_time(t, sizeof(t), utime);
    const int n = snprintf(buf, len, "%s %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n", t, pose->position[0], pose->position[1],
                           pose->position[2], q[1], q[2], q[3], q[0]);
    if (n < 0 || (size_t)n >= len) {
        return -1;
    }
    return n;
}

int vl_trajectory_open(vl_trajectory_file_t *t, const char *path, char *err, size_t err_len)
{
    memset(t, 0, sizeof(*t));
    t->f = fopen(path, "w");
    if (t->f == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "cannot write trajectory %s: %s", path, strerror(errno));
        }
        return -1;
    }
    /* Our own buffer: stdio would otherwise malloc one at the first write. */
    setvbuf(t->f, t->buffer, _IOFBF, sizeof(t->buffer));
    return 0;
}

int vl_trajectory_open_append(vl_trajectory_file_t *t, const char *path, const char *note, int *appended, char *err,
                              size_t err_len)
{
    memset(t, 0, sizeof(*t));
    if (appended != NULL) {
        *appended = 0;
    }
    t->f = fopen(path, "a+");
    if (t->f == NULL) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "cannot append to trajectory %s: %s", path, strerror(errno));
        }
        return -1;
    }
    setvbuf(t->f, t->buffer, _IOFBF, sizeof(t->buffer));
    /* "a+" reads anywhere but always writes at the end. */
    int bad = fseek(t->f, 0, SEEK_END) != 0;
    const long size = bad ? -1 : ftell(t->f);
    if (size > 0) {
        int last = EOF;
        bad = fseek(t->f, -1, SEEK_END) != 0 || (last = fgetc(t->f)) == EOF || fseek(t->f, 0, SEEK_END) != 0;
        if (!bad && last != '\n') {
            bad = fputc('\n', t->f) == EOF;
        }
        if (!bad) {
            bad = fprintf(t->f, "# %s\n", note != NULL ? note : "a new run appends here") < 0 || fflush(t->f) != 0;
        }
        if (appended != NULL) {
            *appended = 1;
        }
    }
    if (bad || size < 0) {
        if (err != NULL && err_len > 0) {
            snprintf(err, err_len, "cannot append to trajectory %s: %s", path, strerror(errno));
        }
        fclose(t->f);
        t->f = NULL;
        return -1;
    }
    return 0;
}

int vl_trajectory_write(vl_trajectory_file_t *t, int64_t utime, const vl_pose_t *pose)
{
    char line[VL_TRAJECTORY_LINE_MAX];
    if (t->f == NULL) {
        t->error = 1;
        return -1;
    }
    const int n = vl_trajectory_format_line(line, sizeof(line), utime, pose);
    if (n < 0 || fwrite(line, 1, (size_t)n, t->f) != (size_t)n || fflush(t->f) != 0) {
        t->error = 1;
        return -1;
    }
    t->lines++;
    return 0;
}

uint64_t vl_trajectory_lines(const vl_trajectory_file_t *t)
{
    return t->lines;
}

int vl_trajectory_close(vl_trajectory_file_t *t)
{
    if (t->f == NULL) {
        return t->error ? -1 : 0;
    }
    const int bad = ferror(t->f);
    const int rc = fclose(t->f);
    t->f = NULL;
    if (bad || rc != 0) {
        t->error = 1;
    }
    return t->error ? -1 : 0;
}
