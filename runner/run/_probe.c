/*
 * runner.run._probe: the native core of the runner.
 *
 * Everything measured runs here, in threads that never touch the Python
 * interpreter: a Python thread that runs bytecode delays every other thread of
 * its process by milliseconds, so a loop that needs the GIL measures the GIL.
 *
 * A Group owns the threads of one worker process.  Threads are created with
 * pthread_create from the calling thread, so the kernel's own inheritance
 * rules decide what they start with; a thread with settings of its own applies
 * them to itself.  Each thread records into its slot of a shared, file-backed
 * buffer (layout below) that the runner reads while the run goes on and after
 * it ends, even when the worker dies.  The loop allocates nothing.
 *
 * Buffer layout (little endian, all offsets in bytes), version 7:
 *   file header, 128 bytes: magic "RSMP0007", u32 version, u32 nthreads,
 *                           u32 capacity, u32 slot_header_size, u32 sample_size,
 *                           u32 hist_buckets (0 when the group keeps none),
 *                           u64 slot_stride, u32 event_stats, u32 phase_stats;
 *                           at 64 the start gate: u32 state (a futex word: 0 shut, 1 open,
 *                           2 cancelled), u32 unused, i64 start_ns, i64 end_ns
 *   per thread, at 128 + i * slot_stride:
 *     slot header, 512 bytes (struct slot_header): totals and running figures
 *     histograms, 3 * hist_buckets u64 (latency, slack >= 0, -slack for slack < 0)
 *     then a second block of hist_buckets u64: callback wall time
 *     ring of capacity samples of sample_size bytes, sample n at n % capacity: a 112-byte struct sample,
 *       then lock_slots 16-byte struct lock_wait (programs: the activation's wait on each mutex it locks)
 *     event_stats times (192-byte struct event_stats + hist_buckets u64): programs' events, then the chain
 *     phase_stats times 384 bytes (struct phase_stats): programs' phases (a spawned thread's start read-back last)
 *
 * Memory does not grow with the run: the figures live in fixed log-linear
 * histograms (HdrHistogram's layout: 128 sub-buckets per power of two, so a
 * value is known to within 1/128 of itself, exactly below 256 ns), and raw
 * samples go to a ring the runner drains to disk while the run goes on.
 */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <linux/futex.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include "histogram.h" /* HIST_* and hist_index(), shared with _trace.c */

#define FILE_HEADER 128
#define GATE_AT 64 /* the start gate in the file header: state, then start and end (CLOCK_MONOTONIC) */
enum gate_state { GATE_SHUT = 0, GATE_OPEN = 1, GATE_CANCELLED = 2 };
#define SLOT_HEADER 512
#define SAMPLE_BYTES 112
#define MAX_LOCK_SLOTS 8 /* mutexes a thread's activations keep apart, in the order its program first locks them */
#define MAX_CPU_WORDS 16

#define HIST_SETS 4 /* latency, slack >= 0, -slack, callback wall time */

enum work_kind { WORK_SLEEP = 0, WORK_PERIODIC = 1, WORK_SPIN = 2, WORK_PROGRAM = 3 };
enum slot_state { ST_CREATED = 0, ST_READY = 1, ST_RUNNING = 2, ST_DONE = 3, ST_FAILED = 4, ST_STARTING = 5 };
enum ring_mode { RING_NONE = 0, RING_ALL = 1, RING_OUTLIERS = 2 };

struct slot_header {
    int32_t tid;
    int32_t state;
    uint64_t count;        /* samples written to the ring (all time); published after each sample */
    int32_t err_sched;     /* errno of applying the policy, 0 if fine or not asked */
    int32_t err_nice;
    int32_t err_cpus;
    int32_t err_other;     /* e.g. ENOMEM of a per-callback allocation */
    int64_t start_ru[4];   /* nivcsw, nvcsw, minflt, majflt when the work starts */
    int64_t end_ru[4];     /* the same when it ends */
    uint64_t loops;        /* callbacks, or spin slices */
    uint64_t missed;       /* releases skipped because a callback overran or woke late */
    int64_t work_start_ns;
    int64_t work_end_ns;
    uint64_t cpus_seen[MAX_CPU_WORDS];
    /* running figures of the periodic work, updated after each callback */
    uint64_t releases;     /* releases in the latency histogram: callbacks plus skipped releases */
    uint64_t overruns;     /* callbacks that ended after their next release */
    uint64_t above_bound;  /* releases whose latency exceeded the work's bound */
    int64_t lat_min, lat_max;
    double lat_mean, lat_m2;      /* Welford's running mean and sum of squared deviations */
    int64_t slack_min, slack_max;
    double slack_mean, slack_m2;
    int64_t wall_min, wall_max;
    uint64_t nivcsw_sum, nivcsw_max, with_nivcsw;
    uint64_t minflt_sum, minflt_max;
    int64_t minflt_first;         /* -1 until the first callback ran */
    int64_t first_wake_ns, last_end_ns;
    uint64_t nvcsw_sum, majflt_sum; /* with nivcsw_sum and minflt_sum: the totals of a thread that never finished */
    /* where a program (kind: phases) is, for the runner's stall and deadlock report */
    int32_t cur_phase;            /* -1 before the first phase */
    int32_t cur_event;            /* index in the program's event list, -1 between events */
    int64_t blocked_since_ns;     /* when the current blocking event (lock, wait, barrier, suspend) began; 0 if none */
    int64_t timer_due_ns;         /* at its end, the first release of the timer it followed that it had not served; 0: none */
    int64_t gate_ns;              /* when it passed the start gate (0: not yet, or a thread spawned mid-run) */
    uint8_t reserved[SLOT_HEADER - 472];
};

struct sample {
    int64_t scheduled_ns;  /* the release this callback served, on the absolute grid */
    int64_t wake_ns;       /* when the thread actually ran */
    int64_t end_ns;        /* end of the callback */
    int64_t burn_wall_ns;  /* wall time the burn took (grows when preempted) */
    int64_t seq;           /* the callback's number, from 0 */
    int32_t nivcsw;        /* deltas over the callback, from getrusage(RUSAGE_THREAD) */
    int32_t nvcsw;
    int32_t minflt;
    int32_t majflt;
    int16_t cpu_start;
    int16_t cpu_end;
    int32_t missed;        /* releases skipped just before this one */
    /* programs (kind: phases): time this activation spent blocked, by what on (0 for periodic work) */
    int64_t lock_wait_ns;  /* acquiring mutexes */
    int64_t cond_wait_ns;  /* in wait on a condition variable */
    int64_t barrier_wait_ns;
    int64_t origin_ns;     /* programs: the timer release that started this activation's chain, 0 if none */
    int64_t period_ns;     /* the grid's step to its release: the period of the timer event that released it; 0: a resume */
    int64_t next_ns;       /* the release after it on its grid (slack = next_ns - end_ns); 0: none (a resume released it) */
};

/* One activation's wait for one of the mutexes its thread locks. */
struct lock_wait {
    int64_t wait_ns;       /* acquiring it, summed over this activation's locks of it */
    int32_t holder;        /* the thread (gid) that held it when the longest of those waits began; -1: none seen */
    uint16_t taken;        /* times this activation locked it */
    uint16_t contended;    /* of those, times it had to wait */
};

_Static_assert(sizeof(struct slot_header) == SLOT_HEADER, "slot header size");
_Static_assert(sizeof(struct sample) == SAMPLE_BYTES, "sample size");
_Static_assert(sizeof(struct lock_wait) == 16, "lock wait size");

static inline void welford(uint64_t n, double *mean, double *m2, int64_t value) {
    double delta = (double)value - *mean;
    *mean += delta / (double)n;
    *m2 += delta * ((double)value - *mean);
}

static volatile sig_atomic_t g_stop = 0;
static int g_stop_pipe[2] = {-1, -1};

static void on_stop_signal(int sig) {
    (void)sig;
    g_stop = 1;
    if (g_stop_pipe[1] >= 0) {
        char c = 1;
        ssize_t ignored = write(g_stop_pipe[1], &c, 1);
        (void)ignored;
    }
}

static inline int64_t now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static inline struct timespec to_ts(int64_t ns) {
    struct timespec ts = {(time_t)(ns / 1000000000LL), (long)(ns % 1000000000LL)};
    return ts;
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

struct settings {
    int policy;          /* -1: leave as is */
    int priority;
    int has_nice;
    int nice;
    int64_t dl_runtime, dl_deadline, dl_period; /* SCHED_DEADLINE parameters, ns */
    int util_min, util_max;                     /* uclamp, -1: leave as is */
    int ncpus;           /* 0: leave as is */
    int cpus[1024];
};

/* struct sched_attr of sched_setattr(2); glibc has no wrapper. */
struct sched_attr_k {
    uint32_t size;
    uint32_t sched_policy;
    uint64_t sched_flags;
    int32_t sched_nice;
    uint32_t sched_priority;
    uint64_t sched_runtime, sched_deadline, sched_period;
    uint32_t sched_util_min, sched_util_max;
};

#define SCHED_DEADLINE_ID 6
#define FLAG_KEEP_ALL 0x18 /* SCHED_FLAG_KEEP_POLICY | SCHED_FLAG_KEEP_PARAMS */
#define FLAG_UTIL_CLAMP_MIN 0x20
#define FLAG_UTIL_CLAMP_MAX 0x40

static int sched_setattr_k(pid_t tid, struct sched_attr_k *a) { return (int)syscall(SYS_sched_setattr, tid, a, 0); }

#define SCHED_RESET_ON_FORK_BIT 0x40000000 /* or'ed into sched_setscheduler's policy */
#define FLAG_RESET_ON_FORK 0x01

/* Apply settings to thread `tid` (0: the calling thread); errs gets the errno of sched, nice, cpus (0: done or not asked).
 * With reset_on_fork, SCHED_RESET_ON_FORK is set too (on the current policy when none is given), as chrt -R does. */
static void apply_settings_to(pid_t tid, const struct settings *s, int reset_on_fork, int32_t errs[3]) {
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

static void apply_settings(const struct settings *s, int32_t errs[3]) { apply_settings_to(0, s, 0, errs); }

/* Fill a settings struct from Python values; returns -1 with an exception set.
 * `extra` is None or (dl_runtime, dl_deadline, dl_period, util_min, util_max), -1 for a uclamp left as is. */
static int parse_settings(PyObject *policy, PyObject *priority, PyObject *nice, PyObject *cpus, PyObject *extra, struct settings *out) {
    memset(out, 0, sizeof(*out));
    out->policy = -1;
    out->util_min = out->util_max = -1;
    if (extra && extra != Py_None) {
        long long rt, dl, per;
        if (!PyArg_ParseTuple(extra, "LLLii", &rt, &dl, &per, &out->util_min, &out->util_max)) return -1;
        out->dl_runtime = rt;
        out->dl_deadline = dl;
        out->dl_period = per;
    }
    if (policy != Py_None) {
        out->policy = (int)PyLong_AsLong(policy);
        out->priority = priority == Py_None ? 0 : (int)PyLong_AsLong(priority);
    }
    if (nice != Py_None) {
        out->has_nice = 1;
        out->nice = (int)PyLong_AsLong(nice);
    }
    if (PyErr_Occurred()) return -1;
    if (cpus != Py_None) {
        PyObject *seq = PySequence_Fast(cpus, "cpus must be a sequence of ints");
        if (!seq) return -1;
        Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
        if (n > 1024) n = 1024;
        for (Py_ssize_t i = 0; i < n; i++) {
            out->cpus[i] = (int)PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        }
        out->ncpus = (int)n;
        Py_DECREF(seq);
        if (PyErr_Occurred()) return -1;
    }
    return 0;
}

/* -------------------------------------------------------------------- work */

struct work {
    int kind;
    int64_t period_ns;
    int64_t burn_ns;
    int burn_wall;
    int64_t alloc_bytes;
    int64_t offset_ns;
    int wait_spin;       /* wait for a release by spinning on the clock instead of sleeping */
    int64_t bound_ns;    /* latency bound: releases above it are counted (0: none) */
    int ring_mode;       /* which callbacks go to the sample ring */
};

/* ------------------------------------------------------------ programs (kind: phases) */

/*
 * A program is a thread's work as rt-app describes one: phases of events, each
 * phase with a loop count and its own scheduling applied on entry.  Events that
 * block (lock, wait, barrier, suspend) wait on objects in a shared segment the
 * runner creates, so threads of different processes synchronise too.  Every
 * blocking wait is cut into 100 ms slices that check for the end of the run, so
 * a scenario that deadlocks still ends with its cell, and the slot tells where
 * each thread stood.
 *
 * Per event the slot keeps its running figures and a histogram (time waited for
 * a lock, a condition, a barrier; wake-up latency of a timer or a resume; wall
 * time of a run), plus who held a contended lock; per phase, its passes, time,
 * switches, faults, CPUs and the settings the kernel reported on entry.  A timer
 * opens an activation that ends at the next timer: activations are the thread's
 * callbacks (releases, latency, slack, overruns and samples as periodic work).
 * In a thread without a timer that suspends (a chain's later stage), a resume
 * opens the activation and the next suspend ends it: latency from the resume,
 * no slack (there is no next release to measure it against).
 */
#define MAX_PHASES 32
#define MAX_EVENTS 128
#define EV_HDR 192
#define PHASE_BYTES 384
#define RES_BYTES 1024
#define QDEPTH 32
#define SLICE_NS 100000000LL

enum ev_type {
    EV_RUN = 1, EV_RUNTIME, EV_SLEEP, EV_TIMER, EV_LOCK, EV_UNLOCK, EV_WAIT, EV_SIGNAL, EV_BROADCAST,
    EV_BARRIER, EV_SUSPEND, EV_RESUME, EV_YIELD, EV_MEM, EV_ALLOC, EV_SPAWN, EV_IORUN
};
enum res_kind { RES_MUTEX = 1, RES_COND, RES_BARRIER, RES_QUEUE, RES_TIMER };
enum queue_mode { QUEUE_KEEP = 0, QUEUE_DROP = 1 }; /* a queue's protocol: what becomes of a resume no thread waits for */
enum overrun_mode { OVR_SKIP = 0, OVR_REBASE = 1, OVR_CATCHUP = 2 };

struct event {
    int type;
    int res;       /* resource index, -1 if none */
    int res2;      /* wait: the mutex */
    int mode;      /* timer: overrun mode */
    int key;       /* timer: index of the first event of the same timer (its state) */
    int64_t arg;   /* ns or bytes; timer: period */
};

struct phase {
    int64_t loop;
    int first, nevents;
    int has_settings;
    struct settings set;
};

struct program {
    int32_t gid;   /* the thread's number in the cell, what resources record as owner */
    int64_t delay_ns;
    int64_t loop;  /* passes over the phases, 0: until the end of the run */
    int nphases, nevents;
    int released;  /* no timer, and a suspend: its activations are released by resumes (a chain's later stage) */
    struct phase phases[MAX_PHASES];
    struct event events[MAX_EVENTS];
    int64_t mem_bytes;
};

/* Figures of one event (and, after the last event, of the thread's chain latency). */
struct event_stats {
    uint64_t count;
    int64_t sum, min, max;
    double mean, m2;
    uint64_t contended;          /* lock: acquisitions that had to wait */
    int32_t holder[4];           /* lock: gids seen holding it on contention, -1 unused */
    uint64_t holder_count[4];
    int64_t holder_wait[4];
    uint64_t other_holders;      /* contentions by holders beyond the four above */
    uint64_t dropped;            /* spawn: spawns that found every instance of the template taken, or failed;
                                  * resume: resumes of a queue that drops them that found no thread suspended */
    uint64_t cut;                /* events under way when the run ended (or the runner stopped it): not in count or figures */
    uint8_t reserved[EV_HDR - 160];
};

struct phase_stats {
    uint64_t passes;             /* passes over the phase's events, loops counted */
    int64_t time_ns;
    int64_t ru[4];               /* nivcsw, nvcsw, minflt, majflt over the phase */
    uint64_t cpus_seen[MAX_CPU_WORDS];
    int32_t entered;
    int32_t policy, priority, nice;      /* read back from the kernel on the first entry */
    int32_t err_sched, err_nice, err_cpus, read_back;
    int64_t dl_runtime, dl_deadline, dl_period;
    uint64_t affinity[MAX_CPU_WORDS];
    uint8_t reserved[PHASE_BYTES - 360];
};

/* One synchronisation object in the shared segment; pthread objects are process-shared.  `protocol` is a mutex's
 * (1: priority inheritance) or a queue's (QUEUE_DROP: rt-app's resume).  A queue that keeps its resumes counts them in
 * `pending` from `head`, each with its origin and time; one that drops them counts its suspended threads in `arrived`
 * and its resumes in `generation`, each resume's origin and time at its generation. */
struct resource {
    int32_t kind, parties, owner, protocol;
    int64_t period;
    int64_t arrived, generation, pending, dropped, head, origin;
    uint64_t acquisitions, contended;
    uint64_t owner_died; /* times a thread took the mutex from a holder that had died holding it (robust mutexes) */
    pthread_mutex_t m;
    pthread_cond_t c;
    int64_t q_origin[QDEPTH], q_time[QDEPTH];
    uint8_t reserved[RES_BYTES - 184 - 2 * QDEPTH * 8];
};

_Static_assert(sizeof(struct event_stats) == EV_HDR, "event stats size");
_Static_assert(sizeof(struct phase_stats) == PHASE_BYTES, "phase stats size");
_Static_assert(sizeof(struct resource) == RES_BYTES, "resource size");

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

struct group;

struct slot {
    struct group *group;
    int index;
    char name[16];
    struct work work;
    struct settings own;
    int explicit_defaults;
    struct slot_header *hdr;
    uint64_t *hist;      /* HIST_SETS * HIST_BUCKETS counters, NULL when the group keeps none */
    char *ring;                 /* capacity samples of group->sample_size bytes */
    struct program *prog;       /* kind: phases, else NULL */
    struct program_state *pstate;
    char *evbase;               /* event stats, prog->nevents + 1 of them (the last: chain latency) */
    char *phbase;               /* phase stats */
    uint64_t capacity;
    size_t stride;
    pthread_t thread;
    int started;
    int deferred;        /* created by a spawn event of another thread, not at setup */
    int after;           /* the slot whose thread must have begun its work before this one begins (start: in_order); -1: none */
    _Atomic int follower; /* another slot begins after this one: wake it when this one begins */
    _Atomic int claimed; /* a spawn event took this instance (set on a template's first instance: the next to take) */
};

struct group {
    char *base;
    Py_ssize_t size;
    uint32_t nslots;
    uint32_t capacity;
    int with_hist;
    size_t stride;
    struct slot *slots;
    cpu_set_t all_cpus;
    long page_size;
    uint32_t nstats, nphases;   /* event and phase stats per slot */
    uint32_t lock_slots;        /* struct lock_wait after each sample */
    size_t sample_size;         /* sizeof(struct sample) + lock_slots * sizeof(struct lock_wait) */
    char *res;                  /* the shared resources segment, NULL if none */
    Py_ssize_t nres;
};

/* The start gate, in the shared file header: a futex word the runner opens (or cancels) for every thread of the
 * process at once, with the run's start and end written before it.  Threads wait on it themselves, each at its
 * own policy, so a thread at an RT priority is released at once, never behind a control thread that has to
 * share the CPUs with the background load first. */
static inline _Atomic uint32_t *gate_word(const char *base) { return (_Atomic uint32_t *)(base + GATE_AT); }

/* The run's start and end: written before the gate opened and never after, so read without a lock. */
static inline int64_t run_start(const struct group *g) { return *(const int64_t *)(g->base + GATE_AT + 8); }
static inline int64_t run_end(const struct group *g) { return *(const int64_t *)(g->base + GATE_AT + 16); }

/* Open a shut gate at `start`, to close at `end`; false if it was opened or cancelled already.  One opener (the
 * runner, or a test's own process): the times are written before the state that publishes them, and a cancel
 * that wins the race leaves them unread. */
static int gate_open(char *base, int64_t start, int64_t end) {
    if (atomic_load_explicit(gate_word(base), memory_order_acquire) != GATE_SHUT) return 0;
    memcpy(base + GATE_AT + 8, &start, sizeof(start));
    memcpy(base + GATE_AT + 16, &end, sizeof(end));
    uint32_t shut = GATE_SHUT;
    if (!atomic_compare_exchange_strong_explicit(gate_word(base), &shut, GATE_OPEN, memory_order_acq_rel, memory_order_acquire)) return 0;
    syscall(SYS_futex, gate_word(base), FUTEX_WAKE, INT32_MAX, NULL, NULL, 0);
    return 1;
}

/* Cancel a shut gate: its threads leave without working.  False if it was open already. */
static int gate_cancel(char *base) {
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
        h->missed += (uint64_t)missed;
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
    s->hdr->missed += (uint64_t)missed;
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

static int create_thread(struct group *g, struct slot *s);

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
        if (t->period > 0 && t->due > 0 && t->due < until) s->hdr->missed += (uint64_t)((until - 1 - t->due) / t->period + 1);
    }
    if (ps->timer_key >= 0) s->hdr->timer_due_ns = ps->timers[ps->timer_key].due;
    activation_close(s, ps, end, own_next(ps));
    chain_close(s, ps, end);
    while (ps->nheld > 0) unlock_mutex(s, ps, ps->held[ps->nheld - 1]);
}

/* Before the thread reports ready: its private state, the mem buffer faulted in, stats cleared. */
static struct program_state *program_prepare(struct slot *s) {
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

static void program_release(struct program_state *ps) {
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
static void run_slot(struct slot *s) {
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
static void prefault_slot(struct slot *s) {
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
static int create_thread(struct group *g, struct slot *s) {
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
static void join_all(struct group *g) {
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

/* ------------------------------------------------------------ Group object */

typedef struct {
    PyObject_HEAD
    struct group g;
    Py_buffer view;
    int has_view;
    Py_buffer res_view;
    int has_res;
} GroupObject;

static void Group_dealloc(GroupObject *self) {
    if (self->g.slots) {
        gate_cancel(self->g.base); /* never opened: parked threads leave */
        Py_BEGIN_ALLOW_THREADS
        join_all(&self->g);
        Py_END_ALLOW_THREADS
        for (uint32_t i = 0; i < self->g.nslots; i++) {
            program_release(self->g.slots[i].pstate);
            PyMem_Free(self->g.slots[i].prog);
        }
        PyMem_Free(self->g.slots);
    }
    if (self->has_view) PyBuffer_Release(&self->view);
    if (self->has_res) PyBuffer_Release(&self->res_view);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Group_init(GroupObject *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"buffer", "nthreads", "capacity", "all_cpus", "histograms", "events", "phases", "resources", "locks", NULL};
    PyObject *buffer, *all_cpus, *resources = Py_None;
    unsigned int nthreads, capacity, nstats = 0, nphases = 0, locks = 0;
    int with_hist = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OIIO|pIIOI", kwlist, &buffer, &nthreads, &capacity, &all_cpus, &with_hist, &nstats,
                                     &nphases, &resources, &locks))
        return -1;
    if (nstats > MAX_EVENTS + 1 || nphases > MAX_PHASES || locks > MAX_LOCK_SLOTS) {
        PyErr_Format(PyExc_ValueError, "at most %d events, %d phases and %d lock slots per thread", MAX_EVENTS, MAX_PHASES, MAX_LOCK_SLOTS);
        return -1;
    }
    if (PyObject_GetBuffer(buffer, &self->view, PyBUF_WRITABLE) != 0) return -1;
    self->has_view = 1;
    if (resources != Py_None) {
        if (PyObject_GetBuffer(resources, &self->res_view, PyBUF_WRITABLE) != 0) return -1;
        self->has_res = 1;
    }
    size_t sample_size = sizeof(struct sample) + locks * sizeof(struct lock_wait);
    size_t ring_bytes = (size_t)capacity * sample_size;
    size_t stat_bytes = (size_t)nstats * (EV_HDR + HIST_BUCKETS * sizeof(uint64_t)) + (size_t)nphases * PHASE_BYTES;
    size_t stride = SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0) + ring_bytes + stat_bytes;
    Py_ssize_t need = FILE_HEADER + (Py_ssize_t)nthreads * (Py_ssize_t)stride;
    if (self->view.len < need) {
        PyErr_Format(PyExc_ValueError, "buffer holds %zd bytes, %zd needed", self->view.len, need);
        return -1;
    }
    struct group *g = &self->g;
    memset(g, 0, sizeof(*g));
    g->base = self->view.buf;
    g->size = self->view.len;
    g->nslots = nthreads;
    g->capacity = capacity;
    g->with_hist = with_hist;
    g->stride = stride;
    g->nstats = nstats;
    g->nphases = nphases;
    g->lock_slots = locks;
    g->sample_size = sample_size;
    g->res = self->has_res ? self->res_view.buf : NULL;
    g->nres = self->has_res ? self->res_view.len / RES_BYTES : 0;
    g->page_size = sysconf(_SC_PAGESIZE);
    CPU_ZERO(&g->all_cpus);
    PyObject *seq = PySequence_Fast(all_cpus, "all_cpus must be a sequence");
    if (!seq) return -1;
    for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(seq); i++)
        CPU_SET((int)PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i)), &g->all_cpus);
    Py_DECREF(seq);
    g->slots = PyMem_Calloc(nthreads ? nthreads : 1, sizeof(struct slot));
    if (!g->slots) {
        PyErr_NoMemory();
        return -1;
    }
    memcpy(g->base, "RSMP0007", 8);
    uint32_t meta[6] = {7, nthreads, capacity, SLOT_HEADER, (uint32_t)sample_size, with_hist ? HIST_BUCKETS : 0};
    memcpy(g->base + 8, meta, sizeof(meta));
    uint64_t stride64 = g->stride;
    memcpy(g->base + 32, &stride64, sizeof(stride64));
    uint32_t meta2[2] = {nstats, nphases};
    memcpy(g->base + 40, meta2, sizeof(meta2));
    for (uint32_t i = 0; i < nthreads; i++) {
        struct slot *s = &g->slots[i];
        char *at = g->base + FILE_HEADER + (size_t)i * g->stride;
        s->group = g;
        s->index = (int)i;
        s->after = -1;
        s->hdr = (struct slot_header *)at;
        s->hist = with_hist ? (uint64_t *)(at + SLOT_HEADER) : NULL;
        s->ring = at + SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0);
        s->capacity = capacity;
        s->evbase = s->ring + ring_bytes;
        s->phbase = s->evbase + (size_t)nstats * (EV_HDR + HIST_BUCKETS * sizeof(uint64_t));
        s->stride = g->stride;
        memset(s->hdr, 0, SLOT_HEADER);
        s->hdr->minflt_first = -1;
    }
    return 0;
}

/* Parse a program: (gid, delay_ns, loop, mem_bytes, phases, events); phases are
 * (loop, first, nevents, settings or None), settings (policy, priority, nice, cpus, extra),
 * events (type, res, res2, mode, arg).  Indexes are checked against the group's sizes. */
static struct program *parse_program(const struct group *g, PyObject *spec) {
    long long gid, delay, loop, mem;
    PyObject *phases, *events;
    if (!PyArg_ParseTuple(spec, "LLLLOO", &gid, &delay, &loop, &mem, &phases, &events)) return NULL;
    PyObject *ph = PySequence_Fast(phases, "phases must be a sequence");
    if (!ph) return NULL;
    PyObject *ev = PySequence_Fast(events, "events must be a sequence");
    if (!ev) {
        Py_DECREF(ph);
        return NULL;
    }
    struct program *p = PyMem_Calloc(1, sizeof(struct program));
    Py_ssize_t np = PySequence_Fast_GET_SIZE(ph), ne = PySequence_Fast_GET_SIZE(ev);
    if (!p) {
        PyErr_NoMemory();
        goto fail;
    }
    if (np < 1 || np > (Py_ssize_t)g->nphases || ne + 1 > (Py_ssize_t)g->nstats) {
        PyErr_Format(PyExc_ValueError, "program of %zd phases and %zd events does not fit the group (%u phases, %u event stats)", np, ne,
                     g->nphases, g->nstats);
        goto fail;
    }
    p->gid = (int32_t)gid;
    p->delay_ns = delay;
    p->loop = loop;
    p->mem_bytes = mem;
    p->nphases = (int)np;
    p->nevents = (int)ne;
    for (Py_ssize_t i = 0; i < ne; i++) {
        struct event *e = &p->events[i];
        long long arg;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(ev, i), "iiiiL", &e->type, &e->res, &e->res2, &e->mode, &arg)) goto fail;
        e->arg = arg;
        int needs = e->type == EV_LOCK || e->type == EV_UNLOCK || e->type == EV_WAIT || e->type == EV_SIGNAL || e->type == EV_BROADCAST ||
                    e->type == EV_BARRIER || e->type == EV_SUSPEND || e->type == EV_RESUME;
        if ((needs && (e->res < 0 || e->res >= g->nres)) || (e->type == EV_WAIT && (e->res2 < 0 || e->res2 >= g->nres)) ||
            (e->type == EV_LOCK && (e->res2 < -1 || e->res2 >= (int)g->lock_slots)) ||
            (e->type == EV_TIMER && e->arg <= 0) ||
            (e->type == EV_SPAWN && (e->res < 0 || e->arg < 1 || e->res + e->arg > (long long)g->nslots)) || e->type < EV_RUN ||
            e->type > EV_IORUN || (e->type == EV_IORUN && mem < 1)) {
            PyErr_Format(PyExc_ValueError, "event %zd (type %d) names resource %d of %zd or lock slot %d of %u, or has no period", i, e->type,
                         e->res, g->nres, e->res2, g->lock_slots);
            goto fail;
        }
        /* A timer's state is the first event naming the same timer: a named one by name, and the thread's
         * private timers as one (rt-app's `unique` timer: its grid advances by each event's own period). */
        e->key = (int)i;
        if (e->type == EV_TIMER) {
            for (Py_ssize_t k = 0; k < i; k++)
                if (p->events[k].type == EV_TIMER && p->events[k].res == e->res) {
                    e->key = (int)k;
                    break;
                }
        }
    }
    int timers = 0, suspends = 0;
    for (Py_ssize_t i = 0; i < ne; i++) {
        timers += p->events[i].type == EV_TIMER;
        suspends += p->events[i].type == EV_SUSPEND;
    }
    p->released = timers == 0 && suspends > 0;
    for (Py_ssize_t i = 0; i < np; i++) {
        struct phase *f = &p->phases[i];
        long long floop;
        PyObject *set;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(ph, i), "LiiO", &floop, &f->first, &f->nevents, &set)) goto fail;
        f->loop = floop;
        if (f->first < 0 || f->nevents < 0 || f->first + f->nevents > p->nevents) {
            PyErr_Format(PyExc_ValueError, "phase %zd has events outside the program", i);
            goto fail;
        }
        if (set != Py_None) {
            PyObject *policy, *priority, *nice, *cpus, *extra;
            if (!PyArg_ParseTuple(set, "OOOOO", &policy, &priority, &nice, &cpus, &extra)) goto fail;
            if (parse_settings(policy, priority, nice, cpus, extra, &f->set)) goto fail;
            f->has_settings = 1;
        }
    }
    Py_DECREF(ph);
    Py_DECREF(ev);
    return p;
fail:
    PyMem_Free(p);
    Py_DECREF(ph);
    Py_DECREF(ev);
    return NULL;
}

static int parse_work(const struct group *g, struct slot *s, PyObject *work) {
    struct work *out = &s->work;
    memset(out, 0, sizeof(*out));
    long long kind, period, burn_ns, alloc, offset, bound = 0;
    int wall, spin = 0, ring = RING_ALL;
    PyObject *program = Py_None;
    if (!PyArg_ParseTuple(work, "LLLpLL|pLiO", &kind, &period, &burn_ns, &wall, &alloc, &offset, &spin, &bound, &ring, &program)) return -1;
    out->wait_spin = spin;
    out->bound_ns = bound;
    out->ring_mode = ring;
    out->kind = (int)kind;
    out->period_ns = period;
    out->burn_ns = burn_ns;
    out->burn_wall = wall;
    out->alloc_bytes = alloc;
    out->offset_ns = offset;
    if (out->kind == WORK_PERIODIC && out->period_ns <= 0) {
        PyErr_SetString(PyExc_ValueError, "periodic work needs a positive period");
        return -1;
    }
    PyMem_Free(s->prog);
    s->prog = NULL;
    if (out->kind == WORK_PROGRAM) {
        if (program == Py_None) {
            PyErr_SetString(PyExc_ValueError, "program work needs a program");
            return -1;
        }
        if (!(s->prog = parse_program(g, program))) return -1;
    }
    return 0;
}

static struct slot *get_slot(GroupObject *self, unsigned int index) {
    if (index >= self->g.nslots) {
        PyErr_Format(PyExc_IndexError, "slot %u out of range (%u slots)", index, self->g.nslots);
        return NULL;
    }
    return &self->g.slots[index];
}

PyDoc_STRVAR(spawn_doc,
"spawn(index, name, work, policy, priority, nice, cpus, explicit[, extra[, deferred[, after]]])\n\n"
"Create a thread from the calling thread (so it inherits the caller's settings\n"
"unless explicit is true), name it, let it apply its own settings, and park it\n"
"at the start gate.  work is (kind, period_ns, burn_ns, burn_wall, alloc_bytes,\n"
"offset_ns[, wait_spin, bound_ns, ring_mode, program]); extra is (dl_runtime,\n"
"dl_deadline, dl_period, util_min, util_max).  Returns when the thread is created;\n"
"see wait_ready().  deferred: only prepare the slot; a spawn event of another\n"
"thread's program creates the thread mid-run (rt-app's fork).  after: a slot\n"
"created before this one whose thread must have begun its work (after the start)\n"
"before this one begins; -1 (default): none, it begins at the common start.");

static PyObject *Group_spawn(GroupObject *self, PyObject *args) {
    unsigned int index;
    const char *name;
    PyObject *work, *policy, *priority, *nice, *cpus, *extra = Py_None;
    int explicit_defaults, deferred = 0, after = -1;
    if (!PyArg_ParseTuple(args, "IsOOOOOp|Opi", &index, &name, &work, &policy, &priority, &nice, &cpus, &explicit_defaults, &extra,
                          &deferred, &after))
        return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    if (s->started) {
        PyErr_Format(PyExc_ValueError, "slot %u already has a thread", index);
        return NULL;
    }
    if (after >= (int)index || after < -1 || (after >= 0 && (deferred || self->g.slots[after].deferred))) {
        PyErr_Format(PyExc_ValueError, "slot %u cannot begin after slot %d: only after a slot before it, neither spawned mid-run", index,
                     after);
        return NULL;
    }
    s->after = after;
    if (after >= 0) atomic_store(&self->g.slots[after].follower, 1);
    if (parse_work(&self->g, s, work) || parse_settings(policy, priority, nice, cpus, extra, &s->own)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->explicit_defaults = explicit_defaults;
    s->deferred = deferred;
    if (deferred) {
        if (s->work.kind != WORK_PROGRAM) {
            PyErr_SetString(PyExc_ValueError, "only a program (kind: phases) can be spawned");
            return NULL;
        }
        Py_RETURN_NONE;
    }
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = create_thread(&self->g, s);
    Py_END_ALLOW_THREADS
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(adopt_doc,
"adopt(index, name, work)\n\nMake the calling thread (the main thread) slot index: record its TID;\n"
"run_main() later runs its work.");

static PyObject *Group_adopt(GroupObject *self, PyObject *args) {
    unsigned int index;
    const char *name;
    PyObject *work;
    if (!PyArg_ParseTuple(args, "IsO", &index, &name, &work)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s || parse_work(&self->g, s, work)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->hdr->tid = (int32_t)syscall(SYS_gettid);
    s->own.policy = -1;
    prefault_slot(s);
    if (s->prog && !(s->pstate = program_prepare(s))) s->hdr->err_other = ENOMEM;
    atomic_store((_Atomic int32_t *)&s->hdr->state, ST_READY);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(wait_ready_doc, "wait_ready(timeout_s) -> bool\n\nWait, without the GIL, until every spawned thread is parked at the gate.");

static PyObject *Group_wait_ready(GroupObject *self, PyObject *args) {
    double timeout;
    if (!PyArg_ParseTuple(args, "d", &timeout)) return NULL;
    int ok = 0;
    Py_BEGIN_ALLOW_THREADS
    int64_t until = now_ns(CLOCK_MONOTONIC) + (int64_t)(timeout * 1e9);
    for (;;) {
        ok = 1;
        for (uint32_t i = 0; i < self->g.nslots; i++) {
            struct slot *s = &self->g.slots[i];
            if (s->started && atomic_load((_Atomic int32_t *)&s->hdr->state) < ST_READY) ok = 0;
        }
        if (ok || now_ns(CLOCK_MONOTONIC) > until) break;
        struct timespec ts = {0, 200000};
        nanosleep(&ts, NULL);
    }
    Py_END_ALLOW_THREADS
    return PyBool_FromLong(ok);
}

PyDoc_STRVAR(release_doc, "release(start_ns, end_ns) -> bool\n\nOpen the gate from this process (as open_gate does from the runner): every thread starts its work at start_ns (CLOCK_MONOTONIC) and stops at end_ns.  False if it was open or cancelled already.");

static PyObject *Group_release(GroupObject *self, PyObject *args) {
    long long start, end;
    if (!PyArg_ParseTuple(args, "LL", &start, &end)) return NULL;
    return PyBool_FromLong(gate_open(self->g.base, start, end));
}

PyDoc_STRVAR(run_main_doc, "run_main(index) -> bool\n\nRun the adopted main thread's work in the calling thread, GIL released, once the gate opens.  False if the gate was cancelled instead: nothing ran.");

static PyObject *Group_run_main(GroupObject *self, PyObject *args) {
    unsigned int index;
    if (!PyArg_ParseTuple(args, "I", &index)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    Py_BEGIN_ALLOW_THREADS
    run_slot(s);
    Py_END_ALLOW_THREADS
    program_release(s->pstate);
    s->pstate = NULL;
    return PyBool_FromLong(atomic_load(gate_word(self->g.base)) == GATE_OPEN);
}

PyDoc_STRVAR(join_doc, "join()\n\nJoin every thread, those spawned mid-run too, GIL released.");

static PyObject *Group_join(GroupObject *self, PyObject *Py_UNUSED(ignored)) {
    Py_BEGIN_ALLOW_THREADS
    join_all(&self->g);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyDoc_STRVAR(errors_doc, "errors(index) -> (tid, err_sched, err_nice, err_cpus, err_other)");

static PyObject *Group_errors(GroupObject *self, PyObject *args) {
    unsigned int index;
    if (!PyArg_ParseTuple(args, "I", &index)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    return Py_BuildValue("(iiiii)", s->hdr->tid, s->hdr->err_sched, s->hdr->err_nice, s->hdr->err_cpus, s->hdr->err_other);
}

static PyMethodDef Group_methods[] = {
    {"spawn", (PyCFunction)Group_spawn, METH_VARARGS, spawn_doc},
    {"adopt", (PyCFunction)Group_adopt, METH_VARARGS, adopt_doc},
    {"wait_ready", (PyCFunction)Group_wait_ready, METH_VARARGS, wait_ready_doc},
    {"release", (PyCFunction)Group_release, METH_VARARGS, release_doc},
    {"run_main", (PyCFunction)Group_run_main, METH_VARARGS, run_main_doc},
    {"join", (PyCFunction)Group_join, METH_NOARGS, join_doc},
    {"errors", (PyCFunction)Group_errors, METH_VARARGS, errors_doc},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject GroupType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "runner.run._probe.Group",
    .tp_doc = PyDoc_STR("Group(buffer, nthreads, capacity, all_cpus): the measured threads of one process."),
    .tp_basicsize = sizeof(GroupObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Group_init,
    .tp_dealloc = (destructor)Group_dealloc,
    .tp_methods = Group_methods,
};

/* ----------------------------------------------------------- module functions */

static PyObject *probe_apply(PyObject *mod, PyObject *args) {
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(args, "OOOO|O", &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    int32_t errs[3];
    apply_settings(&s, errs);
    return Py_BuildValue("(iii)", errs[0], errs[1], errs[2]);
}

PyDoc_STRVAR(buckets_doc,
"buckets(buffer, offset, negated=False, first=0, last=HIST_BUCKETS-1) -> [(low, high, count), ...]\n\n"
"The rows of the histogram of HIST_BUCKETS native uint64 counters at `offset` of `buffer`: the buckets\n"
"that are not zero with the values each holds, ascending (histogram.from_rows, read in place: a cell of\n"
"1,024 threads holds 4,096 histograms of 4,352 counters).  `negated`: the counters are of the negation\n"
"of the values, so the rows are (-high, -low, count), still ascending.  Only counters first..last are\n"
"looked at (the buckets of a finished thread's exact minimum and maximum: the rest are zero).");

static PyObject *bucket_row(int i, int negated, uint64_t count) {
    int64_t low, high;
    hist_bounds(i, &low, &high);
    return Py_BuildValue("(LLK)", (long long)(negated ? -high : low), (long long)(negated ? -low : high), (unsigned long long)count);
}

static PyObject *probe_buckets(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    Py_ssize_t offset;
    int negated = 0, first = 0, last = HIST_BUCKETS - 1;
    if (!PyArg_ParseTuple(args, "On|pii", &buffer, &offset, &negated, &first, &last)) return NULL;
    if (first < 0 || last >= HIST_BUCKETS || first > last + 1) {
        PyErr_Format(PyExc_ValueError, "counters %d..%d are not within 0..%d", first, last, HIST_BUCKETS - 1);
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(buffer, &view, PyBUF_SIMPLE) != 0) return NULL;
    PyObject *out = NULL;
    if (offset < 0 || offset > view.len - (Py_ssize_t)HIST_BUCKETS * 8) {
        PyErr_Format(PyExc_ValueError, "a histogram at %zd does not fit a buffer of %zd bytes", offset, view.len);
        goto done;
    }
    if (!(out = PyList_New(0))) goto done;
    const char *at = (const char *)view.buf + offset;
    for (int k = 0; k <= last - first; k++) {
        int i = negated ? last - k : first + k;
        uint64_t v;
        memcpy(&v, at + (Py_ssize_t)i * 8, 8);
        if (!v) continue;
        PyObject *row = bucket_row(i, negated, v);
        if (!row || PyList_Append(out, row) < 0) {
            Py_XDECREF(row);
            Py_CLEAR(out);
            goto done;
        }
        Py_DECREF(row);
    }
done:
    PyBuffer_Release(&view);
    return out;
}

PyDoc_STRVAR(init_resources_doc,
"init_resources(buffer, specs)\n\n"
"Initialise the shared resources segment: specs is a sequence of (kind, protocol, parties, period_ns),\n"
"one per RES_BYTES record.  Mutexes, conditions and their internal locks are process-shared;\n"
"protocol 1 makes a mutex priority-inheriting, QUEUE_DROP a queue drop the resumes no thread waits for (rt-app's);\n"
"conditions wait on CLOCK_MONOTONIC.");

static PyObject *probe_init_resources(PyObject *mod, PyObject *args) {
    PyObject *buffer, *specs;
    if (!PyArg_ParseTuple(args, "OO", &buffer, &specs)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(buffer, &view, PyBUF_WRITABLE) != 0) return NULL;
    PyObject *seq = PySequence_Fast(specs, "specs must be a sequence");
    if (!seq) {
        PyBuffer_Release(&view);
        return NULL;
    }
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    int rc = 0;
    if (view.len < n * RES_BYTES) {
        PyErr_Format(PyExc_ValueError, "resources segment holds %zd bytes, %zd needed", view.len, n * RES_BYTES);
        goto done;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        struct resource *r = (struct resource *)((char *)view.buf + i * RES_BYTES);
        int kind, protocol, parties;
        long long period;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "iiiL", &kind, &protocol, &parties, &period)) goto done;
        memset(r, 0, RES_BYTES);
        r->kind = kind;
        r->protocol = protocol;
        r->parties = parties;
        r->period = period;
        r->owner = -1;
        pthread_mutexattr_t ma;
        pthread_mutexattr_init(&ma);
        pthread_mutexattr_setpshared(&ma, PTHREAD_PROCESS_SHARED);
        /* A worker that dies holding it (killed, crashed) must not leave its peers blocked on it for good. */
        pthread_mutexattr_setrobust(&ma, PTHREAD_MUTEX_ROBUST);
        if (kind != RES_MUTEX || protocol == 1) rc = pthread_mutexattr_setprotocol(&ma, PTHREAD_PRIO_INHERIT);
        if (!rc) rc = pthread_mutex_init(&r->m, &ma);
        pthread_mutexattr_destroy(&ma);
        pthread_condattr_t ca;
        pthread_condattr_init(&ca);
        pthread_condattr_setpshared(&ca, PTHREAD_PROCESS_SHARED);
        pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
        if (!rc) rc = pthread_cond_init(&r->c, &ca);
        pthread_condattr_destroy(&ca);
        if (rc) {
            errno = rc;
            PyErr_SetFromErrno(PyExc_OSError);
            goto done;
        }
    }
done:
    Py_DECREF(seq);
    PyBuffer_Release(&view);
    if (PyErr_Occurred()) return NULL;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(getattr_doc,
"sched_getattr(tid) -> (policy, flags, nice, priority, runtime_ns, deadline_ns, period_ns, util_min, util_max)\n\n"
"A thread's scheduling attributes as the kernel holds them (sched_getattr(2)), SCHED_DEADLINE's included.");

static PyObject *probe_sched_getattr(PyObject *mod, PyObject *args) {
    int tid;
    if (!PyArg_ParseTuple(args, "i", &tid)) return NULL;
    struct sched_attr_k a;
    memset(&a, 0, sizeof(a));
    if (syscall(SYS_sched_getattr, tid, &a, sizeof(a), 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    return Py_BuildValue("(iKiiKKKII)", (int)a.sched_policy, (unsigned long long)a.sched_flags, a.sched_nice, (int)a.sched_priority,
                         (unsigned long long)a.sched_runtime, (unsigned long long)a.sched_deadline, (unsigned long long)a.sched_period,
                         a.sched_util_min, a.sched_util_max);
}

static PyObject *probe_set_name(PyObject *mod, PyObject *args) {
    const char *name;
    if (!PyArg_ParseTuple(args, "s", &name)) return NULL;
    if (prctl(PR_SET_NAME, name, 0, 0, 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    Py_RETURN_NONE;
}

static PyObject *probe_lock_memory(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    /* As the ros2-realtime-examples: keep freed heap mapped and locked, never mmap a block. */
    if (mallopt(M_TRIM_THRESHOLD, -1) == 0 || mallopt(M_MMAP_MAX, 0) == 0) {
        munlockall();
        PyErr_SetString(PyExc_OSError, "mallopt failed");
        return NULL;
    }
    Py_RETURN_NONE;
}

static PyObject *probe_preallocate(PyObject *mod, PyObject *args) {
    long long bytes;
    if (!PyArg_ParseTuple(args, "L", &bytes)) return NULL;
    long page = sysconf(_SC_PAGESIZE);
    void *buf = NULL;
    int rc = posix_memalign(&buf, (size_t)page, (size_t)bytes);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    for (long long off = 0; off < bytes; off += page) ((volatile char *)buf)[off] = 0;
    free(buf);
    Py_RETURN_NONE;
}

static PyObject *probe_set_default_stacksize(PyObject *mod, PyObject *args) {
    long long bytes;
    if (!PyArg_ParseTuple(args, "L", &bytes)) return NULL;
    pthread_attr_t attr;
    int rc = pthread_getattr_default_np(&attr);
    if (!rc) rc = pthread_attr_setstacksize(&attr, (size_t)bytes);
    if (!rc) rc = pthread_setattr_default_np(&attr);
    pthread_attr_destroy(&attr);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    Py_RETURN_NONE;
}

static PyObject *probe_install_stop_handler(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    if (g_stop_pipe[0] < 0 && pipe2(g_stop_pipe, O_CLOEXEC | O_NONBLOCK) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    struct sigaction sa;
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    Py_RETURN_NONE;
}

static PyObject *probe_set_pdeathsig(PyObject *mod, PyObject *args) {
    int sig;
    if (!PyArg_ParseTuple(args, "i", &sig)) return NULL;
    if (prctl(PR_SET_PDEATHSIG, sig, 0, 0, 0) != 0) return PyErr_SetFromErrno(PyExc_OSError);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(apply_to_doc,
"apply_to(tid, policy, priority, nice, cpus[, extra]) -> (err_sched, err_nice, err_cpus)\n\n"
"Apply settings to another thread (a program's thread a rule matched), as apply() does to the caller.");

static PyObject *probe_apply_to(PyObject *mod, PyObject *args) {
    int tid;
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(args, "iOOOO|O", &tid, &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    int32_t errs[3];
    Py_BEGIN_ALLOW_THREADS
    apply_settings_to(tid, &s, 0, errs);
    Py_END_ALLOW_THREADS
    return Py_BuildValue("(iii)", errs[0], errs[1], errs[2]);
}

/* Stages a program's start reports on its report pipe, each as (stage, errno). */
#define STAGE_CWD 1
#define STAGE_EXEC 2

static char **byte_strings(PyObject *seq_in, const char *what) {
    PyObject *seq = PySequence_Fast(seq_in, what);
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    char **out = PyMem_Calloc((size_t)n + 1, sizeof(char *));
    if (!out) {
        Py_DECREF(seq);
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PySequence_Fast_GET_ITEM(seq, i);
        if (!PyBytes_Check(item)) {
            PyErr_Format(PyExc_TypeError, "%s: item %zd is not bytes", what, i);
            goto fail;
        }
        const char *text = PyBytes_AS_STRING(item);
        out[i] = PyMem_Malloc((size_t)PyBytes_GET_SIZE(item) + 1);
        if (!out[i]) {
            PyErr_NoMemory();
            goto fail;
        }
        memcpy(out[i], text, (size_t)PyBytes_GET_SIZE(item) + 1);
    }
    Py_DECREF(seq);
    return out;
fail:
    for (Py_ssize_t i = 0; i < n; i++) PyMem_Free(out[i]);
    PyMem_Free(out);
    Py_DECREF(seq);
    return NULL;
}

static void free_strings(char **v) {
    if (!v) return;
    for (char **p = v; *p; p++) PyMem_Free(*p);
    PyMem_Free(v);
}

/* Close every descriptor from 3 up but `keep`: close_range(2) where the kernel has it, one by one where not. */
static void close_others(int keep, long maxfd) {
#ifdef SYS_close_range
    if ((keep <= 3 || syscall(SYS_close_range, 3U, (unsigned)keep - 1, 0U) == 0) && syscall(SYS_close_range, (unsigned)keep + 1, ~0U, 0U) == 0) return;
#endif
    for (int fd = 3; fd < maxfd; fd++) {
        if (fd != keep) close(fd);
    }
}

/* Close every descriptor from 3 up but the `n` in `keep` (at most 8): between fork and exec, so that a child
 * holds no end of another pipe of the runner's (the write end of its own gate, or of another program's). */
static void close_all_but(const int *keep, int n, long maxfd) {
    int k[8], m = 0;
    for (int i = 0; i < n && m < 8; i++) {
        if (keep[i] < 3) continue;
        int j = m++;
        while (j > 0 && k[j - 1] > keep[i]) {
            k[j] = k[j - 1];
            j--;
        }
        k[j] = keep[i];
    }
    int from = 3;
    for (int i = 0; i <= m; i++) {
        int to = i < m ? k[i] - 1 : -1; /* -1: to the last descriptor */
        if (to < 0 || to >= from) {
#ifdef SYS_close_range
            if (syscall(SYS_close_range, (unsigned)from, to < 0 ? ~0U : (unsigned)to, 0U) != 0)
#endif
                for (long fd = from; fd < (to < 0 ? maxfd : to + 1); fd++) close((int)fd);
        }
        if (i < m) from = k[i] + 1;
    }
}

static void write_all(int fd, const void *buf, size_t len) {
    const char *p = buf;
    while (len) {
        ssize_t w = write(fd, p, len);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return;
        p += w;
        len -= (size_t)w;
    }
}

PyDoc_STRVAR(spawn_program_doc,
"spawn_program(path, argv, envp, cwd, settings, reset_on_fork, out_fd, err_fd) -> (pid, report_fd, gate_fd)\n\n"
"Fork a child that leads its own process group, dies with the runner (PR_SET_PDEATHSIG), applies\n"
"`settings` (policy, priority, nice, cpus, extra) to itself, writes their three errnos to report_fd,\n"
"then waits for a byte on gate_fd before it execs `path` (bytes; argv and envp lists of bytes; cwd\n"
"bytes or None) with stdin from /dev/null and stdout/stderr on the given fds.  A failed chdir or exec\n"
"writes (stage, errno) to report_fd and exits 127; report_fd reaches end of file at a successful exec.\n"
"Closing gate_fd without a byte makes the child exit 0 without exec.  Only async-signal-safe calls\n"
"run between fork and exec: everything is built before the fork.");

static PyObject *probe_spawn_program(PyObject *mod, PyObject *args) {
    PyObject *path_o, *argv_o, *envp_o, *cwd_o, *settings_o;
    int reset_on_fork, out_fd, err_fd;
    if (!PyArg_ParseTuple(args, "SOOOOpii", &path_o, &argv_o, &envp_o, &cwd_o, &settings_o, &reset_on_fork, &out_fd, &err_fd)) return NULL;
    PyObject *policy, *priority, *nice, *cpus, *extra = Py_None;
    if (!PyArg_ParseTuple(settings_o, "OOOO|O", &policy, &priority, &nice, &cpus, &extra)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, extra, &s)) return NULL;
    if (cwd_o != Py_None && !PyBytes_Check(cwd_o)) return PyErr_Format(PyExc_TypeError, "cwd must be bytes or None");
    char **argv = byte_strings(argv_o, "argv");
    if (!argv) return NULL;
    char **envp = byte_strings(envp_o, "envp");
    if (!envp) {
        free_strings(argv);
        return NULL;
    }
    const char *path = PyBytes_AS_STRING(path_o);
    const char *cwd = cwd_o == Py_None ? NULL : PyBytes_AS_STRING(cwd_o);
    int report[2] = {-1, -1}, gate[2] = {-1, -1};
    int devnull = open("/dev/null", O_RDONLY | O_CLOEXEC);
    if (devnull < 0 || pipe2(report, O_CLOEXEC) != 0 || pipe2(gate, O_CLOEXEC) != 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        goto fail;
    }
    pid_t parent = getpid();
    long maxfd = sysconf(_SC_OPEN_MAX);
    if (maxfd < 0 || maxfd > 65536) maxfd = 65536;
    pid_t pid = fork();
    if (pid < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        goto fail;
    }
    if (pid == 0) {
        setpgid(0, 0);
        prctl(PR_SET_PDEATHSIG, SIGKILL, 0, 0, 0);
        if (getppid() != parent) _exit(0); /* the runner died before the line above */
        /* Its gate's write end, held here, would keep its read from ever seeing the runner close it. */
        const int keep[] = {report[1], gate[0], devnull, out_fd, err_fd};
        close_all_but(keep, 5, maxfd);
        struct sigaction dfl;
        memset(&dfl, 0, sizeof(dfl));
        dfl.sa_handler = SIG_DFL;
        for (int sig = 1; sig < NSIG; sig++) sigaction(sig, &dfl, NULL);
        sigset_t none;
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, NULL);
        int32_t errs[3];
        apply_settings_to(0, &s, reset_on_fork, errs);
        write_all(report[1], errs, sizeof(errs));
        char go;
        ssize_t got;
        do got = read(gate[0], &go, 1);
        while (got < 0 && errno == EINTR);
        if (got != 1) _exit(0); /* the runner gave up on the cell before the program's start */
        if (dup2(devnull, 0) < 0 || dup2(out_fd, 1) < 0 || dup2(err_fd, 2) < 0) {
            int32_t r[2] = {STAGE_EXEC, errno};
            write_all(report[1], r, sizeof(r));
            _exit(127);
        }
        close_others(report[1], maxfd);
        if (cwd && chdir(cwd) != 0) {
            int32_t r[2] = {STAGE_CWD, errno};
            write_all(report[1], r, sizeof(r));
            _exit(127);
        }
        execve(path, argv, envp);
        int32_t r[2] = {STAGE_EXEC, errno};
        write_all(report[1], r, sizeof(r));
        _exit(127);
    }
    close(report[1]);
    close(gate[0]);
    close(devnull);
    free_strings(argv);
    free_strings(envp);
    return Py_BuildValue("(iii)", (int)pid, report[0], gate[1]);
fail:
    for (int k = 0; k < 2; k++) {
        if (report[k] >= 0) close(report[k]);
        if (gate[k] >= 0) close(gate[k]);
    }
    if (devnull >= 0) close(devnull);
    free_strings(argv);
    free_strings(envp);
    return NULL;
}

static PyObject *probe_stopped(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    return PyBool_FromLong(g_stop);
}

/* The runner's side of a worker's start gate: its writable mapping of the buffer's file header. */
static char *gate_header(PyObject *buffer, Py_buffer *view) {
    if (PyObject_GetBuffer(buffer, view, PyBUF_WRITABLE) != 0) return NULL;
    if (view->len < FILE_HEADER) {
        PyErr_Format(PyExc_ValueError, "a buffer's header is %d bytes, this one %zd", FILE_HEADER, view->len);
        PyBuffer_Release(view);
        return NULL;
    }
    return view->buf;
}

PyDoc_STRVAR(open_gate_doc,
"open_gate(header, start_ns, end_ns) -> bool\n\n"
"Open a worker's start gate (header: a writable mapping of its buffer's first bytes): every thread waiting at it\n"
"is woken at once, at its own policy, to start at start_ns (CLOCK_MONOTONIC) and stop at end_ns.  False if the\n"
"gate was open or cancelled already.");

static PyObject *probe_open_gate(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    long long start, end;
    if (!PyArg_ParseTuple(args, "OLL", &buffer, &start, &end)) return NULL;
    Py_buffer view;
    char *base = gate_header(buffer, &view);
    if (!base) return NULL;
    int opened = gate_open(base, start, end);
    PyBuffer_Release(&view);
    return PyBool_FromLong(opened);
}

PyDoc_STRVAR(cancel_gate_doc,
"cancel_gate(header) -> bool\n\n"
"Cancel a worker's start gate that is still shut: its threads (and those that reach it later) leave without\n"
"working.  True if it is cancelled now, False if it had been opened.");

static PyObject *probe_cancel_gate(PyObject *mod, PyObject *args) {
    PyObject *buffer;
    if (!PyArg_ParseTuple(args, "O", &buffer)) return NULL;
    Py_buffer view;
    char *base = gate_header(buffer, &view);
    if (!base) return NULL;
    int cancelled = gate_cancel(base);
    PyBuffer_Release(&view);
    return PyBool_FromLong(cancelled);
}

/* ------------------------------------------------------------------ Watchdog */

/*
 * The runner's deadline, enforced from outside the measured threads: a native
 * thread, at the highest RT priority the runner may use, that needs no GIL and
 * so still runs when RT threads starve the runner's Python threads.  When the
 * deadline passes it SIGKILLs every registered process group.
 */
typedef struct {
    PyObject_HEAD
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int64_t deadline_ns;   /* 0: disarmed */
    Py_ssize_t npids;
    pid_t *pids;           /* every process group it kills at the deadline, however many (malloc'd; NULL: none) */
    int fired;
    int quit;
    int running;
    int rt_priority;       /* what the thread got; 0 if it stayed SCHED_OTHER */
} WatchdogObject;

static void *watchdog_main(void *arg) {
    WatchdogObject *w = arg;
    prctl(PR_SET_NAME, "runner-watchdog", 0, 0, 0);
    pthread_mutex_lock(&w->lock);
    while (!w->quit) {
        if (w->deadline_ns == 0) {
            pthread_cond_wait(&w->cond, &w->lock);
            continue;
        }
        struct timespec ts = to_ts(w->deadline_ns);
        int rc = pthread_cond_timedwait(&w->cond, &w->lock, &ts);
        if (rc == ETIMEDOUT && w->deadline_ns && now_ns(CLOCK_MONOTONIC) >= w->deadline_ns) {
            for (Py_ssize_t i = 0; i < w->npids; i++) kill(-w->pids[i], SIGKILL);
            for (Py_ssize_t i = 0; i < w->npids; i++) kill(w->pids[i], SIGKILL);
            w->fired = 1;
            w->deadline_ns = 0;
        }
    }
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

static int Watchdog_init(WatchdogObject *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"rt_priority", NULL};
    int prio = 99;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "|i", kwlist, &prio)) return -1;
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&self->cond, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&self->lock, NULL);
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, 64 * 1024);
    int rc = -1;
    if (prio > 0) {
        struct sched_param p = {.sched_priority = prio};
        pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
        pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
        pthread_attr_setschedparam(&attr, &p);
        rc = pthread_create(&self->thread, &attr, watchdog_main, self);
        if (rc == 0) self->rt_priority = prio;
    }
    if (rc != 0) { /* no right to RT: a plain thread still enforces the deadline, just less surely */
        pthread_attr_setinheritsched(&attr, PTHREAD_INHERIT_SCHED);
        rc = pthread_create(&self->thread, &attr, watchdog_main, self);
    }
    pthread_attr_destroy(&attr);
    if (rc) {
        errno = rc;
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    self->running = 1;
    return 0;
}

static PyObject *Watchdog_arm(WatchdogObject *self, PyObject *args) {
    long long deadline;
    PyObject *pids;
    if (!PyArg_ParseTuple(args, "LO", &deadline, &pids)) return NULL;
    PyObject *seq = PySequence_Fast(pids, "pids must be a sequence");
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    pid_t *list = PyMem_RawMalloc((size_t)(n ? n : 1) * sizeof(pid_t));
    if (!list) {
        Py_DECREF(seq);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        long pid = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (pid == -1 && PyErr_Occurred()) break;
        if (pid <= 0 || pid > INT_MAX) { /* kill(-0) or kill(-1) would signal far more than the cell */
            PyErr_Format(PyExc_ValueError, "pid %ld: expected a process id above 0", pid);
            break;
        }
        list[i] = (pid_t)pid;
    }
    Py_DECREF(seq);
    if (PyErr_Occurred()) {
        PyMem_RawFree(list);
        return NULL;
    }
    pthread_mutex_lock(&self->lock);
    pid_t *old = self->pids;
    self->pids = list;
    self->npids = n;
    self->deadline_ns = deadline;
    self->fired = 0;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
    PyMem_RawFree(old);
    Py_RETURN_NONE;
}

static PyObject *Watchdog_disarm(WatchdogObject *self, PyObject *Py_UNUSED(ignored)) {
    pthread_mutex_lock(&self->lock);
    self->deadline_ns = 0;
    self->npids = 0;
    pid_t *old = self->pids;
    self->pids = NULL;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
    PyMem_RawFree(old);
    Py_RETURN_NONE;
}

static PyObject *Watchdog_close(WatchdogObject *self, PyObject *Py_UNUSED(ignored)) {
    if (self->running) {
        pthread_mutex_lock(&self->lock);
        self->quit = 1;
        pthread_cond_broadcast(&self->cond);
        pthread_mutex_unlock(&self->lock);
        Py_BEGIN_ALLOW_THREADS
        pthread_join(self->thread, NULL);
        Py_END_ALLOW_THREADS
        self->running = 0;
    }
    Py_RETURN_NONE;
}

static PyObject *Watchdog_get_fired(WatchdogObject *self, void *closure) { return PyBool_FromLong(self->fired); }
static PyObject *Watchdog_get_prio(WatchdogObject *self, void *closure) { return PyLong_FromLong(self->rt_priority); }

static void Watchdog_dealloc(WatchdogObject *self) {
    PyObject *r = Watchdog_close(self, NULL);
    Py_XDECREF(r);
    PyMem_RawFree(self->pids);
    pthread_mutex_destroy(&self->lock);
    pthread_cond_destroy(&self->cond);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef Watchdog_methods[] = {
    {"arm", (PyCFunction)Watchdog_arm, METH_VARARGS, "arm(deadline_ns, pids): SIGKILL these process groups at deadline_ns (CLOCK_MONOTONIC)"},
    {"disarm", (PyCFunction)Watchdog_disarm, METH_NOARGS, "disarm(): forget the deadline"},
    {"close", (PyCFunction)Watchdog_close, METH_NOARGS, "close(): stop the watchdog thread"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Watchdog_getset[] = {
    {"fired", (getter)Watchdog_get_fired, NULL, "True once the deadline passed and the processes were killed", NULL},
    {"rt_priority", (getter)Watchdog_get_prio, NULL, "SCHED_FIFO priority of the watchdog thread, 0 if none", NULL},
    {NULL},
};

static PyTypeObject WatchdogType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "runner.run._probe.Watchdog",
    .tp_doc = PyDoc_STR("Watchdog(rt_priority=99): kills registered process groups when a deadline passes."),
    .tp_basicsize = sizeof(WatchdogObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Watchdog_init,
    .tp_dealloc = (destructor)Watchdog_dealloc,
    .tp_methods = Watchdog_methods,
    .tp_getset = Watchdog_getset,
};

static PyMethodDef module_methods[] = {
    {"apply", probe_apply, METH_VARARGS, "apply(policy, priority, nice, cpus[, extra]) -> (err_sched, err_nice, err_cpus) for the calling thread"},
    {"init_resources", probe_init_resources, METH_VARARGS, init_resources_doc},
    {"buckets", probe_buckets, METH_VARARGS, buckets_doc},
    {"sched_getattr", probe_sched_getattr, METH_VARARGS, getattr_doc},
    {"set_name", probe_set_name, METH_VARARGS, "set_name(name): prctl(PR_SET_NAME) on the calling thread"},
    {"lock_memory", probe_lock_memory, METH_NOARGS, "mlockall(MCL_CURRENT|MCL_FUTURE), no heap trimming, no mmap'd blocks"},
    {"preallocate", probe_preallocate, METH_VARARGS, "preallocate(bytes): grow the heap by bytes, fault it in, keep it"},
    {"set_default_stacksize", probe_set_default_stacksize, METH_VARARGS, "default stack size of threads created later"},
    {"install_stop_handler", probe_install_stop_handler, METH_NOARGS, "SIGTERM/SIGINT/SIGUSR1 stop every loop of this process"},
    {"set_pdeathsig", probe_set_pdeathsig, METH_VARARGS, "set_pdeathsig(sig): receive sig when the parent dies"},
    {"stopped", probe_stopped, METH_NOARGS, "True once a stop signal arrived"},
    {"open_gate", probe_open_gate, METH_VARARGS, open_gate_doc},
    {"cancel_gate", probe_cancel_gate, METH_VARARGS, cancel_gate_doc},
    {"apply_to", probe_apply_to, METH_VARARGS, apply_to_doc},
    {"spawn_program", probe_spawn_program, METH_VARARGS, spawn_program_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef probe_module = {
    PyModuleDef_HEAD_INIT, "runner.run._probe",
    "Native core of the runner: GIL-free measured threads and the deadline watchdog.", -1, module_methods,
};

PyMODINIT_FUNC PyInit__probe(void) {
    if (PyType_Ready(&GroupType) < 0 || PyType_Ready(&WatchdogType) < 0) return NULL;
    PyObject *m = PyModule_Create(&probe_module);
    if (!m) return NULL;
    Py_INCREF(&GroupType);
    PyModule_AddObject(m, "Group", (PyObject *)&GroupType);
    Py_INCREF(&WatchdogType);
    PyModule_AddObject(m, "Watchdog", (PyObject *)&WatchdogType);
    PyModule_AddIntConstant(m, "FILE_HEADER", FILE_HEADER);
    PyModule_AddIntConstant(m, "SLOT_GATE_AT", offsetof(struct slot_header, gate_ns));
    PyModule_AddIntConstant(m, "STAGE_CWD", STAGE_CWD);
    PyModule_AddIntConstant(m, "STAGE_EXEC", STAGE_EXEC);
    PyModule_AddIntConstant(m, "SLOT_HEADER", SLOT_HEADER);
    PyModule_AddIntConstant(m, "SAMPLE_SIZE", sizeof(struct sample));
    PyModule_AddIntConstant(m, "LOCK_WAIT_SIZE", sizeof(struct lock_wait));
    PyModule_AddIntConstant(m, "MAX_LOCK_SLOTS", MAX_LOCK_SLOTS);
    PyModule_AddIntConstant(m, "HIST_BUCKETS", HIST_BUCKETS);
    PyModule_AddIntConstant(m, "HIST_SUB_BITS", HIST_SUB_BITS);
    PyModule_AddIntConstant(m, "HIST_SETS", HIST_SETS);
    PyModule_AddIntConstant(m, "RING_NONE", RING_NONE);
    PyModule_AddIntConstant(m, "RING_ALL", RING_ALL);
    PyModule_AddIntConstant(m, "RING_OUTLIERS", RING_OUTLIERS);
    PyModule_AddIntConstant(m, "WORK_SLEEP", WORK_SLEEP);
    PyModule_AddIntConstant(m, "WORK_PERIODIC", WORK_PERIODIC);
    PyModule_AddIntConstant(m, "WORK_SPIN", WORK_SPIN);
    PyModule_AddIntConstant(m, "WORK_PROGRAM", WORK_PROGRAM);
    PyModule_AddIntConstant(m, "MAX_PHASES", MAX_PHASES);
    PyModule_AddIntConstant(m, "MAX_EVENTS", MAX_EVENTS);
    PyModule_AddIntConstant(m, "EV_HDR", EV_HDR);
    PyModule_AddIntConstant(m, "PHASE_BYTES", PHASE_BYTES);
    PyModule_AddIntConstant(m, "RES_BYTES", RES_BYTES);
    PyModule_AddIntConstant(m, "QDEPTH", QDEPTH);
    PyModule_AddIntConstant(m, "EV_RUN", EV_RUN);
    PyModule_AddIntConstant(m, "EV_RUNTIME", EV_RUNTIME);
    PyModule_AddIntConstant(m, "EV_SLEEP", EV_SLEEP);
    PyModule_AddIntConstant(m, "EV_TIMER", EV_TIMER);
    PyModule_AddIntConstant(m, "EV_LOCK", EV_LOCK);
    PyModule_AddIntConstant(m, "EV_UNLOCK", EV_UNLOCK);
    PyModule_AddIntConstant(m, "EV_WAIT", EV_WAIT);
    PyModule_AddIntConstant(m, "EV_SIGNAL", EV_SIGNAL);
    PyModule_AddIntConstant(m, "EV_BROADCAST", EV_BROADCAST);
    PyModule_AddIntConstant(m, "EV_BARRIER", EV_BARRIER);
    PyModule_AddIntConstant(m, "EV_SUSPEND", EV_SUSPEND);
    PyModule_AddIntConstant(m, "EV_RESUME", EV_RESUME);
    PyModule_AddIntConstant(m, "EV_YIELD", EV_YIELD);
    PyModule_AddIntConstant(m, "EV_MEM", EV_MEM);
    PyModule_AddIntConstant(m, "EV_ALLOC", EV_ALLOC);
    PyModule_AddIntConstant(m, "EV_SPAWN", EV_SPAWN);
    PyModule_AddIntConstant(m, "EV_IORUN", EV_IORUN);
    PyModule_AddIntConstant(m, "RES_MUTEX", RES_MUTEX);
    PyModule_AddIntConstant(m, "RES_COND", RES_COND);
    PyModule_AddIntConstant(m, "RES_BARRIER", RES_BARRIER);
    PyModule_AddIntConstant(m, "RES_QUEUE", RES_QUEUE);
    PyModule_AddIntConstant(m, "RES_TIMER", RES_TIMER);
    PyModule_AddIntConstant(m, "QUEUE_KEEP", QUEUE_KEEP);
    PyModule_AddIntConstant(m, "QUEUE_DROP", QUEUE_DROP);
    PyModule_AddIntConstant(m, "OVR_SKIP", OVR_SKIP);
    PyModule_AddIntConstant(m, "OVR_REBASE", OVR_REBASE);
    PyModule_AddIntConstant(m, "OVR_CATCHUP", OVR_CATCHUP);
    return m;
}
