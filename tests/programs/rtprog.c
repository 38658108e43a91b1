/* A small program with named threads, as a user's own binary would be: the test subject of programs (command:).
 *
 * Threads: the main thread (the binary's name), `ctl_loop` (a periodic loop: sleep to the next absolute
 * tick of CLOCK_MONOTONIC, then burn CPU for a while) and three idle "middleware" threads (`mw_exec`,
 * `mw_io`, `mw_timer`) that only sleep, as an executor's helper threads do.  Options:
 *   --period-us N   ctl_loop's period (default 1000)
 *   --burn-us N     CPU time it burns per period (default 100)
 *   --exit-after S  exit with --exit-code (default 0) after S seconds
 *   --crash-after S raise SIGSEGV after S seconds
 *   --ignore-term   ignore SIGTERM (the runner must SIGKILL it)
 *   --alloc-mib N   allocate N MiB and write every page of it at start, and keep it (memory_max)
 *   --rename        create ctl_loop as `tmp_name` and rename it 20 ms later (programs name threads late); it then
 *                   prints how long after its renaming it found its own policy changed (by a rule), from inside
 * It prints one line per event on stdout and flushes it, so its output can be checked.
 */
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static long period_ns = 1000000, burn_ns = 100000;
static int do_rename;

static long long now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void *ctl_loop(void *arg) {
    (void)arg;
    if (do_rename) {
        usleep(20000);
        long long named = now_ns(CLOCK_MONOTONIC);
        pthread_setname_np(pthread_self(), "ctl_loop");
        struct timespec poll = {0, 20000};
        while (sched_getscheduler(0) == SCHED_OTHER && now_ns(CLOCK_MONOTONIC) - named < 1000000000LL) nanosleep(&poll, NULL);
        if (sched_getscheduler(0) != SCHED_OTHER) printf("rtprog: ctl_loop's policy changed %lld us after its renaming\n", (now_ns(CLOCK_MONOTONIC) - named) / 1000);
        else printf("rtprog: ctl_loop's policy did not change within 1 s of its renaming\n");
        fflush(stdout);
    }
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    for (;;) {
        next.tv_nsec += period_ns;
        while (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec++;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        long long until = now_ns(CLOCK_THREAD_CPUTIME_ID) + burn_ns;
        while (now_ns(CLOCK_THREAD_CPUTIME_ID) < until) {
        }
    }
    return NULL;
}

static void *idle(void *arg) {
    (void)arg;
    for (;;) pause();
    return NULL;
}

static void start(const char *name, void *(*fn)(void *)) {
    pthread_t t;
    if (pthread_create(&t, NULL, fn, NULL) != 0) {
        perror("pthread_create");
        exit(2);
    }
    pthread_setname_np(t, name);
}

int main(int argc, char **argv) {
    double exit_after = -1, crash_after = -1;
    int code = 0;
    long alloc_mib = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--period-us") && i + 1 < argc) period_ns = atol(argv[++i]) * 1000;
        else if (!strcmp(argv[i], "--burn-us") && i + 1 < argc) burn_ns = atol(argv[++i]) * 1000;
        else if (!strcmp(argv[i], "--exit-after") && i + 1 < argc) exit_after = atof(argv[++i]);
        else if (!strcmp(argv[i], "--crash-after") && i + 1 < argc) crash_after = atof(argv[++i]);
        else if (!strcmp(argv[i], "--exit-code") && i + 1 < argc) code = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--ignore-term")) signal(SIGTERM, SIG_IGN);
        else if (!strcmp(argv[i], "--rename")) do_rename = 1;
        else if (!strcmp(argv[i], "--alloc-mib") && i + 1 < argc) alloc_mib = atol(argv[++i]);
        else {
            fprintf(stderr, "rtprog: unknown option %s\n", argv[i]);
            return 2;
        }
    }
    if (alloc_mib > 0) {
        char *block = malloc((size_t)alloc_mib << 20);
        if (!block) {
            perror("malloc");
            return 2;
        }
        memset(block, 1, (size_t)alloc_mib << 20);
        printf("rtprog: allocated %ld MiB\n", alloc_mib);
        fflush(stdout);
    }
    start(do_rename ? "tmp_name" : "ctl_loop", ctl_loop);
    start("mw_exec", idle);
    start("mw_io", idle);
    start("mw_timer", idle);
    printf("rtprog: started\n");
    fflush(stdout);
    double wait = exit_after >= 0 ? exit_after : crash_after;
    if (wait < 0) {
        for (;;) pause();
    }
    usleep((useconds_t)(wait * 1e6));
    if (crash_after >= 0) {
        fprintf(stderr, "rtprog: crashing now\n");
        raise(SIGSEGV);
    }
    printf("rtprog: exiting with %d\n", code);
    fflush(stdout);
    return code;
}
