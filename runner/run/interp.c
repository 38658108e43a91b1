/*
 * The native core's interpreter and timing: the measured threads' work (sleep, periodic callbacks, spin,
 * programs of events), the start gate, the running figures.  No Python here, by construction: this file
 * does not include Python.h, so nothing it runs can take the GIL (a Python thread that runs bytecode
 * delays every other thread of its process by milliseconds, so a loop that needs the GIL measures the GIL).
 *
 * Memory does not grow with the run: the figures live in fixed log-linear
 * histograms (HdrHistogram's layout: 128 sub-buckets per power of two, so a
 * value is known to within 1/128 of itself, exactly below 256 ns), and raw
 * samples go to a ring the runner drains to disk while the run goes on.
 */
#define _GNU_SOURCE
#include "interp.h"

#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

#define NEEDS(name, needs) [EV_##name] = needs,
const unsigned char ev_needs_resource[EV_COUNT] = {EVENT_KINDS(NEEDS)};
#undef NEEDS

static inline void welford(uint64_t n, double *mean, double *m2, int64_t value) {
    double delta = (double)value - *mean;
    *mean += delta / (double)n;
    *m2 += delta * ((double)value - *mean);
}

volatile sig_atomic_t g_stop = 0;
int g_stop_pipe[2] = {-1, -1};

void on_stop_signal(int sig) {
    (void)sig;
    g_stop = 1;
    if (g_stop_pipe[1] >= 0) {
        char c = 1;
        ssize_t ignored = write(g_stop_pipe[1], &c, 1);
        (void)ignored;
    }
}

static inline void sleep_until(int64_t t) {
    struct timespec ts = to_ts(t);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !g_stop) {
    }
}

static inline void read_ru(int64_t out[4]) {
    struct rusage ru;
    getrusage(RUSAGE_THREAD, &ru);
    out[0] = ru.ru_nivcsw;
    out[1] = ru.ru_nvcsw;
    out[2] = ru.ru_minflt;
    out[3] = ru.ru_majflt;
}

static inline void note_cpu(struct slot_header *h, int cpu) {
    if (cpu >= 0 && cpu < MAX_CPU_WORDS * 64)
        h->cpus_seen[cpu / 64] |= 1ULL << (cpu % 64);
}

/* ------------------------------------------------------------------ settings */

static int sched_setattr_k(pid_t tid, struct sched_attr_k *a) { return (int)syscall(SYS_sched_setattr, tid, a, 0); }

#define SCHED_RESET_ON_FORK_BIT 0x40000000 /* or'ed into sched_setscheduler's policy */
#define FLAG_RESET_ON_FORK 0x01

/* Apply settings to thread `tid` (0: the calling thread); errs gets the errno of sched, nice, cpus (0: done or not asked).
 * With reset_on_fork, SCHED_RESET_ON_FORK is set too (on the current policy when none is given), as chrt -R does. */
void apply_settings_to(pid_t tid, const struct settings *s, int reset_on_fork, int32_t errs[3]) {
    errs[0] = errs[1] = errs[2] = 0;
    if (s->policy == SCHED_DEADLINE_ID) {
        struct sched_attr_k a = {.size = sizeof(a), .sched_policy = SCHED_DEADLINE_ID};
        a.sched_runtime = (uint64_t)s->dl_runtime;
        a.sched_deadline = (uint64_t)s->dl_deadline;
        a.sched_period = (uint64_t)s->dl_period;
        if (reset_on_fork) a.sched_flags |= FLAG_RESET_ON_FORK;
        if (sched_setattr_k(tid, &a) != 0) errs[0] = errno;
    } else if (s->policy >= 0) {
        struct sched_param p = {.sched_priority = s->priority};
        if (sched_setscheduler(tid, s->policy | (reset_on_fork ? SCHED_RESET_ON_FORK_BIT : 0), &p) != 0) errs[0] = errno;
    } else if (reset_on_fork) {
        struct sched_param p;
        int policy = sched_getscheduler(tid);
        if (policy < 0 || sched_getparam(tid, &p) != 0 || sched_setscheduler(tid, policy | SCHED_RESET_ON_FORK_BIT, &p) != 0) errs[0] = errno;
    }
    if (s->util_min >= 0 || s->util_max >= 0) {
        struct sched_attr_k a = {.size = sizeof(a), .sched_flags = FLAG_KEEP_ALL};
        if (s->util_min >= 0) {
            a.sched_flags |= FLAG_UTIL_CLAMP_MIN;
            a.sched_util_min = (uint32_t)s->util_min;
        }
        if (s->util_max >= 0) {
            a.sched_flags |= FLAG_UTIL_CLAMP_MAX;
            a.sched_util_max = (uint32_t)s->util_max;
        }
        if (sched_setattr_k(tid, &a) != 0 && !errs[0]) errs[0] = errno;
    }
    if (s->has_nice) {
        if (setpriority(PRIO_PROCESS, tid ? (id_t)tid : (id_t)syscall(SYS_gettid), s->nice) != 0) errs[1] = errno;
    }
    if (s->ncpus > 0) {
        cpu_set_t set;
        CPU_ZERO(&set);
        for (int i = 0; i < s->ncpus; i++) CPU_SET(s->cpus[i], &set);
        if (sched_setaffinity(tid, sizeof(set), &set) != 0) errs[2] = errno;
    }
}

void apply_settings(const struct settings *s, int32_t errs[3]) { apply_settings_to(0, s, 0, errs); }

/* ------------------------------------------------------------ programs (kind: phases) */

struct timer_state {
    int started;
    int64_t origin, last;
    int64_t due, period; /* the first release not yet served (or counted missed), and the step it comes at; 0: none */
};

/* What a running program keeps to itself (not in the shared buffer). */
struct program_state {
    struct timer_state timers[MAX_EVENTS];
    int timer_key;               /* the timer of the thread's last timer event (its key), -1 before one */
    int64_t t_start;             /* its start: the common start plus its delay (a spawned thread: its creation) */
    int act_open;
    int64_t act_release, act_wake, act_period;
    int32_t act_missed;
    int act_cpu;
    int64_t act_ru[4];
    int64_t act_lock_wait, act_cond_wait, act_barrier_wait; /* blocked so far in the open activation */
    struct lock_wait act_locks[MAX_LOCK_SLOTS];            /* the open activation's waits by mutex (a lock event's slot) */
    int64_t act_lock_longest[MAX_LOCK_SLOTS];              /* the longest contended wait of each, for its holder */
    int64_t origin;              /* release that started this activation's chain, 0 if none */
    int chain_open;
    uint8_t *mem;
    int64_t phase_t0, phase_ru[4];
    int held[MAX_EVENTS];        /* mutexes this thread holds, by resource index, for a clean exit */
    int nheld;
    int io_fd;                   /* iorun: /dev/null, opened before the start; -1 if it could not be */
};

/* The run's start and end: written before the gate opened and never after, so read without a lock. */
static inline int64_t run_start(const struct group *g) { return *(const int64_t *)(g->base + GATE_AT + 8); }
static inline int64_t run_end(const struct group *g) { return *(const int64_t *)(g->base + GATE_AT + 16); }

/* Open a shut gate at `start`, to close at `end`; false if it was opened or cancelled already.  One opener (the
 * runner, or a test's own process): the times are written before the state that publishes them, and a cancel
 * that wins the race leaves them unread. */
int gate_open(char *base, int64_t start, int64_t end) {
    if (atomic_load_explicit(gate_word(base), memory_order_acquire) != GATE_SHUT) return 0;
    memcpy(base + GATE_AT + 8, &start, sizeof(start));
    memcpy(base + GATE_AT + 16, &end, sizeof(end));
    uint32_t shut = GATE_SHUT;
    if (!atomic_compare_exchange_strong_explicit(gate_word(base), &shut, GATE_OPEN, memory_order_acq_rel, memory_order_acquire)) return 0;
    syscall(SYS_futex, gate_word(base), FUTEX_WAKE, INT32_MAX, NULL, NULL, 0);
    return 1;
}

/* Cancel a shut gate: its threads leave without working.  False if it was open already. */
int gate_cancel(char *base) {
    uint32_t shut = GATE_SHUT;
    int done = atomic_compare_exchange_strong_explicit(gate_word(base), &shut, GATE_CANCELLED, memory_order_acq_rel, memory_order_acquire);
    if (done) syscall(SYS_futex, gate_word(base), FUTEX_WAKE, INT32_MAX, NULL, NULL, 0);
    return done || shut == GATE_CANCELLED;
}

/* Wait for the gate; its state once it is no longer shut. */
static uint32_t gate_wait(const struct group *g) {
    uint32_t state;
    while ((state = atomic_load_explicit(gate_word(g->base), memory_order_acquire)) == GATE_SHUT) {
        if (syscall(SYS_futex, gate_word(g->base), FUTEX_WAIT, GATE_SHUT, NULL, NULL, 0) != 0 && errno != EAGAIN && errno != EINTR) {
            struct timespec ms = {0, 1000000}; /* the futex refused (a seccomp filter): wait by the clock, never spin at an RT priority */
            nanosleep(&ms, NULL);
        }
    }
    return state;
}

/* A periodic callback's burn: `ns` of the thread's CPU time (of wall time if `wall`), cut short only by a stop
 * (SIGTERM, SIGINT, the runner's stop).  A callback under way at the run's end runs to its own end, measured, and
 * the background load stays beside it; but one of a long period (up to an hour) at an RT priority must end when
 * the runner stops the cell, not spin on through it. */
static void burn(const struct work *w) {
    clockid_t clock = w->burn_wall ? CLOCK_MONOTONIC : CLOCK_THREAD_CPUTIME_ID;
    int64_t until = now_ns(clock) + w->burn_ns;
    unsigned k = 0;
    while (now_ns(clock) < until) {
        if ((++k & 255) == 0 && g_stop) break;
    }
}

static int touch_memory(int64_t bytes, long page) {
    volatile uint8_t *p = malloc((size_t)bytes);
    if (!p) return ENOMEM;
    for (int64_t off = 0; off < bytes; off += page) p[off] = (uint8_t)off;
    free((void *)p);
    return 0;
}

static inline void wait_until(const struct work *w, int64_t t) {
    if (w->wait_spin) {
        while (!g_stop && now_ns(CLOCK_MONOTONIC) < t) {
        }
    } else {
        sleep_until(t);
    }
}

/* A release's latency: from its place on the grid to the wake-up that answered it. */
static inline void record_latency(struct slot *s, int64_t latency) {
    struct slot_header *h = s->hdr;
    uint64_t n = ++h->releases;
    if (n == 1 || latency < h->lat_min) h->lat_min = latency;
    if (n == 1 || latency > h->lat_max) h->lat_max = latency;
    welford(n, &h->lat_mean, &h->lat_m2, latency);
    if (s->work.bound_ns > 0 && latency > s->work.bound_ns) h->above_bound++;
    if (s->hist) s->hist[hist_index(latency)]++;
}

/* Releases missed in a row (none served between them): counted, and the longest such run kept. */
static inline void note_missed(struct slot_header *h, uint64_t missed) {
    h->missed += missed;
    if (missed > h->missed_consecutive_max) h->missed_consecutive_max = missed;
}

/* Everything a callback adds to the running figures, after it ended (outside the measured span). */
static void record_callback(struct slot *s, const struct sample *c, const struct lock_wait *locks) {
    struct slot_header *h = s->hdr;
    const struct work *w = &s->work;
    int64_t period = c->period_ns;
    /* Skipped releases were answered by this wake-up too: each is as late as the wait for it. */
    for (int32_t k = c->missed; k >= 1; k--) record_latency(s, c->wake_ns - (c->scheduled_ns - k * period));
    record_latency(s, c->wake_ns - c->scheduled_ns);
    uint64_t n = h->loops; /* this callback's number, from 1 */
    /* Slack needs a next release on a grid: an activation released by a resume has none. */
    int64_t slack = c->next_ns > 0 ? c->next_ns - c->end_ns : 0;
    int64_t wall = c->end_ns - c->wake_ns;
    if (c->next_ns > 0) {
        if (slack < 0) h->overruns++;
        if (n == 1 || slack < h->slack_min) h->slack_min = slack;
        if (n == 1 || slack > h->slack_max) h->slack_max = slack;
        welford(n, &h->slack_mean, &h->slack_m2, slack);
    }
    if (n == 1 || wall < h->wall_min) h->wall_min = wall;
    if (n == 1 || wall > h->wall_max) h->wall_max = wall;
    h->nivcsw_sum += (uint64_t)c->nivcsw;
    if ((uint64_t)c->nivcsw > h->nivcsw_max) h->nivcsw_max = (uint64_t)c->nivcsw;
    if (c->nivcsw) h->with_nivcsw++;
    h->minflt_sum += (uint64_t)c->minflt;
    h->nvcsw_sum += (uint64_t)c->nvcsw;
    h->majflt_sum += (uint64_t)c->majflt;
    if ((uint64_t)c->minflt > h->minflt_max) h->minflt_max = (uint64_t)c->minflt;
    if (n == 1) {
        h->minflt_first = c->minflt;
        h->first_wake_ns = c->wake_ns;
    }
    h->last_end_ns = c->end_ns;
    if (s->hist) {
        if (c->next_ns <= 0)
            ;
        else if (slack >= 0)
            s->hist[HIST_BUCKETS + hist_index(slack)]++;
        else
            s->hist[2 * HIST_BUCKETS + hist_index(-slack)]++;
        s->hist[3 * HIST_BUCKETS + hist_index(wall)]++;
    }
    if (s->capacity == 0 || w->ring_mode == RING_NONE) return;
    if (w->ring_mode == RING_OUTLIERS && !(c->missed || slack < 0 || (w->bound_ns > 0 && c->wake_ns - c->scheduled_ns + c->missed * period > w->bound_ns)))
        return;
    uint64_t at = h->count;
    char *el = s->ring + (at % s->capacity) * s->group->sample_size;
    memcpy(el, c, sizeof *c);
    size_t lock_bytes = s->group->lock_slots * sizeof(struct lock_wait);
    if (lock_bytes) {
        if (locks)
            memcpy(el + sizeof *c, locks, lock_bytes);
        else
            memset(el + sizeof *c, 0, lock_bytes);
    }
    atomic_store_explicit((_Atomic uint64_t *)&h->count, at + 1, memory_order_release);
}

static void run_periodic(struct slot *s) {
    struct group *g = s->group;
    struct slot_header *h = s->hdr;
    const struct work *w = &s->work;
    int64_t next = run_start(g) + w->offset_ns;
    int64_t ru0[4], ru1[4];
    int32_t missed = 0;
    struct sample c;
    memset(&c, 0, sizeof(c));
    while (!g_stop && next < run_end(g)) {
        wait_until(w, next);
        if (g_stop) break;
        int64_t wake = now_ns(CLOCK_MONOTONIC);
        int cpu0 = sched_getcpu();
        read_ru(ru0);
        if (w->alloc_bytes > 0) {
            int err = touch_memory(w->alloc_bytes, g->page_size);
            if (err) h->err_other = err;
        }
        int64_t b0 = now_ns(CLOCK_MONOTONIC);
        if (w->burn_ns > 0) burn(w);
        int64_t b1 = now_ns(CLOCK_MONOTONIC);
        read_ru(ru1);
        int cpu1 = sched_getcpu();
        c.scheduled_ns = next;
        c.wake_ns = wake;
        c.end_ns = b1;
        c.burn_wall_ns = b1 - b0;
        c.seq = (int64_t)h->loops;
        c.nivcsw = (int32_t)(ru1[0] - ru0[0]);
        c.nvcsw = (int32_t)(ru1[1] - ru0[1]);
        c.minflt = (int32_t)(ru1[2] - ru0[2]);
        c.majflt = (int32_t)(ru1[3] - ru0[3]);
        c.cpu_start = (int16_t)cpu0;
        c.cpu_end = (int16_t)cpu1;
        c.missed = missed;
        c.period_ns = w->period_ns;
        c.next_ns = next + w->period_ns;
        note_cpu(h, cpu0);
        note_cpu(h, cpu1);
        h->loops++;
        record_callback(s, &c, NULL);
        missed = 0;
        next += w->period_ns;
        int64_t now = now_ns(CLOCK_MONOTONIC);
        while (next < now) { /* overran or woke late: skip the releases already past, as ROS 2 timers do */
            if (next < run_end(g)) missed++;
            next += w->period_ns;
        }
        note_missed(h, (uint64_t)missed);
    }
    /* No release left in the run: wait for its end as a thread waiting for its next release
     * would, rather than run on into the worker's own epilogue (the trace ends this callback's
     * run at this sleep, as it ends every other one's). */
    if (!g_stop && next >= run_end(g)) sleep_until(run_end(g));
}

static void run_spin(struct slot *s) {
    struct group *g = s->group;
    uint64_t loops = 0;
    while (!g_stop) {
        int64_t t = now_ns(CLOCK_MONOTONIC);
        if (t >= run_end(g)) break;
        if ((loops & 1023) == 0) note_cpu(s->hdr, sched_getcpu());
        loops++;
    }
    s->hdr->loops = loops;
}

static void run_sleep(struct slot *s) {
    struct group *g = s->group;
    while (!g_stop) {
        int64_t left = run_end(g) - now_ns(CLOCK_MONOTONIC);
        if (left <= 0) break;
        struct timespec ts = to_ts(left);
        struct pollfd pfd = {.fd = g_stop_pipe[0], .events = POLLIN};
        ppoll(g_stop_pipe[0] >= 0 ? &pfd : NULL, g_stop_pipe[0] >= 0 ? 1 : 0, &ts, NULL);
        note_cpu(s->hdr, sched_getcpu());
    }
}

/* ------------------------------------------------------------ program interpreter */

static inline struct event_stats *ev_stats(struct slot *s, int i) {
    return (struct event_stats *)(s->evbase + (size_t)i * (EV_HDR + HIST_BUCKETS * sizeof(uint64_t)));
}

static inline struct phase_stats *ph_stats(struct slot *s, int i) {
    return (struct phase_stats *)(s->phbase + (size_t)i * PHASE_BYTES);
}

static inline struct resource *res_at(struct slot *s, int i) { return (struct resource *)(s->group->res + (size_t)i * RES_BYTES); }

static inline int live(const struct group *g) { return !g_stop && now_ns(CLOCK_MONOTONIC) < run_end(g); }

static void ev_record(struct slot *s, int i, int64_t v) {
    struct event_stats *e = ev_stats(s, i);
    uint64_t n = ++e->count;
    if (n == 1 || v < e->min) e->min = v;
    if (n == 1 || v > e->max) e->max = v;
    e->sum += v;
    welford(n, &e->mean, &e->m2, v);
    uint64_t *hist = (uint64_t *)((char *)e + EV_HDR);
    hist[hist_index(v)]++;
}

/* An event the end of the run (or the runner's stop) cut short: counted apart, its partial time in no figure. */
static inline void ev_cut(struct slot *s, int i) { ev_stats(s, i)->cut++; }

static void ev_holder(struct slot *s, int i, int32_t holder, int64_t wait) {
    struct event_stats *e = ev_stats(s, i);
    e->contended++;
    for (int k = 0; k < 4; k++) {
        if (e->holder[k] == holder || e->holder[k] == -1) {
            e->holder[k] = holder;
            e->holder_count[k]++;
            e->holder_wait[k] += wait;
            return;
        }
    }
    e->other_holders++;
}

/* A CLOCK_REALTIME instant one slice from now, for pthread_mutex_timedlock. */
static struct timespec slice_realtime(void) { return to_ts(now_ns(CLOCK_REALTIME) + SLICE_NS); }

static struct timespec slice_monotonic(const struct group *g) {
    int64_t t = now_ns(CLOCK_MONOTONIC) + SLICE_NS;
    return to_ts(t < run_end(g) ? t : run_end(g));
}

/* A lock call's result with a dead holder's mutex made consistent and counted: the caller holds it then. */
static int taken_over(struct resource *r, int rc) {
    if (rc != EOWNERDEAD) return rc;
    pthread_mutex_consistent(&r->m);
    __atomic_add_fetch(&r->owner_died, 1, __ATOMIC_RELAXED);
    return 0;
}

/* One slice's wait for the mutex: on CLOCK_MONOTONIC where the C library and kernel serve it (a step of the
 * wall clock would stretch a CLOCK_REALTIME one), else on CLOCK_REALTIME. */
static int lock_slice(struct resource *r, const struct group *g) {
    static _Atomic int pi_realtime_only; /* PI mutexes only: plain ones take CLOCK_MONOTONIC from glibc 2.30 on */
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 30))
    int pi = r->kind != RES_MUTEX || r->protocol == 1; /* as init_resources made them */
    if (!pi || !atomic_load_explicit(&pi_realtime_only, memory_order_relaxed)) {
        struct timespec ts = slice_monotonic(g);
        int rc = pthread_mutex_clocklock(&r->m, CLOCK_MONOTONIC, &ts);
        if (rc != EINVAL || !pi) return taken_over(r, rc);
        atomic_store_explicit(&pi_realtime_only, 1, memory_order_relaxed); /* before glibc 2.35 or FUTEX_LOCK_PI2 */
    }
#endif
    (void)g;
    struct timespec ts = slice_realtime();
    return taken_over(r, pthread_mutex_timedlock(&r->m, &ts));
}

/* Take a resource's mutex, waiting in slices while the run lives: 0, or ETIMEDOUT once it ended (or a stop came). */
static int res_lock(struct resource *r, const struct group *g) {
    int rc = taken_over(r, pthread_mutex_trylock(&r->m));
    while (rc == EBUSY || rc == ETIMEDOUT) {
        if (!live(g)) return ETIMEDOUT;
        rc = lock_slice(r, g);
    }
    return rc;
}

/* A condition's timed wait; the mutex it takes back may be a dead holder's. */
static void res_wait(struct resource *c, struct resource *m, const struct group *g) {
    struct timespec ts = slice_monotonic(g);
    taken_over(m, pthread_cond_timedwait(&c->c, &m->m, &ts));
}

/* Burn thread CPU time (run) or wall time (runtime); gives up at the end of the run.  Whether it burnt it all. */
static int burn_until_end(const struct group *g, int64_t ns, int wall) {
    clockid_t clock = wall ? CLOCK_MONOTONIC : CLOCK_THREAD_CPUTIME_ID;
    int64_t until = now_ns(clock) + ns;
    unsigned k = 0;
    while (now_ns(clock) < until) {
        if ((++k & 255) == 0 && (g_stop || now_ns(CLOCK_MONOTONIC) >= run_end(g))) return 0;
    }
    return 1;
}

/* The release after the open activation's by its own timer's period, as if its timer went on (0: released by a resume). */
static inline int64_t own_next(const struct program_state *ps) { return ps->act_period > 0 ? ps->act_release + ps->act_period : 0; }

/* The open activation ends at `end`; `next` is the release that follows it on its grid (0: none). */
static void activation_close(struct slot *s, struct program_state *ps, int64_t end, int64_t next) {
    if (!ps->act_open) return;
    ps->act_open = 0;
    int64_t ru1[4];
    read_ru(ru1);
    struct sample c;
    memset(&c, 0, sizeof(c));
    c.scheduled_ns = ps->act_release;
    c.wake_ns = ps->act_wake;
    c.end_ns = end;
    c.burn_wall_ns = end - ps->act_wake;
    c.seq = (int64_t)s->hdr->loops;
    c.nivcsw = (int32_t)(ru1[0] - ps->act_ru[0]);
    c.nvcsw = (int32_t)(ru1[1] - ps->act_ru[1]);
    c.minflt = (int32_t)(ru1[2] - ps->act_ru[2]);
    c.majflt = (int32_t)(ru1[3] - ps->act_ru[3]);
    c.cpu_start = (int16_t)ps->act_cpu;
    c.cpu_end = (int16_t)sched_getcpu();
    c.missed = ps->act_missed;
    c.lock_wait_ns = ps->act_lock_wait;
    c.cond_wait_ns = ps->act_cond_wait;
    c.barrier_wait_ns = ps->act_barrier_wait;
    c.origin_ns = ps->origin;
    c.period_ns = ps->act_period;
    c.next_ns = next;
    note_cpu(s->hdr, c.cpu_end);
    s->hdr->loops++;
    record_callback(s, &c, ps->act_locks);
}

/* An activation starts: released at `release` (a timer's tick, or a resume), running since `wake`. */
static void activation_open(struct slot *s, struct program_state *ps, int64_t release, int64_t wake, int64_t period, int32_t missed) {
    ps->act_open = 1;
    ps->act_release = release;
    ps->act_wake = wake;
    ps->act_period = period;
    ps->act_missed = missed;
    ps->act_lock_wait = ps->act_cond_wait = ps->act_barrier_wait = 0;
    for (uint32_t k = 0; k < s->group->lock_slots; k++) { /* the only ones a sample carries */
        ps->act_locks[k] = (struct lock_wait){.holder = -1};
        ps->act_lock_longest[k] = 0;
    }
    ps->act_cpu = sched_getcpu();
    note_cpu(s->hdr, ps->act_cpu);
    read_ru(ps->act_ru);
}

static void chain_close(struct slot *s, struct program_state *ps, int64_t end) {
    if (!ps->chain_open) return;
    ps->chain_open = 0;
    if (ps->origin > 0) ev_record(s, s->prog->nevents, end - ps->origin);
}

static void ev_timer(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    struct group *g = s->group;
    struct timer_state *t = &ps->timers[e->key]; /* one state per timer: the first event naming it */
    int64_t now = now_ns(CLOCK_MONOTONIC);
    int64_t period = e->arg, next, rebased = 0;
    int32_t missed = 0;
    /* Whether the thread follows this timer: its last timer event was this timer's.  A thread that comes to
     * a timer first, or after another timer released it, joins it at its next release (a named timer's next
     * tick on its grid from the common start; the private one's on its grid from the thread's start, or
     * one period from now when it comes back to it from another timer): the releases that
     * passed meanwhile were never due to it, so none is missed.  The open activation's next release is
     * this timer's next on the grid when the thread follows it (a step of this event's period, which for
     * the private timer may differ from the step that released it), else one period of its own after its
     * release. */
    int follows = t->started && ps->timer_key == e->key;
    activation_close(s, ps, now, follows ? t->last + period : own_next(ps));
    if (!follows) {
        if (e->res >= 0)
            t->origin = run_start(g);
        else
            t->origin = t->started ? now : ps->t_start;
        t->started = 1;
        next = t->origin + ((now - t->origin) / period + 1) * period;
    } else {
        next = t->last + period;
        if (next < now) { /* the activation overran, or the thread came late */
            if (e->mode == OVR_SKIP) {
                while (next < now) { /* as periodic work and ROS 2 timers: skip the releases already past */
                    if (next < run_end(g)) missed++;
                    next += period;
                }
            } else if (e->mode == OVR_REBASE) {
                rebased = now; /* run now for the late release; the grid restarts here */
            } /* OVR_CATCHUP: keep the grid, run every late release at once */
        }
    }
    ps->timer_key = e->key;
    t->due = next, t->period = period;
    if (next >= run_end(g)) { /* no release left in the run: the program is over */
        sleep_until(run_end(g));
        return;
    }
    note_missed(s->hdr, (uint64_t)missed);
    wait_until(&s->work, next);
    int64_t wake = now_ns(CLOCK_MONOTONIC);
    t->last = rebased ? rebased : next;
    t->due = t->last + period;
    ev_record(s, i, wake - next);
    activation_open(s, ps, next, wake, period, missed);
    if (!ps->chain_open) ps->origin = next;
}

static int lock_mutex(struct slot *s, struct program_state *ps, int i, int r, int slot) {
    struct resource *m = res_at(s, r);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    int rc = taken_over(m, pthread_mutex_trylock(&m->m));
    int32_t holder = -1;
    int busy = rc == EBUSY;
    if (busy) {
        /* The holder writes its gid just after it takes the mutex: a moment's look lets it (or says none). */
        holder = m->owner;
        for (int k = 0; holder == -1 && k < 64; k++) holder = __atomic_load_n(&m->owner, __ATOMIC_RELAXED);
        s->hdr->blocked_since_ns = t0;
        for (;;) {
            rc = lock_slice(m, s->group);
            if (rc != ETIMEDOUT || !live(s->group)) break;
        }
        /* Given up at the end of the run, or let through only by a thread that was leaving: the slot keeps where it stood. */
        if (rc == 0 && live(s->group)) s->hdr->blocked_since_ns = 0;
        if (rc == 0) ev_holder(s, i, holder, now_ns(CLOCK_MONOTONIC) - t0);
        if (rc == 0) __atomic_add_fetch(&m->contended, 1, __ATOMIC_RELAXED);
    }
    if (rc != 0) {
        ev_cut(s, i);
        return rc;
    }
    m->owner = s->prog->gid;
    __atomic_add_fetch(&m->acquisitions, 1, __ATOMIC_RELAXED);
    int64_t waited = now_ns(CLOCK_MONOTONIC) - t0;
    ev_record(s, i, waited);
    ps->act_lock_wait += waited;
    if (slot >= 0 && slot < MAX_LOCK_SLOTS) {
        struct lock_wait *w = &ps->act_locks[slot];
        w->wait_ns += waited;
        if (w->taken < UINT16_MAX) w->taken++;
        if (busy) {
            if (w->contended < UINT16_MAX) w->contended++;
            if (waited > ps->act_lock_longest[slot]) {
                ps->act_lock_longest[slot] = waited;
                w->holder = holder;
            }
        }
    }
    if (ps->nheld < MAX_EVENTS) ps->held[ps->nheld++] = r;
    return 0;
}

static void unlock_mutex(struct slot *s, struct program_state *ps, int r) {
    struct resource *m = res_at(s, r);
    for (int k = ps->nheld - 1; k >= 0; k--) {
        if (ps->held[k] == r) {
            ps->held[k] = ps->held[--ps->nheld];
            m->owner = -1;
            pthread_mutex_unlock(&m->m);
            return;
        }
    }
}

static void ev_wait(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    struct resource *c = res_at(s, e->res), *m = res_at(s, e->res2);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    int64_t gen = c->generation;
    s->hdr->blocked_since_ns = t0;
    m->owner = -1;
    while (c->generation == gen && live(s->group)) res_wait(c, m, s->group);
    m->owner = s->prog->gid;
    if (c->generation == gen) { /* the run ended while waiting: the slot keeps where it stood */
        ev_cut(s, i);
        return;
    }
    if (live(s->group)) s->hdr->blocked_since_ns = 0;
    int64_t now = now_ns(CLOCK_MONOTONIC);
    ev_record(s, i, now - t0);
    ps->act_cond_wait += now - t0;
    chain_close(s, ps, t0);
    if (c->origin > 0) {
        ps->origin = c->origin;
        ps->chain_open = 1;
    }
}

/* signal and broadcast are called with the cond's mutex held (rt-app's rule) or not; both are fine for pthreads. */
static void ev_signal(struct slot *s, struct program_state *ps, int i, const struct event *e, int all) {
    struct resource *c = res_at(s, e->res);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    c->origin = ps->origin > 0 ? ps->origin : t0;
    __atomic_add_fetch(&c->generation, 1, __ATOMIC_RELEASE);
    if (all)
        pthread_cond_broadcast(&c->c);
    else
        pthread_cond_signal(&c->c);
    ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
}

static void ev_barrier(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    struct resource *b = res_at(s, e->res);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    s->hdr->blocked_since_ns = t0;
    if (res_lock(b, s->group) != 0) { /* the run ended before the barrier's count could be reached */
        ev_cut(s, i);
        return;
    }
    int64_t gen = b->generation;
    if (++b->arrived >= b->parties) {
        b->arrived = 0;
        b->generation++;
        pthread_cond_broadcast(&b->c);
    } else {
        while (b->generation == gen && live(s->group)) res_wait(b, b, s->group);
        if (b->generation == gen) b->arrived--; /* gave up at the end of the run */
    }
    int passed = b->generation != gen;
    pthread_mutex_unlock(&b->m);
    if (!passed) { /* the run ended at the barrier: the slot keeps where it stood */
        ev_cut(s, i);
        return;
    }
    if (live(s->group)) s->hdr->blocked_since_ns = 0;
    int64_t waited = now_ns(CLOCK_MONOTONIC) - t0;
    ev_record(s, i, waited);
    ps->act_barrier_wait += waited;
}

static void ev_resume(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    struct resource *q = res_at(s, e->res);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    if (res_lock(q, s->group) != 0) { /* the run ended before the queue could be reached */
        ev_cut(s, i);
        return;
    }
    if (q->protocol == QUEUE_DROP) {
        /* rt-app's resume (pthread_cond_broadcast under the queue's mutex): it wakes every thread suspended at this
         * moment, and is lost when none is. */
        if (q->arrived > 0) {
            int64_t at = (q->generation + 1) % QDEPTH;
            q->q_origin[at] = ps->origin > 0 ? ps->origin : t0;
            q->q_time[at] = t0;
            q->arrived = 0;
            q->generation++;
            pthread_cond_broadcast(&q->c);
        } else {
            q->dropped++;
            ev_stats(s, i)->dropped++;
        }
    } else if (q->pending < QDEPTH) {
        int64_t at = (q->head + q->pending) % QDEPTH;
        q->q_origin[at] = ps->origin > 0 ? ps->origin : t0;
        q->q_time[at] = t0;
        q->pending++;
        pthread_cond_signal(&q->c);
    } else {
        q->dropped++; /* the consumer is QDEPTH activations behind */
    }
    pthread_mutex_unlock(&q->m);
    ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
}

static void ev_suspend(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    struct resource *q = res_at(s, e->res);
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    if (s->prog->released) activation_close(s, ps, t0, 0);
    chain_close(s, ps, t0);
    s->hdr->blocked_since_ns = t0;
    if (res_lock(q, s->group) != 0) { /* the run ended before the queue could be reached: the slot keeps where it stood */
        ev_cut(s, i);
        return;
    }
    int64_t origin = 0, resumed = 0;
    int got;
    if (q->protocol == QUEUE_DROP) { /* only a resume that comes while it waits wakes it (rt-app's suspend) */
        int64_t gen = q->generation;
        q->arrived++;
        while (q->generation == gen && live(s->group)) res_wait(q, q, s->group);
        got = q->generation != gen;
        if (got) {
            origin = q->q_origin[(gen + 1) % QDEPTH];
            resumed = q->q_time[(gen + 1) % QDEPTH];
        } else {
            q->arrived--; /* the resume that counts it has not come */
        }
    } else {
        while (q->pending == 0 && live(s->group)) res_wait(q, q, s->group);
        got = q->pending > 0;
        if (got) {
            origin = q->q_origin[q->head];
            resumed = q->q_time[q->head];
            q->head = (q->head + 1) % QDEPTH;
            q->pending--;
        }
    }
    pthread_mutex_unlock(&q->m);
    if (!got) { /* the run ended while suspended: the slot keeps where it stood */
        ev_cut(s, i);
        return;
    }
    if (live(s->group)) s->hdr->blocked_since_ns = 0;
    int64_t wake = now_ns(CLOCK_MONOTONIC);
    /* Wake-up latency of the hop: from the resume (or from this wait, if the resume came first) to running. */
    ev_record(s, i, wake - (resumed > t0 ? resumed : t0));
    ps->origin = origin;
    ps->chain_open = 1;
    /* A stage released by resumes: its activation was released by the resume, however long it was
     * still busy with the last one (as a periodic callback's latency runs from its release). */
    if (s->prog->released) activation_open(s, ps, resumed, wake, 0, 0);
}

/* rt-app's fork: start the next free instance of a template thread of this process, now, from this thread
 * (so it inherits this thread's current settings, then applies its own).  The event's figure is the time
 * pthread_create took; a spawn that finds every instance taken (or that the kernel refuses) is counted. */
static void ev_spawn(struct slot *s, int i, const struct event *e) {
    struct group *g = s->group;
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    struct slot *first = &g->slots[e->res];
    /* Claim the next instance only while one is left: a counter bumped by every spawn would wrap in a long run. */
    int k = atomic_load(&first->claimed);
    while (k < e->arg && !atomic_compare_exchange_weak(&first->claimed, &k, k + 1)) {
    }
    if (k >= e->arg) {
        ev_stats(s, i)->dropped++;
        return;
    }
    /* Working from now: the runner must not take the cell's work for over before the new thread says it is ready. */
    struct slot *spawned = &g->slots[e->res + k];
    atomic_store((_Atomic int32_t *)&spawned->hdr->state, ST_STARTING);
    if (create_thread(g, spawned) != 0) {
        atomic_store((_Atomic int32_t *)&spawned->hdr->state, ST_CREATED);
        ev_stats(s, i)->dropped++;
        return;
    }
    ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
}

/* rt-app's iorun: write N bytes to /dev/null (its default io_device), from the thread's buffer. */
static void ev_iorun(struct slot *s, struct program_state *ps, int i, const struct event *e) {
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    int64_t left = e->arg;
    while (left > 0 && ps->io_fd >= 0 && ps->mem) {
        size_t chunk = (size_t)(left < s->prog->mem_bytes ? left : s->prog->mem_bytes);
        ssize_t n = write(ps->io_fd, ps->mem, chunk);
        if (n <= 0) {
            if (n < 0 && errno == EINTR) continue;
            s->hdr->err_other = n < 0 ? errno : EIO;
            break;
        }
        left -= n;
    }
    ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
}

static void run_event(struct slot *s, struct program_state *ps, int i) {
    const struct event *e = &s->prog->events[i];
    struct group *g = s->group;
    int64_t t0;
    s->hdr->cur_event = i;
    switch (e->type) {
        case EV_RUN:
        case EV_RUNTIME:
            t0 = now_ns(CLOCK_MONOTONIC);
            if (burn_until_end(g, e->arg, e->type == EV_RUNTIME))
                ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
            else
                ev_cut(s, i);
            break;
        case EV_SLEEP: {
            t0 = now_ns(CLOCK_MONOTONIC);
            int64_t until = t0 + e->arg;
            sleep_until(until < run_end(g) ? until : run_end(g));
            int64_t t1 = now_ns(CLOCK_MONOTONIC);
            if (t1 >= until) /* a sleep the end of the run (or a stop) cut short is no sleep of its length */
                ev_record(s, i, t1 - t0);
            else
                ev_cut(s, i);
            break;
        }
        case EV_TIMER: ev_timer(s, ps, i, e); break;
        case EV_LOCK: lock_mutex(s, ps, i, e->res, e->res2); break;
        case EV_UNLOCK:
            t0 = now_ns(CLOCK_MONOTONIC);
            unlock_mutex(s, ps, e->res);
            ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
            break;
        case EV_WAIT: ev_wait(s, ps, i, e); break;
        case EV_SIGNAL: ev_signal(s, ps, i, e, 0); break;
        case EV_BROADCAST: ev_signal(s, ps, i, e, 1); break;
        case EV_BARRIER: ev_barrier(s, ps, i, e); break;
        case EV_SUSPEND: ev_suspend(s, ps, i, e); break;
        case EV_RESUME: ev_resume(s, ps, i, e); break;
        case EV_YIELD:
            t0 = now_ns(CLOCK_MONOTONIC);
            sched_yield();
            ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
            break;
        case EV_MEM:
            t0 = now_ns(CLOCK_MONOTONIC);
            if (ps->mem) memset(ps->mem, (int)(s->hdr->loops & 0xff), (size_t)e->arg);
            ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
            break;
        case EV_ALLOC: {
            t0 = now_ns(CLOCK_MONOTONIC);
            int err = touch_memory(e->arg, g->page_size);
            if (err) s->hdr->err_other = err;
            ev_record(s, i, now_ns(CLOCK_MONOTONIC) - t0);
            break;
        }
        case EV_SPAWN: ev_spawn(s, i, e); break;
        case EV_IORUN: ev_iorun(s, ps, i, e); break;
        default: break;
    }
    if (!s->hdr->blocked_since_ns) s->hdr->cur_event = -1;
}

static void read_back(struct phase_stats *st) {
    struct sched_attr_k a;
    memset(&a, 0, sizeof(a));
    if (syscall(SYS_sched_getattr, 0, &a, sizeof(a), 0) == 0) {
        st->policy = (int32_t)a.sched_policy;
        st->priority = (int32_t)a.sched_priority;
        st->nice = a.sched_nice;
        st->dl_runtime = (int64_t)a.sched_runtime;
        st->dl_deadline = (int64_t)a.sched_deadline;
        st->dl_period = (int64_t)a.sched_period;
    }
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof(set), &set) == 0) {
        for (int c = 0; c < MAX_CPU_WORDS * 64 && c < CPU_SETSIZE; c++)
            if (CPU_ISSET(c, &set)) st->affinity[c / 64] |= 1ULL << (c % 64);
    }
    st->read_back = 1;
}

/* Add the time and rusage since the current phase was entered to its figures. */
static void phase_account(struct slot *s, struct program_state *ps) {
    int k = s->hdr->cur_phase;
    if (k < 0) return;
    struct phase_stats *st = ph_stats(s, k);
    int64_t ru1[4];
    read_ru(ru1);
    st->time_ns += now_ns(CLOCK_MONOTONIC) - ps->phase_t0;
    for (int r = 0; r < 4; r++) st->ru[r] += ru1[r] - ps->phase_ru[r];
}

static void run_program(struct slot *s, struct program_state *ps) {
    struct group *g = s->group;
    const struct program *p = s->prog;
    int64_t begin = run_start(g) + p->delay_ns;
    /* A spawned thread starts when it is created; the others at their place on the scenario's clock, whatever
     * the jitter of their release, so that their grids keep the offsets the scenario gives them. */
    ps->t_start = s->deferred ? now_ns(CLOCK_MONOTONIC) : begin;
    if (p->delay_ns > 0) sleep_until(begin < run_end(g) ? begin : run_end(g));
    for (int64_t pass = 0; (p->loop == 0 || pass < p->loop) && live(g); pass++) {
        for (int k = 0; k < p->nphases && live(g); k++) {
            const struct phase *ph = &p->phases[k];
            struct phase_stats *st = ph_stats(s, k);
            if (k != s->hdr->cur_phase) { /* a phase change: account the last one, apply this one's settings */
                phase_account(s, ps);
                s->hdr->cur_phase = k;
                if (ph->has_settings) {
                    int32_t errs[3];
                    apply_settings(&ph->set, errs);
                    if (errs[0]) st->err_sched = errs[0];
                    if (errs[1]) st->err_nice = errs[1];
                    if (errs[2]) st->err_cpus = errs[2];
                }
                if (st->entered++ == 0) read_back(st);
                read_ru(ps->phase_ru);
                ps->phase_t0 = now_ns(CLOCK_MONOTONIC);
            }
            for (int64_t n = 0; n < ph->loop && live(g); n++) {
                for (int i = ph->first; i < ph->first + ph->nevents && live(g); i++) run_event(s, ps, i);
                st->passes++;
                int cpu = sched_getcpu();
                if (cpu >= 0 && cpu < MAX_CPU_WORDS * 64) st->cpus_seen[cpu / 64] |= 1ULL << (cpu % 64);
                note_cpu(s->hdr, cpu);
            }
        }
    }
    phase_account(s, ps);
    int64_t end = now_ns(CLOCK_MONOTONIC);
    if (!live(g) && ps->timer_key >= 0) {
        /* Cut by the end of the run: the releases of the timer it follows from the first it had not served, before
         * the end, came while it was blocked or still busy and were never served (a thread stuck for the last 1.99 s
         * of a 10 ms timer missed 199, not 0).  A timer whose first release was past the end had none due. */
        const struct timer_state *t = &ps->timers[ps->timer_key];
        int64_t until = end < run_end(g) ? end : run_end(g); /* an interrupt ends the count where it came */
        if (t->period > 0 && t->due > 0 && t->due < until) note_missed(s->hdr, (uint64_t)((until - 1 - t->due) / t->period + 1));
    }
    if (ps->timer_key >= 0) s->hdr->timer_due_ns = ps->timers[ps->timer_key].due;
    activation_close(s, ps, end, own_next(ps));
    chain_close(s, ps, end);
    while (ps->nheld > 0) unlock_mutex(s, ps, ps->held[ps->nheld - 1]);
}

/* Before the thread reports ready: its private state, the mem buffer faulted in, stats cleared. */
struct program_state *program_prepare(struct slot *s) {
    struct program_state *ps = calloc(1, sizeof(*ps));
    if (!ps) return NULL;
    ps->io_fd = -1;
    ps->timer_key = -1;
    if (s->prog->mem_bytes > 0) {
        ps->mem = malloc((size_t)s->prog->mem_bytes);
        if (ps->mem) memset(ps->mem, 0, (size_t)s->prog->mem_bytes);
    }
    for (int i = 0; i < s->prog->nevents; i++)
        if (s->prog->events[i].type == EV_IORUN) {
            ps->io_fd = open("/dev/null", O_WRONLY | O_CLOEXEC);
            if (ps->io_fd < 0) s->hdr->err_other = errno;
            break;
        }
    for (int i = 0; i <= s->prog->nevents; i++)
        for (int k = 0; k < 4; k++) ev_stats(s, i)->holder[k] = -1;
    s->hdr->cur_phase = -1;
    s->hdr->cur_event = -1;
    return ps;
}

void program_release(struct program_state *ps) {
    if (!ps) return;
    if (ps->io_fd >= 0) close(ps->io_fd);
    free(ps->mem);
    free(ps);
}

/* A thread that begins after another (start: in_order, as rt-app creates its threads in file order): wait until that one
 * began its work, or ended, or the run did.  Its thread wakes this one as it begins (see run_slot). */
static void wait_begun(struct slot *s) {
    struct slot *first = &s->group->slots[s->after];
    if (!atomic_load((_Atomic int *)&first->started) && first->index != 0) return; /* never created: nothing to wait for */
    _Atomic int32_t *word = (_Atomic int32_t *)&first->hdr->state;
    int32_t st;
    while (((st = atomic_load(word)) == ST_READY || st == ST_CREATED || st == ST_STARTING) && live(s->group)) {
        struct timespec slice = to_ts(SLICE_NS);
        syscall(SYS_futex, word, FUTEX_WAIT, st, &slice, NULL, 0);
    }
}

/* Wait for the gate, run the work, record totals.  Called with the GIL released. */
void run_slot(struct slot *s) {
    struct group *g = s->group;
    struct slot_header *h = s->hdr;
    if (gate_wait(g) != GATE_OPEN) { /* the runner gave up on the cell: leave without working */
        atomic_store((_Atomic int32_t *)&h->state, ST_DONE);
        return;
    }
    if (!s->deferred) h->gate_ns = now_ns(CLOCK_MONOTONIC);
    if (s->work.kind != WORK_PERIODIC) sleep_until(run_start(g));
    if (s->after >= 0) wait_begun(s);
    h->work_start_ns = now_ns(CLOCK_MONOTONIC);
    read_ru(h->start_ru);
    atomic_store((_Atomic int32_t *)&h->state, ST_RUNNING);
    if (atomic_load(&s->follower)) syscall(SYS_futex, &h->state, FUTEX_WAKE, INT32_MAX, NULL, NULL, 0);
    switch (s->work.kind) {
        case WORK_PERIODIC: run_periodic(s); break;
        case WORK_SPIN: run_spin(s); break;
        case WORK_PROGRAM:
            if (s->pstate) run_program(s, s->pstate);
            break;
        default: run_sleep(s); break;
    }
    read_ru(h->end_ru);
    h->work_end_ns = now_ns(CLOCK_MONOTONIC);
    atomic_store((_Atomic int32_t *)&h->state, ST_DONE);
}

/*
 * Write every page of the thread's own slot (header, histograms, ring) before it
 * reports ready, so the faults of the runner's bookkeeping happen here and not in
 * the measured work: a locked, preallocated thread then shows 0 minor faults in
 * total.  The buffer is a memfd, so no writeback ever write-protects the pages
 * again.  Only bytes inside the slot are rewritten (with their own value): the
 * neighbours' bytes on a shared page belong to other threads.
 */
void prefault_slot(struct slot *s) {
    volatile uint8_t *lo = (volatile uint8_t *)s->hdr;
    volatile uint8_t *hi = lo + s->stride;
    long page = s->group->page_size;
    for (volatile uint8_t *p = lo; p < hi;) {
        *p = *p;
        p = (volatile uint8_t *)(((uintptr_t)p / (uintptr_t)page + 1) * (uintptr_t)page);
    }
}

static void *thread_main(void *arg) {
    struct slot *s = arg;
    prctl(PR_SET_NAME, s->name, 0, 0, 0);
    s->hdr->tid = (int32_t)syscall(SYS_gettid);
    prefault_slot(s);
    if (s->explicit_defaults) {
        /* PTHREAD_EXPLICIT_SCHED set policy and CPUs from the attribute; nice is per thread. */
        if (setpriority(PRIO_PROCESS, (id_t)s->hdr->tid, 0) != 0) s->hdr->err_nice = errno;
    }
    int32_t errs[3];
    apply_settings(&s->own, errs);
    if (errs[0]) s->hdr->err_sched = errs[0];
    if (errs[1]) s->hdr->err_nice = errs[1];
    if (errs[2]) s->hdr->err_cpus = errs[2];
    if (s->prog && !(s->pstate = program_prepare(s))) s->hdr->err_other = ENOMEM;
    /* A spawned thread starts after the runner read every thread's settings from /proc: it reads its own
     * back from the kernel into the phase record after its program's (the worker sizes one more for it). */
    if (s->deferred && s->prog && (uint32_t)s->prog->nphases < s->group->nphases) read_back(ph_stats(s, (int)s->group->nphases - 1));
    atomic_store((_Atomic int32_t *)&s->hdr->state, ST_READY);
    run_slot(s);
    program_release(s->pstate);
    s->pstate = NULL;
    return NULL;
}

/* Create slot s's thread (named, settings and work parsed already).  Called from the worker at setup, or from a
 * spawn event mid-run: it inherits the calling thread's settings unless the slot asks for explicit defaults.
 * Returns 0 or the error of pthread_create. */
int create_thread(struct group *g, struct slot *s) {
    pthread_attr_t attr;
    int rc = pthread_getattr_default_np(&attr);
    if (rc) return rc;
    if (s->explicit_defaults) {
        struct sched_param p = {.sched_priority = 0};
        pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
        pthread_attr_setschedpolicy(&attr, SCHED_OTHER);
        pthread_attr_setschedparam(&attr, &p);
        pthread_attr_setaffinity_np(&attr, sizeof(cpu_set_t), &g->all_cpus);
    }
    rc = pthread_create(&s->thread, &attr, thread_main, s);
    pthread_attr_destroy(&attr);
    if (rc == 0) atomic_store((_Atomic int *)&s->started, 1);
    return rc;
}

/* Join every thread of the group, spawned ones included: a pass that joins a spawner makes the threads it
 * spawned visible to the next, so passes repeat until one finds nothing left to join. */
void join_all(struct group *g) {
    int progress;
    do {
        progress = 0;
        for (uint32_t i = 0; i < g->nslots; i++) {
            struct slot *s = &g->slots[i];
            if (atomic_load((_Atomic int *)&s->started)) {
                pthread_join(s->thread, NULL);
                atomic_store((_Atomic int *)&s->started, 0);
                progress = 1;
            }
        }
    } while (progress);
}

