/*
 * Heap allocation counter, loaded with LD_PRELOAD to measure whether a program
 * allocates after its start-up:
 *
 *   LD_PRELOAD=libvl_alloc_counter.so vislamd ...
 *
 * Every malloc, calloc, realloc and aligned allocation of the process (all
 * threads, libraries included) increments one counter, then goes to glibc's
 * allocator through its __libc_* entry points (no dlsym, so no recursion at
 * start-up). A program looks up `uint64_t vl_alloc_count(void)` with
 * dlsym(RTLD_DEFAULT, ...) and compares counts; it finds nothing, and pays
 * nothing, when the library is not preloaded. vl_alloc_count_armed_thread()
 * counts only the allocations of the thread that called vl_alloc_arm() (the
 * daemon's main thread), since that call, to tell them from those of library
 * threads (LCM's receive thread).
 *
 * Finding the culprits: after the program calls vl_alloc_arm() (vislamd does
 * at the end of its start-up), the first $VL_ALLOC_BACKTRACE allocations print
 * their call stack to stderr (backtrace_symbols_fd, which does not allocate).
 * Resolve library offsets with addr2line -e LIB 0xOFFSET.
 */
#define _GNU_SOURCE

#include <errno.h>
#include <execinfo.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

extern void *__libc_malloc(size_t size);
extern void *__libc_calloc(size_t n, size_t size);
extern void *__libc_realloc(void *p, size_t size);
extern void *__libc_memalign(size_t alignment, size_t size);
extern void __libc_free(void *p);

uint64_t vl_alloc_count(void);
uint64_t vl_alloc_count_armed_thread(void);
void vl_alloc_arm(void);

static uint64_t g_count;
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

uint64_t vl_alloc_count(void)
{
    return __atomic_load_n(&g_count, __ATOMIC_RELAXED);
}

/* Allocations made by the thread that called vl_alloc_arm, since that call. */
uint64_t vl_alloc_count_armed_thread(void)
{
    return __atomic_load_n(&g_count_armed_thread, __ATOMIC_RELAXED);
}

void vl_alloc_arm(void)
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
    t_is_armed_thread = 1;
    __atomic_store_n(&g_armed, 1, __ATOMIC_RELAXED);
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
    __libc_free(p);
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
