/*
 * A file of the consuming project that warns on purpose: it compiles only if
 * vislam (built as a subproject) leaves its own -Werror out of this project's
 * targets. It includes vislam.h to take the usage requirements of vislam::core.
 */
#include "vislam/vislam.h"

#warning "tests/consumer/warns.c warns on purpose (it must not be an error)"

int consumer_warns_capacity(void)
{
    return VL_MAX_LANDMARKS;
}
