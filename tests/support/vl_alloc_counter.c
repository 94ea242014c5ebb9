/*
 * Heap allocation counter, loaded with LD_PRELOAD to measure whether a program
 * allocates after its start-up, without the program knowing about it:
 *
 *   VL_ALLOC_REPORT=out.alloc LD_PRELOAD=libvl_alloc_counter.so vislamd ...
 *
 * or linked into a test executable, which then reads the counts around the
 * calls it measures (vl_alloc_counter.h; tests/test_alloc.c).
 *
 * Every malloc, calloc, realloc and aligned allocation of the process (all
 * threads, libraries included) increments one counter, then goes to glibc's
 * allocator through its __libc_* entry points (no dlsym, so no recursion at
 * start-up).
 *
 * Arming: the end of start-up is the program's first mlockall(), which the
 * counter interposes (the call itself goes to the kernel unchanged). vislamd
 * locks its memory as the last step of its start-up, once everything the loop
 * uses is mapped, so "after arming" is "in the message loop". From then on the
 * counter also counts the allocations of the thread that called mlockall (the
 * daemon's main, estimation thread) separately from those of library threads
 * (LCM's receive thread). A program that never calls mlockall (vislamd
 * --no-mlock) is never armed.
 *
 * Reporting: at exit (a destructor, so after main returns or exit() is
 * called), when $VL_ALLOC_REPORT names a file, the counter writes "key value"
 * lines to it, the format tests/support/vl_log_inspect prints:
 *
 *   alloc.armed 0|1                      mlockall was called
 *   alloc.process_total N                every allocation since the library loaded
 *   alloc.process_after_arm N            every thread's, after arming
 *   alloc.armed_thread_after_arm N       the arming thread's, after arming
 *
 * Finding the culprits: after arming, the first $VL_ALLOC_BACKTRACE
 * allocations print their call stack to stderr (backtrace_symbols_fd, which
 * does not allocate). Resolve library offsets with addr2line -e LIB 0xOFFSET.
 */
#define _GNU_SOURCE

#include <errno.h>
#include <fcntl.h>
#include <execinfo.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "vl_alloc_counter.h"
extern void *__libc_malloc(size_t size);
extern void *__libc_calloc(size_t n, size_t size);
extern void *__libc_realloc(void *p, size_t size);
extern void *__libc_memalign(size_t alignment, size_t size);
extern void __libc_free(void *p);

int mlockall(int flags);

static uint64_t g_count;
static uint64_t g_frees;
static uint64_t g_count_at_arm;
static uint64_t g_count_armed_thread;
static __thread int t_is_armed_thread;
static int g_armed;
static long g_trace_left;
static __thread int t_in_trace;

static void trace(size_t size)
{
    /* Only the first few after arming, never from inside our own tracing. */
    if (!__atomic_load_n(&g_armed, __ATOMIC_RELAXED) || t_in_trace ||
        __atomic_fetch_sub(&g_trace_left, 1, __ATOMIC_RELAXED) <= 0) {
        return;
    }
    t_in_trace = 1;
    char head[96];
    const char *msg = "vl_alloc_counter: allocation after start-up, size ";
    size_t n = strlen(msg);
    memcpy(head, msg, n);
    char digits[24];
    size_t k = 0;
    do {
        digits[k++] = (char)('0' + size % 10);
        size /= 10;
    } while (size != 0 && k < sizeof(digits));
    while (k > 0 && n < sizeof(head) - 2) {
        head[n++] = digits[--k];
    }
    head[n++] = '\n';
    if (write(STDERR_FILENO, head, n) < 0) {
        /* nothing to do: this is a diagnostic */
    }
    void *frames[32];
    const int depth = backtrace(frames, 32);
    backtrace_symbols_fd(frames, depth, STDERR_FILENO);
    t_in_trace = 0;
}

static void count(size_t size)
{
    __atomic_fetch_add(&g_count, 1, __ATOMIC_RELAXED);
    if (t_is_armed_thread) {
        __atomic_fetch_add(&g_count_armed_thread, 1, __ATOMIC_RELAXED);
    }
    trace(size);
}

/* The end of the program's start-up: counting per thread starts here (see the top of the file). */
static void arm(void)
{
    const char *env = getenv("VL_ALLOC_BACKTRACE");
    long n = env != NULL ? strtol(env, NULL, 10) : 0;
    if (n > 0) {
        /* backtrace() loads libgcc_s (and allocates) on first use: do that now. */
        void *frames[4];
        t_in_trace = 1;
        (void)backtrace(frames, 4);
        t_in_trace = 0;
    }
    __atomic_store_n(&g_trace_left, n, __ATOMIC_RELAXED);
    __atomic_store_n(&g_count_armed_thread, 0, __ATOMIC_RELAXED);
    __atomic_store_n(&g_count_at_arm, __atomic_load_n(&g_count, __ATOMIC_RELAXED), __ATOMIC_RELAXED);
    t_is_armed_thread = 1;
    __atomic_store_n(&g_armed, 1, __ATOMIC_RELAXED);
}

int mlockall(int flags)
{
    /* The system call itself, so no lookup of the next definition (dlsym allocates). */
    const long r = syscall(SYS_mlockall, flags);
    const int saved = errno;
    if (!__atomic_load_n(&g_armed, __ATOMIC_RELAXED)) {
        arm();
    }
    errno = saved;
    return r == 0 ? 0 : -1;
}

/* Written with write(2) from a stack buffer: reporting must not allocate what it counts. */
__attribute__((destructor)) static void report(void)
{
    const char *path = getenv("VL_ALLOC_REPORT");
    if (path == NULL || path[0] == '\0') {
        return;
    }
    const uint64_t total = __atomic_load_n(&g_count, __ATOMIC_RELAXED);
    const int armed = __atomic_load_n(&g_armed, __ATOMIC_RELAXED);
    const uint64_t at_arm = __atomic_load_n(&g_count_at_arm, __ATOMIC_RELAXED);
    char buf[256];
    const int n = snprintf(buf, sizeof(buf),
                           "alloc.armed %d\nalloc.process_total %llu\nalloc.process_after_arm %llu\n"
                           "alloc.armed_thread_after_arm %llu\n",
                           armed, (unsigned long long)total, (unsigned long long)(armed ? total - at_arm : 0),
                           (unsigned long long)(armed ? __atomic_load_n(&g_count_armed_thread, __ATOMIC_RELAXED) : 0));
    const int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0 || n <= 0) {
        return;
    }
    if (write(fd, buf, (size_t)n) != n) {
        /* nothing to do: the reader finds the file short and says so */
    }
    close(fd);
}

void *malloc(size_t size)
{
    count(size);
    return __libc_malloc(size);
}

void *calloc(size_t n, size_t size)
{
    count(n * size);
    return __libc_calloc(n, size);
}

void *realloc(void *p, size_t size)
{
    count(size);
    return __libc_realloc(p, size);
}

void free(void *p)
{
    if (p != NULL) {
        __atomic_fetch_add(&g_frees, 1, __ATOMIC_RELAXED);
    }
    __libc_free(p);
}

uint64_t vl_alloc_counter_allocations(void)
{
    return __atomic_load_n(&g_count, __ATOMIC_RELAXED);
}

uint64_t vl_alloc_counter_frees(void)
{
    return __atomic_load_n(&g_frees, __ATOMIC_RELAXED);
}

void *memalign(size_t alignment, size_t size)
{
    count(size);
    return __libc_memalign(alignment, size);
}

void *aligned_alloc(size_t alignment, size_t size)
{
    count(size);
    return __libc_memalign(alignment, size);
}

int posix_memalign(void **out, size_t alignment, size_t size)
{
    if (alignment < sizeof(void *) || (alignment & (alignment - 1)) != 0) {
        return EINVAL;
    }
    count(size);
    void *p = __libc_memalign(alignment, size);
    if (p == NULL && size != 0) {
        return ENOMEM;
    }
    *out = p;
    return 0;
}

void *valloc(size_t size)
{
    count(size);
    return __libc_memalign((size_t)sysconf(_SC_PAGESIZE), size);
}
