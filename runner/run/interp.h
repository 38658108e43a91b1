/*
 * The native core's measured side, without Python: what the bindings (_probe.c) and the interpreter
 * (interp.c) share.  A Group owns the threads of one worker process; each thread records into its slot of
 * the shared buffer (records.h) and runs its work here, in interp.c, which cannot call into Python (it does
 * not include Python.h), so "the measured loop never touches the interpreter" is something the compiler checks.
 */
#ifndef RUNNER_INTERP_H
#define RUNNER_INTERP_H

#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <sys/types.h>
#include <time.h>

#include "histogram.h" /* HIST_* and hist_index(), shared with _trace.c */
#include "records.h"   /* the records of the shared buffer, declared once */

enum gate_state { GATE_SHUT = 0, GATE_OPEN = 1, GATE_CANCELLED = 2 };
#define HIST_SETS 4 /* latency, slack >= 0, -slack, callback wall time */

enum work_kind { WORK_SLEEP = 0, WORK_PERIODIC = 1, WORK_SPIN = 2, WORK_PROGRAM = 3 };
enum ring_mode { RING_NONE = 0, RING_ALL = 1, RING_OUTLIERS = 2 };

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
#define RES_BYTES 1024
#define QDEPTH 32
#define SLICE_NS 100000000LL

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

_Static_assert(sizeof(struct resource) == RES_BYTES, "resource size");

/* What a running program keeps to itself (interp.c). */
struct program_state;

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
    ssize_t size;
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
    ssize_t nres;
};

/* The start gate, in the shared file header: a futex word the runner opens (or cancels) for every thread of the
 * process at once, with the run's start and end written before it.  Threads wait on it themselves, each at its
 * own policy, so a thread at an RT priority is released at once, never behind a control thread that has to
 * share the CPUs with the background load first. */
static inline _Atomic uint32_t *gate_word(const char *base) { return (_Atomic uint32_t *)(base + GATE_AT); }

extern volatile sig_atomic_t g_stop;
extern int g_stop_pipe[2];

static inline int64_t now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static inline struct timespec to_ts(int64_t ns) {
    struct timespec ts = {(time_t)(ns / 1000000000LL), (long)(ns % 1000000000LL)};
    return ts;
}

void on_stop_signal(int sig);
void apply_settings_to(pid_t tid, const struct settings *s, int reset_on_fork, int32_t errs[3]);
void apply_settings(const struct settings *s, int32_t errs[3]);
int gate_open(char *base, int64_t start, int64_t end);
int gate_cancel(char *base);
void run_slot(struct slot *s);
void prefault_slot(struct slot *s);
struct program_state *program_prepare(struct slot *s);
void program_release(struct program_state *ps);
int create_thread(struct group *g, struct slot *s);
void join_all(struct group *g);
extern const unsigned char ev_needs_resource[EV_COUNT];

#endif
