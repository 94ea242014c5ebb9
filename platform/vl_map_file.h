/**
 * @file vl_map_file.h
 * @brief The map as an ASCII PLY file: what vislam-run --map writes, and what a recording of
 *        vislamd's VISLAM_LANDMARKS converts to (tests/support/vl_log_inspect), line for line.
 *
 * A map point keeps what the file holds (floats for the position and the spread), so a long
 * run's map costs 32 bytes a landmark in memory until it is written.
 */
#ifndef VISLAM_PLATFORM_VL_MAP_FILE_H
#define VISLAM_PLATFORM_VL_MAP_FILE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "vislam/vislam.h"

#ifdef __cplusplus
extern "C" {
#endif

/** One vertex of the map file. */
typedef struct {
    int32_t id;            /**< track id */
    float position[3];     /**< world frame, m */
    float sigma;           /**< sqrt(trace(covariance)), m */
    uint32_t observations; /**< frames that observed it */
    int64_t first_utime;   /**< its first observation, us */
} vl_map_point_t;

/** The vertex of a landmark leaving the window. */
void vl_map_point_from_landmark(const vl_landmark_t *landmark, vl_map_point_t *out);

/**
 * Writes the PLY header and one line per point ("x y z id sigma observations first_time").
 * @return 0, or -1 on a write error
 */
int vl_map_write_ply(FILE *f, const vl_map_point_t *points, size_t count);

#ifdef __cplusplus
}
#endif

#endif /* VISLAM_PLATFORM_VL_MAP_FILE_H */
