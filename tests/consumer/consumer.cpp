// The same program as consumer.c, compiled as C++: vislam.h is usable from C++ and the core links
// into a C++ program.
#include "consumer.c"
