/*
 * A program using the installed LCM message types: encodes a pose message with
 * the generated C code and decodes it again (no LCM network needed).
 */
#include <stdio.h>
#include <string.h>

#include "vislam_pose_t.h"

int main(void)
{
    vislam_pose_t pose, back;
    memset(&pose, 0, sizeof(pose));
    pose.utime = 123456789;
    pose.position[0] = 1.5;
    pose.orientation[0] = 1.0;
    unsigned char buf[4096];
    const int size = vislam_pose_t_encoded_size(&pose);
    if (size <= 0 || size > (int)sizeof(buf) || vislam_pose_t_encode(buf, 0, size, &pose) != size ||
        vislam_pose_t_decode(buf, 0, size, &back) != size) {
        return 1;
    }
    printf("vislam_pose_t: %d bytes, utime %lld, x %.1f\n", size, (long long)back.utime, back.position[0]);
    return back.utime == pose.utime && back.position[0] == pose.position[0] ? 0 : 1;
}
