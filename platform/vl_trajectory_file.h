/**
 * @file vl_trajectory_file.h
 * @brief TUM trajectory writer shared by vislam-run and vislamd.
 *
 * One line per pose: "time tx ty tz qx qy qz qw", time in seconds printed
 * exactly from the microsecond stamp (6 decimals, no floating point), the
 * position and the world-from-IMU quaternion (w >= 0) with 9 decimals. Both
 * programs write through this file, so their lines are identical by
 * construction. Each line is flushed to the kernel as it is written: a crash
 * loses at most the line being written. The stdio buffer lives inside the
 * writer, so writing does not allocate after vl_trajectory_open.
 */
#ifndef VISLAM_PLATFORM_VL_TRAJECTORY_FILE_H
#define VISLAM_PLATFORM_VL_TRAJECTORY_FILE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Longest line the writer produces, terminator included: 7 numbers of up to 320 characters
    (%.9f of +-DBL_MAX) and the time. */
#define VL_TRAJECTORY_LINE_MAX 2560

/** Writer state; members are private. */
typedef struct {
    FILE *f;
    uint64_t lines;    /**< lines written */
    int error;         /**< a write or flush failed */
    char buffer[4096]; /**< stdio buffer (setvbuf) */
} vl_trajectory_file_t;

/** Room for vl_trajectory_format_time's text, with its terminator. */
#define VL_TRAJECTORY_TIME_MAX 24

/**
 * A time in seconds, printed exactly from the integer microseconds ("-" when negative, 6
 * decimals), as every output that pairs with a TUM file by time prints it.
 * @return its length, or -1 if @p len is too small
 */
int vl_trajectory_format_time(char *buf, size_t len, int64_t utime);

/**
 * Formats one TUM line (with its newline) into @p buf.
 * @return the line's length, or -1 if @p len is too small
 */
int vl_trajectory_format_line(char *buf, size_t len, int64_t utime, const vl_pose_t *pose);

/**
 * Creates (truncates) @p path.
 * @return 0, or -1 with a message in @p err
 */
int vl_trajectory_open(vl_trajectory_file_t *t, const char *path, char *err, size_t err_len);

/**
 * Opens @p path for appending, creating it if needed: a restarted daemon never truncates the
 * trajectory of an earlier run. When the file already has content, a line cut by a crash is
 * ended first, then one comment line ("# " + @p note + "\n") marks where this run starts; TUM
 * readers (evo, tools/evaluate) skip '#' lines. A new or empty file gets no comment, so a single
 * run's file is exactly what vl_trajectory_open would write.
 * @param note what the comment says (e.g. the program and its pid); NULL for a generic one
 * @param appended set to 1 if the file had content (may be NULL)
 * @return 0, or -1 with a message in @p err
 */
int vl_trajectory_open_append(vl_trajectory_file_t *t, const char *path, const char *note, int *appended, char *err,
                              size_t err_len);

/** Appends one line and flushes it. 0, or -1 on a write error (also remembered for close). */
int vl_trajectory_write(vl_trajectory_file_t *t, int64_t utime, const vl_pose_t *pose);

/** Lines written so far. */
uint64_t vl_trajectory_lines(const vl_trajectory_file_t *t);

/** Closes the file. 0, or -1 if any write, flush or the close failed. Safe to call twice. */
int vl_trajectory_close(vl_trajectory_file_t *t);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_TRAJECTORY_FILE_H */
