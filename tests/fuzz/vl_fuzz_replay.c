/*
 * Replays inputs through a fuzz harness without libFuzzer, so that regression inputs and seeds
 * run in every build, with any compiler:
 *
 *   vl_fuzz_replay_HARNESS PATH...     each PATH a file or a directory of input files
 *
 * Files in a directory are replayed in name order; names starting with '.' and notes ending in
 * ".md" are not inputs. Each file is named on stdout before it runs, so a crash (the harnesses
 * abort with __builtin_trap) is attributed to the last name printed. Exit 0 when every input
 * ran (a directory with no input is fine: the regression folders start empty), 1 when a path
 * cannot be read.
 *
 * Allocation limit: libFuzzer fails an input that asks malloc for more than -malloc_limit_mb
 * (by default 2048 MiB). A plain build would instead get the memory (or NULL), so an input that
 * crashed the fuzzer could pass here. The driver therefore applies the same limit: above
 * VL_FUZZ_MALLOC_LIMIT_MB (default 2048) an allocation aborts with a message. Under
 * AddressSanitizer, whose allocator the driver must not replace, the same limit is ASan's
 * max_allocation_size_mb.
 */
#define _GNU_SOURCE

#include <dirent.h>
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "vl_fuzz.h"

#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define VL_FUZZ_ASAN 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#define VL_FUZZ_ASAN 1
#endif

#define VL_FUZZ_DEFAULT_LIMIT_MB 2048

#ifdef VL_FUZZ_ASAN

/* ASan reads this before main; the environment's ASAN_OPTIONS still take precedence. */
const char *__asan_default_options(void);
const char *__asan_default_options(void)
{
    return "max_allocation_size_mb=2048:allocator_may_return_null=0";
}

#else

extern void *__libc_malloc(size_t size);
extern void *__libc_calloc(size_t n, size_t size);
extern void *__libc_realloc(void *p, size_t size);
extern void *__libc_memalign(size_t alignment, size_t size);

static size_t g_limit_bytes = (size_t)VL_FUZZ_DEFAULT_LIMIT_MB << 20;

static void vl_fuzz_check_size(size_t size)
{
    if (size <= g_limit_bytes) {
        return;
    }
    /* No stdio: this may run inside an allocation. */
    static const char msg[] = "vl_fuzz_replay: allocation above the limit (VL_FUZZ_MALLOC_LIMIT_MB, as "
                              "libFuzzer's -malloc_limit_mb): the input fails\n";
    if (write(STDERR_FILENO, msg, sizeof(msg) - 1) < 0) {
        /* nothing more to say */
    }
    abort();
}

void *malloc(size_t size)
{
    vl_fuzz_check_size(size);
    return __libc_malloc(size);
}

void *calloc(size_t n, size_t size)
{
    if (size != 0 && n > SIZE_MAX / size) {
        vl_fuzz_check_size(SIZE_MAX);
    }
    vl_fuzz_check_size(n * size);
    return __libc_calloc(n, size);
}

void *realloc(void *p, size_t size)
{
    vl_fuzz_check_size(size);
    return __libc_realloc(p, size);
}

void *memalign(size_t alignment, size_t size)
{
    vl_fuzz_check_size(size);
    return __libc_memalign(alignment, size);
}

void *aligned_alloc(size_t alignment, size_t size)
{
    return memalign(alignment, size);
}

int posix_memalign(void **out, size_t alignment, size_t size)
{
    if (alignment < sizeof(void *) || (alignment & (alignment - 1)) != 0) {
        return EINVAL;
    }
    void *p = memalign(alignment, size);
    if (p == NULL && size != 0) {
        return ENOMEM;
    }
    *out = p;
    return 0;
}

#endif /* VL_FUZZ_ASAN */

static int vl_fuzz_replay_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (f == NULL) {
        fprintf(stderr, "vl_fuzz_replay: %s: %s\n", path, strerror(errno));
        return -1;
    }
    uint8_t *data = NULL;
    size_t size = 0;
    size_t cap = 0;
    for (;;) {
        if (size == cap) {
            cap = cap == 0 ? 65536 : 2 * cap;
            uint8_t *grown = realloc(data, cap);
            if (grown == NULL) {
                fprintf(stderr, "vl_fuzz_replay: %s: out of memory\n", path);
                free(data);
                fclose(f);
                return -1;
            }
            data = grown;
        }
        const size_t n = fread(data + size, 1, cap - size, f);
        size += n;
        if (n == 0) {
            break;
        }
    }
    const int bad = ferror(f);
    fclose(f);
    if (bad) {
        fprintf(stderr, "vl_fuzz_replay: %s: read error\n", path);
        free(data);
        return -1;
    }
    printf("replay %s (%zu bytes)\n", path, size);
    fflush(stdout);
    /* An exact-size copy, so ASan sees reads past the input's end. */
    uint8_t *exact = malloc(size > 0 ? size : 1);
    if (exact == NULL) {
        free(data);
        return -1;
    }
    if (size > 0) {
        memcpy(exact, data, size);
    }
    free(data);
    LLVMFuzzerTestOneInput(exact, size);
    free(exact);
    return 0;
}

static int vl_fuzz_is_input_name(const char *name)
{
    const size_t n = strlen(name);
    return name[0] != '.' && !(n >= 3 && strcmp(name + n - 3, ".md") == 0);
}

/* Returns the number of inputs replayed, or -1. */
static long vl_fuzz_replay_path(const char *path)
{
    struct stat st;
    if (stat(path, &st) != 0) {
        fprintf(stderr, "vl_fuzz_replay: %s: %s\n", path, strerror(errno));
        return -1;
    }
    if (!S_ISDIR(st.st_mode)) {
        return vl_fuzz_replay_file(path) == 0 ? 1 : -1;
    }
    struct dirent **names = NULL;
    const int n = scandir(path, &names, NULL, alphasort);
    if (n < 0) {
        fprintf(stderr, "vl_fuzz_replay: %s: %s\n", path, strerror(errno));
        return -1;
    }
    long done = 0;
    for (int i = 0; i < n; ++i) {
        if (done >= 0 && vl_fuzz_is_input_name(names[i]->d_name)) {
            char file[4096];
            const int len = snprintf(file, sizeof(file), "%s/%s", path, names[i]->d_name);
            struct stat fst;
            if (len <= 0 || (size_t)len >= sizeof(file) || stat(file, &fst) != 0) {
                fprintf(stderr, "vl_fuzz_replay: %s/%s: cannot stat\n", path, names[i]->d_name);
                done = -1;
            } else if (S_ISREG(fst.st_mode)) {
                done = vl_fuzz_replay_file(file) == 0 ? done + 1 : -1;
            }
        }
        free(names[i]);
    }
    free(names);
    return done;
}

int main(int argc, char **argv)
{
#ifndef VL_FUZZ_ASAN
    const char *limit = getenv("VL_FUZZ_MALLOC_LIMIT_MB");
    if (limit != NULL && atol(limit) > 0) {
        g_limit_bytes = (size_t)atol(limit) << 20;
    }
#endif
    if (argc < 2) {
        fprintf(stderr, "usage: %s FILE_OR_DIRECTORY...\n", argv[0]);
        return 2;
    }
    long total = 0;
    for (int i = 1; i < argc; ++i) {
        const long n = vl_fuzz_replay_path(argv[i]);
        if (n < 0) {
            return 1;
        }
        if (n == 0) {
            printf("%s: no inputs\n", argv[i]);
        }
        total += n;
    }
    printf("%ld input(s) replayed, none crashed\n", total);
    return 0;
}
