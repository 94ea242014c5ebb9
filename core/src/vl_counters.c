/* Named access to the counters, so tools and the daemon print and publish them all. */
#include "vislam/vislam.h"

#include <stddef.h>

/* C99 has no _Static_assert: a negative array size stops the build instead. */
#define VL_STATIC_CHECK(cond, name) typedef char vl_static_check_##name[(cond) ? 1 : -1]

/* Each counter must fit the uint64_t of vl_counter_entry_t without loss. */
#define VL_COUNTER_FITS_(type, field, meaning) VL_STATIC_CHECK(sizeof(type) <= sizeof(uint64_t), field);
VL_COUNTERS(VL_COUNTER_FITS_)
#undef VL_COUNTER_FITS_

/* The counters are the only members and they sit without holes (uint64_t rows before the
   uint32_t ones), so zeroing, copying and comparing a vl_counters_t touches counters only:
   the rows' sizes, rounded up to the struct's alignment of 8, are its whole size. */
#define VL_COUNTER_SIZE_(type, field, meaning) +sizeof(type)
VL_STATIC_CHECK((((0 VL_COUNTERS(VL_COUNTER_SIZE_)) + 7) / 8) * 8 == sizeof(vl_counters_t), counters_packed);
#undef VL_COUNTER_SIZE_

/* VL_NUM_COUNTERS sizes arrays in the tools: it must be the number of rows. */
#define VL_COUNTER_NAME_(type, field, meaning) #field,
static const char *const k_counter_names[] = {VL_COUNTERS(VL_COUNTER_NAME_)};
#undef VL_COUNTER_NAME_
VL_STATIC_CHECK(sizeof(k_counter_names) / sizeof(k_counter_names[0]) == VL_NUM_COUNTERS, num_counters);

size_t vl_counters_list(const vl_counters_t *c, vl_counter_entry_t out[VL_NUM_COUNTERS])
{
    size_t n = 0;
#define VL_COUNTER_ENTRY_(type, field, text) \
    out[n].name = k_counter_names[n];        \
    out[n].value = (uint64_t)c->field;       \
    out[n].meaning = text;                   \
    ++n;
    VL_COUNTERS(VL_COUNTER_ENTRY_)
#undef VL_COUNTER_ENTRY_
    return n;
}
