/* Vector-state guard, run inside a SocketCAN guest before any test (.ci/socketcan/run).
   Two threads each keep a value in a vector register across what a guest kernel does
   between two instructions of a thread: a page fault, a system call, a signal, a switch to
   the other thread (which holds a different value in the same register). Prints:

       xmm ok (0 bad of 8000)          SSE state survives (required of every backend)
       ymm ok (0 bad of 8000)          AVX state survives
       ymm CORRUPTED (N bad of 8000)   AVX state is lost (expected on the uml-noxstate backend)
       ymm n/a                         the CPU or the OS offers no AVX

   Exit code 0 when the xmm check passes, 1 when it does not. */
#define _GNU_SOURCE
#include <cpuid.h>
#include <immintrin.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#define ROUNDS 4000
#define PAGES 256

static volatile sig_atomic_t signals_seen;
static long process_id;
static __thread long thread_id;

static void on_signal(int sig) {
    (void)sig;
    signals_seen++;
}

/* A store to a fresh page (a page fault on first touch), then one raw system call:
   sched_yield, getppid or tgkill(SIGUSR1). No function call in between, so nothing the
   C ABI allows to clobber vector registers runs between the load and the check. */
static inline __attribute__((always_inline)) void disturb(int round, char *pages, long page) {
    long number, arg1 = 0, arg2 = 0;
    switch (round % 3) {
    case 0: number = 24; break;   /* sched_yield */
    case 1: number = 110; break;  /* getppid */
    default: number = 234; arg1 = process_id; arg2 = thread_id; break;  /* tgkill */
    }
    pages[(round % PAGES) * page] = (char)round;
    long result;
    __asm__ volatile("syscall"
                     : "=a"(result)
                     : "a"(number), "D"(arg1), "S"(arg2), "d"((long)SIGUSR1)
                     : "rcx", "r11", "memory");
    (void)result;
}

__attribute__((target("avx"))) static long check_ymm(int seed, char *pages, long page) {
    long bad = 0;
    for (int round = 0; round < ROUNDS; round++) {
        __m256i want = _mm256_set1_epi32(seed * 1000003 + round), seen;
        __asm__ volatile("vmovdqu %0, %%ymm7" : : "m"(want) : "xmm7");
        disturb(round, pages, page);
        __asm__ volatile("vmovdqu %%ymm7, %0" : "=m"(seen) : : "xmm7");
        if (memcmp(&seen, &want, sizeof seen) != 0) bad++;
    }
    return bad;
}

static long check_xmm(int seed, char *pages, long page) {
    long bad = 0;
    for (int round = 0; round < ROUNDS; round++) {
        __m128i want = _mm_set1_epi32(seed * 7919 + round), seen;
        __asm__ volatile("movdqu %0, %%xmm6" : : "m"(want) : "xmm6");
        disturb(round, pages, page);
        __asm__ volatile("movdqu %%xmm6, %0" : "=m"(seen) : : "xmm6");
        if (memcmp(&seen, &want, sizeof seen) != 0) bad++;
    }
    return bad;
}

struct job {
    int seed;
    int avx;
    long bad;
};

static void *run_job(void *arg) {
    struct job *job = arg;
    thread_id = gettid();
    long page = sysconf(_SC_PAGESIZE);
    char *pages = mmap(NULL, PAGES * page, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (pages == MAP_FAILED) {
        job->bad = ROUNDS;
        return NULL;
    }
    job->bad = job->avx ? check_ymm(job->seed, pages, page) : check_xmm(job->seed, pages, page);
    munmap(pages, PAGES * page);
    return NULL;
}

static long two_threads(int avx) {
    pthread_t threads[2];
    struct job jobs[2] = {{1, avx, 0}, {2, avx, 0}};
    for (int i = 0; i < 2; i++) pthread_create(&threads[i], NULL, run_job, &jobs[i]);
    for (int i = 0; i < 2; i++) pthread_join(threads[i], NULL);
    return jobs[0].bad + jobs[1].bad;
}

static int os_offers_avx(void) {
    unsigned a, b, c, d;
    if (!__get_cpuid(1, &a, &b, &c, &d) || !(c & bit_AVX) || !(c & bit_OSXSAVE)) return 0;
    unsigned lo, hi;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return (lo & 6) == 6; /* XMM and YMM state enabled by the OS */
}

int main(void) {
    signal(SIGUSR1, on_signal);
    process_id = getpid();
    long xmm = two_threads(0);
    /* fputs, not printf: its output must not depend on the state being checked */
    char line[80];
    snprintf(line, sizeof line, "xmm %s (%ld bad of %d)\n", xmm ? "CORRUPTED" : "ok", xmm,
             2 * ROUNDS);
    fputs(line, stdout);
    if (os_offers_avx()) {
        long ymm = two_threads(1);
        snprintf(line, sizeof line, "ymm %s (%ld bad of %d)\n", ymm ? "CORRUPTED" : "ok", ymm,
                 2 * ROUNDS);
        fputs(line, stdout);
    } else {
        fputs("ymm n/a\n", stdout);
    }
    return xmm ? 1 : 0;
}
