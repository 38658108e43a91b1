/*
 * The records the native core shares with the runner, declared once: each is a list of fields (an X-macro)
 * that gives both the C struct and the table of field names, offsets, sizes and struct formats the
 * extension exports (`_probe.records()`), from which runner/run/records.py reads every field by name.
 * A field added, moved or retyped here moves in Python with it; nothing mirrors a record by position.
 * No Python here: interp.c (the measured loop) and _probe.c (the bindings) both include it.
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
 * A list's F(type, name) is a field, A(type, name, n) an array of n; types are the fixed-width ones (and
 * double), whose struct format record_code() gives.  Fields follow one another without padding (the
 * Python test checks it); a record's reserved tail is outside its list.
 */
#ifndef RUNNER_RECORDS_H
#define RUNNER_RECORDS_H

#include <stddef.h>
#include <stdint.h>

#define FILE_HEADER 128
#define GATE_AT 64 /* the start gate in the file header: state, then start and end (CLOCK_MONOTONIC) */
#define SLOT_HEADER 512
#define SAMPLE_BYTES 112
#define EV_HDR 192
#define PHASE_BYTES 384
#define MAX_LOCK_SLOTS 8 /* mutexes a thread's activations keep apart, in the order its program first locks them */
#define MAX_CPU_WORDS 16

enum slot_state { ST_CREATED = 0, ST_READY = 1, ST_RUNNING = 2, ST_DONE = 3, ST_FAILED = 4, ST_STARTING = 5 };

/* A thread's header: totals, the running figures of its callbacks, where a program stands. */
#define SLOT_HEADER_FIELDS(F, A)                                                                                          \
    F(int32_t, tid)                                                                                                       \
    F(int32_t, state)                                                                                                     \
    F(uint64_t, count)        /* samples written to the ring (all time); published after each sample */                  \
    F(int32_t, err_sched)     /* errno of applying the policy, 0 if fine or not asked */                                 \
    F(int32_t, err_nice)                                                                                                  \
    F(int32_t, err_cpus)                                                                                                  \
    F(int32_t, err_other)     /* e.g. ENOMEM of a per-callback allocation */                                             \
    A(int64_t, start_ru, 4)   /* nivcsw, nvcsw, minflt, majflt when the work starts */                                   \
    A(int64_t, end_ru, 4)     /* the same when it ends */                                                                \
    F(uint64_t, loops)        /* callbacks, or spin slices */                                                            \
    F(uint64_t, missed)       /* releases skipped because a callback overran or woke late */                             \
    F(int64_t, work_start_ns)                                                                                             \
    F(int64_t, work_end_ns)                                                                                               \
    A(uint64_t, cpus_seen, MAX_CPU_WORDS)                                                                                 \
    /* running figures of the periodic work, updated after each callback */                                               \
    F(uint64_t, releases)     /* releases in the latency histogram: callbacks plus skipped releases */                   \
    F(uint64_t, overruns)     /* callbacks that ended after their next release */                                        \
    F(uint64_t, above_bound)  /* releases whose latency exceeded the work's bound */                                     \
    F(int64_t, lat_min)                                                                                                   \
    F(int64_t, lat_max)                                                                                                   \
    F(double, lat_mean)       /* Welford's running mean and sum of squared deviations */                                 \
    F(double, lat_m2)                                                                                                     \
    F(int64_t, slack_min)                                                                                                 \
    F(int64_t, slack_max)                                                                                                 \
    F(double, slack_mean)                                                                                                 \
    F(double, slack_m2)                                                                                                   \
    F(int64_t, wall_min)                                                                                                  \
    F(int64_t, wall_max)                                                                                                  \
    F(uint64_t, nivcsw_sum)                                                                                               \
    F(uint64_t, nivcsw_max)                                                                                               \
    F(uint64_t, with_nivcsw)                                                                                              \
    F(uint64_t, minflt_sum)                                                                                               \
    F(uint64_t, minflt_max)                                                                                               \
    F(int64_t, minflt_first)  /* -1 until the first callback ran */                                                      \
    F(int64_t, first_wake_ns)                                                                                             \
    F(int64_t, last_end_ns)                                                                                               \
    F(uint64_t, nvcsw_sum)    /* with nivcsw_sum and minflt_sum: the totals of a thread that never finished */           \
    F(uint64_t, majflt_sum)                                                                                               \
    /* where a program (kind: phases) is, for the runner's stall and deadlock report */                                   \
    F(int32_t, cur_phase)     /* -1 before the first phase */                                                            \
    F(int32_t, cur_event)     /* index in the program's event list, -1 between events */                                 \
    F(int64_t, blocked_since_ns) /* when the current blocking event (lock, wait, barrier, suspend) began; 0 if none */   \
    F(int64_t, timer_due_ns)  /* at its end, the first release of the timer it followed that it had not served; 0 */     \
    F(int64_t, gate_ns)       /* when it passed the start gate (0: not yet, or a thread spawned mid-run) */          \
    F(uint64_t, missed_consecutive_max) /* the most releases missed in a row (no callback served one between them) */

/* One callback (or a program's activation) in the ring. */
#define SAMPLE_FIELDS(F, A)                                                                                               \
    F(int64_t, scheduled_ns)  /* the release this callback served, on the absolute grid */                               \
    F(int64_t, wake_ns)       /* when the thread actually ran */                                                         \
    F(int64_t, end_ns)        /* end of the callback */                                                                  \
    F(int64_t, burn_wall_ns)  /* wall time the burn took (grows when preempted) */                                       \
    F(int64_t, seq)           /* the callback's number, from 0 */                                                        \
    F(int32_t, nivcsw)        /* deltas over the callback, from getrusage(RUSAGE_THREAD) */                              \
    F(int32_t, nvcsw)                                                                                                     \
    F(int32_t, minflt)                                                                                                    \
    F(int32_t, majflt)                                                                                                    \
    F(int16_t, cpu_start)                                                                                                 \
    F(int16_t, cpu_end)                                                                                                   \
    F(int32_t, missed)        /* releases skipped just before this one */                                                \
    /* programs (kind: phases): time this activation spent blocked, by what on (0 for periodic work) */                   \
    F(int64_t, lock_wait_ns)  /* acquiring mutexes */                                                                    \
    F(int64_t, cond_wait_ns)  /* in wait on a condition variable */                                                      \
    F(int64_t, barrier_wait_ns)                                                                                           \
    F(int64_t, origin_ns)     /* programs: the timer release that started this activation's chain, 0 if none */         \
    F(int64_t, period_ns)     /* the grid's step to its release: the timer event's period that released it; 0: a resume */ \
    F(int64_t, next_ns)       /* the release after it on its grid (slack = next_ns - end_ns); 0: none (a resume) */

/* One activation's wait for one of the mutexes its thread locks (after each sample, one per lock slot). */
#define LOCK_WAIT_FIELDS(F, A)                                                                                            \
    F(int64_t, wait_ns)       /* acquiring it, summed over this activation's locks of it */                              \
    F(int32_t, holder)        /* the thread (gid) that held it when the longest of those waits began; -1: none seen */   \
    F(uint16_t, taken)        /* times this activation locked it */                                                      \
    F(uint16_t, contended)    /* of those, times it had to wait */

/* Figures of one event of a program (and, after the last event, of the thread's chain latency). */
#define EVENT_STATS_FIELDS(F, A)                                                                                          \
    F(uint64_t, count)                                                                                                    \
    F(int64_t, sum)                                                                                                       \
    F(int64_t, min)                                                                                                       \
    F(int64_t, max)                                                                                                       \
    F(double, mean)                                                                                                       \
    F(double, m2)                                                                                                         \
    F(uint64_t, contended)    /* lock: acquisitions that had to wait */                                                  \
    A(int32_t, holder, 4)     /* lock: gids seen holding it on contention, -1 unused */                                  \
    A(uint64_t, holder_count, 4)                                                                                          \
    A(int64_t, holder_wait, 4)                                                                                            \
    F(uint64_t, other_holders) /* contentions by holders beyond the four above */                                        \
    F(uint64_t, dropped)      /* spawn: spawns that found every instance taken, or failed; resume: resumes of a queue   \
                               * that drops them that found no thread suspended */                                       \
    F(uint64_t, cut)          /* events under way when the run ended (or the runner stopped it): not in the figures */

/* One phase of a program: passes, time, rusage, CPUs, and the settings the kernel reported on its first entry. */
#define PHASE_STATS_FIELDS(F, A)                                                                                          \
    F(uint64_t, passes)       /* passes over the phase's events, loops counted */                                        \
    F(int64_t, time_ns)                                                                                                   \
    A(int64_t, ru, 4)         /* nivcsw, nvcsw, minflt, majflt over the phase */                                         \
    A(uint64_t, cpus_seen, MAX_CPU_WORDS)                                                                                 \
    F(int32_t, entered)                                                                                                   \
    F(int32_t, policy)        /* read back from the kernel on the first entry */                                         \
    F(int32_t, priority)                                                                                                  \
    F(int32_t, nice)                                                                                                      \
    F(int32_t, err_sched)                                                                                                 \
    F(int32_t, err_nice)                                                                                                  \
    F(int32_t, err_cpus)                                                                                                  \
    F(int32_t, read_back)                                                                                                 \
    F(int64_t, dl_runtime)                                                                                                \
    F(int64_t, dl_deadline)                                                                                               \
    F(int64_t, dl_period)                                                                                                 \
    A(uint64_t, affinity, MAX_CPU_WORDS)

#define RECORD_SCALAR(T, name) T name;
#define RECORD_ARRAY(T, name, n) T name[n];

struct slot_header {
    SLOT_HEADER_FIELDS(RECORD_SCALAR, RECORD_ARRAY)
    uint8_t reserved[SLOT_HEADER - 480];
};

struct sample {
    SAMPLE_FIELDS(RECORD_SCALAR, RECORD_ARRAY)
};

struct lock_wait {
    LOCK_WAIT_FIELDS(RECORD_SCALAR, RECORD_ARRAY)
};

struct event_stats {
    EVENT_STATS_FIELDS(RECORD_SCALAR, RECORD_ARRAY)
    uint8_t reserved[EV_HDR - 160];
};

struct phase_stats {
    PHASE_STATS_FIELDS(RECORD_SCALAR, RECORD_ARRAY)
    uint8_t reserved[PHASE_BYTES - 360];
};

_Static_assert(sizeof(struct slot_header) == SLOT_HEADER, "slot header size");
_Static_assert(sizeof(struct sample) == SAMPLE_BYTES, "sample size");
_Static_assert(sizeof(struct lock_wait) == 16, "lock wait size");
_Static_assert(sizeof(struct event_stats) == EV_HDR, "event stats size");
_Static_assert(sizeof(struct phase_stats) == PHASE_BYTES, "phase stats size");

/* One field of a record as the table gives it: its struct format is `count` times `code` (a count of 1 is left out). */
struct record_field {
    const char *name;
    size_t offset, size;
    const char *code;
    int count;
};

struct record_table {
    const char *name;
    size_t size; /* the record's bytes, its reserved tail included */
    const struct record_field *fields;
    int nfields;
};

extern const struct record_table native_records[]; /* records.c */
extern const int native_nrecords;

/*
 * The event kinds of a program, in the order of their codes from 1 (0 is none): X(NAME, needs_resource).
 * A kind added here gets its EV_ code, its export (EV_NAME and event_kinds()) and the range check;
 * runner/run/spawn.py maps EventKind to them by name; run_event's switch runs it.
 */
#define EVENT_KINDS(X)                                                                                                    \
    X(RUN, 0)                                                                                                             \
    X(RUNTIME, 0)                                                                                                         \
    X(SLEEP, 0)                                                                                                           \
    X(TIMER, 0)                                                                                                           \
    X(LOCK, 1)                                                                                                            \
    X(UNLOCK, 1)                                                                                                          \
    X(WAIT, 1)                                                                                                            \
    X(SIGNAL, 1)                                                                                                          \
    X(BROADCAST, 1)                                                                                                       \
    X(BARRIER, 1)                                                                                                         \
    X(SUSPEND, 1)                                                                                                         \
    X(RESUME, 1)                                                                                                          \
    X(YIELD, 0)                                                                                                           \
    X(MEM, 0)                                                                                                             \
    X(ALLOC, 0)                                                                                                           \
    X(SPAWN, 0)                                                                                                           \
    X(IORUN, 0)

#define EV_ENUM(name, needs) EV_##name,
enum ev_type { EV_NONE = 0, EVENT_KINDS(EV_ENUM) EV_COUNT };
#undef EV_ENUM

#endif
