/* Named access to the counters, so tools and the daemon print and publish them all. */
#include "vislam/vislam.h"

size_t vl_counters_list(const vl_counters_t *c, vl_counter_entry_t out[VL_NUM_COUNTERS])
{
    size_t n = 0;
#define VL_COUNTER(field) (out[n].name = #field, out[n].value = (uint64_t)c->field, ++n)
    VL_COUNTER(imu_accepted);
    VL_COUNTER(imu_rejected);
    VL_COUNTER(frames_accepted);
    VL_COUNTER(frames_rejected);
    VL_COUNTER(frames_truncated);
    VL_COUNTER(observations_received);
    VL_COUNTER(observations_truncated);
    VL_COUNTER(observations_invalid);
    VL_COUNTER(observations_low_disparity);
    VL_COUNTER(observations_used);
    VL_COUNTER(observations_gated);
    VL_COUNTER(observations_rescued);
    VL_COUNTER(observations_deferred);
    VL_COUNTER(observations_behind_camera);
    VL_COUNTER(landmarks_initialized);
    VL_COUNTER(landmarks_deferred);
    VL_COUNTER(tracks_inconsistent);
    VL_COUNTER(frames_reassociated);
    VL_COUNTER(frames_repeated);
    VL_COUNTER(tracks_broken);
    VL_COUNTER(landmarks_marginalized);
    VL_COUNTER(landmarks_evicted);
    VL_COUNTER(numerical_failures);
    VL_COUNTER(time_gaps);
    VL_COUNTER(time_jumps);
    VL_COUNTER(timeline_changes);
    VL_COUNTER(divergence_resets);
    VL_COUNTER(resets);
    VL_COUNTER(landmarks_discarded);
    VL_COUNTER(imu_implausible);
    VL_COUNTER(observations_implausible);
    VL_COUNTER(imu_silences);
    VL_COUNTER(frames_imu_silent);
    VL_COUNTER(window_peak);
#undef VL_COUNTER
    return n;
}
