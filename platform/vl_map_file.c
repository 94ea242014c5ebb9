/* The map as an ASCII PLY file (vl_map_file.h). */
#include "vl_map_file.h"

#include <math.h>

#include "vl_trajectory_file.h"

void vl_map_point_from_landmark(const vl_landmark_t *landmark, vl_map_point_t *out)
{
    out->id = landmark->id;
    for (int i = 0; i < 3; ++i) {
        out->position[i] = (float)landmark->position[i];
    }
    const double trace = landmark->covariance[0] + landmark->covariance[4] + landmark->covariance[8];
    out->sigma = (float)sqrt(trace > 0.0 ? trace : 0.0);
    out->observations = landmark->observations;
    out->first_utime = landmark->first_utime;
}

int vl_map_write_ply(FILE *f, const vl_map_point_t *points, size_t count)
{
    fprintf(f,
            "ply\n"
            "format ascii 1.0\n"
            "comment vislam map: marginalized landmarks, world frame, m; sigma = sqrt(trace(cov))\n"
            "element vertex %zu\n"
            "property float x\n"
            "property float y\n"
            "property float z\n"
            "property int id\n"
            "property float sigma\n"
            "property uint observations\n"
            "property double first_time\n"
            "end_header\n",
            count);
    for (size_t i = 0; i < count; ++i) {
        const vl_map_point_t *p = &points[i];
        char t[VL_TRAJECTORY_TIME_MAX];
        vl_trajectory_format_time(t, sizeof(t), p->first_utime);
        fprintf(f, "%.9g %.9g %.9g %d %.9g %u %s\n", (double)p->position[0], (double)p->position[1],
                (double)p->position[2], (int)p->id, (double)p->sigma, (unsigned)p->observations, t);
    }
    return ferror(f) ? -1 : 0;
}
