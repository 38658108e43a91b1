/*
 * runner.run._trace: the native reader of the kernel's scheduler trace.
 *
 * A Reader decodes the binary ring-buffer pages of tracefs (per_cpu/cpuN/
 * trace_pipe_raw) and folds every sched event into per-thread aggregates, in a
 * pthread that never takes the GIL: a run of an hour at tens of thousands of
 * events per second must cost the measured machine little and hold no Python
 * objects per event.  Python (runner/run/tracing.py) parses the format files
 * and hands over the event ids and field offsets; nothing here assumes a layout.
 *
 * Page (events/header_page): u64 timestamp, local_t commit (bytes of data, with
 * the missed-events flags in bits 31 and 30), data.  Event header: u32 with
 * type_len in its low 5 bits and a 27-bit time delta above; type_len 1..28 is a
 * data event of type_len * 4 bytes, 0 one whose length is the next u32, 29
 * padding (the rest of the page when its delta is 0), 30 a time extend (delta
 * continues in the next u32), 31 an absolute time stamp.
 *
 * Events of all CPUs are merged by time before they are applied: a wake-up is
 * traced on the waker's CPU and the switch onto a CPU on the wakee's.  A drain
 * applies only events older than the moment it began reading the slowest CPU,
 * less a margin (hold_ns), and keeps the rest for the next drain, so no CPU's
 * later pages can bring an event that belongs before one already applied.
 *
 * Memory is bounded: a table of at most max_threads threads (4.3 KiB each,
 * plus a 17 KiB histogram once a thread wakes; 16 bytes of index per slot), tids
 * beyond it only counted (`untracked`), and at most MAX_RECS held events (80
 * bytes each, 20 MiB): for 8192 threads that all wake, 190 MiB at most.
 */
#define _GNU_SOURCE
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "histogram.h" /* HIST_* and hist_index(), shared with _probe.c */

#define COMM_LEN 16
#define MAX_PREEMPTORS 32
#define MAX_WORST 64
#define MAX_RUNS 16      /* a thread's most preempted runs kept */
#define RUN_TAKERS 4     /* distinct preemptors followed within one run */
#define CPU_WORDS 16 /* CPUs 0..1023 */
#define MAX_RECS (1 << 18)
#define MAX_FIELDS 8

#define TYPE_DATA_MAX 28
#define TYPE_PADDING 29
#define TYPE_TIME_EXTEND 30
#define TYPE_TIME_STAMP 31
#define TS_SHIFT 27
#define ABS_TS_MASK ((1ULL << 59) - 1)
#define COMMIT_MASK ((1ULL << 27) - 1)
#define MISSED_EVENTS (1ULL << 31)
#define MISSED_STORED (1ULL << 30)

/* The events the reader understands, and the fields it needs of each, in the order
 * Python passes their layouts (exported as FIELDS: the one list of them). */
enum kind { K_SWITCH, K_WAKING, K_WAKEUP_NEW, K_MIGRATE, K_FORK, K_EXEC, K_EXIT, K_COUNT, K_GAP = K_COUNT };
static const char *const KIND_NAMES[K_COUNT] = {"switch", "waking", "wakeup_new", "migrate", "fork", "exec", "exit"};

/* where a field lands in a decoded record */
enum dest { D_COMM_A, D_COMM_B, D_PID_A, D_PID_B, D_PRIO_A, D_PRIO_B, D_STATE };
struct field_spec { const char *name; enum dest dest; };
static const struct field_spec KIND_FIELDS[K_COUNT][MAX_FIELDS] = {
    [K_SWITCH] = {{"prev_comm", D_COMM_A}, {"prev_pid", D_PID_A}, {"prev_prio", D_PRIO_A}, {"prev_state", D_STATE},
                  {"next_comm", D_COMM_B}, {"next_pid", D_PID_B}, {"next_prio", D_PRIO_B}},
    [K_WAKING] = {{"comm", D_COMM_A}, {"pid", D_PID_A}, {"prio", D_PRIO_A}},
    [K_WAKEUP_NEW] = {{"comm", D_COMM_A}, {"pid", D_PID_A}, {"prio", D_PRIO_A}},
    [K_MIGRATE] = {{"pid", D_PID_A}, {"orig_cpu", D_STATE}, {"dest_cpu", D_PID_B}},
    [K_FORK] = {{"parent_pid", D_PID_A}, {"child_comm", D_COMM_B}, {"child_pid", D_PID_B}},
    [K_EXEC] = {{"pid", D_PID_A}}, /* known, so it is not counted unknown; the new comm shows at the next switch */
    [K_EXIT] = {{"comm", D_COMM_A}, {"pid", D_PID_A}},
};

/* how a field is stored: an integer, an inline char array, or a __data_loc string */
enum field_kind { FK_UINT = 0, FK_INT = 1, FK_CHARS = 2, FK_DATA_LOC = 3 };
struct field { int32_t off, size, kind; };
struct layout { int id; int nfields; struct field f[MAX_FIELDS]; };

/* One decoded event.  a/b: switch prev/next; waking, wakeup_new, exit: the task (b unused);
 * migrate: the task, b_pid = dest CPU, state = orig CPU; fork: parent, child. */
struct rec {
    uint64_t ts;
    uint64_t seq;
    int64_t state;
    int32_t cpu, kind;
    int32_t pid_a, pid_b;
    int32_t prio_a, prio_b;
    char comm_a[COMM_LEN], comm_b[COMM_LEN];
};

struct preemptor { int32_t tid, prio; uint64_t count; char comm[COMM_LEN]; };
struct late { int64_t latency, at; int32_t cpu, tid, prio; char comm[COMM_LEN]; };
/* One run of a thread: from the switch-in that ended a wake-up to its next voluntary switch-out
 * (for a periodic thread of the runner's, one callback), with the time it spent preempted and
 * the task that held the CPU longest meanwhile. */
struct taker { int32_t tid, prio; uint32_t count; int64_t ns; char comm[COMM_LEN]; };
struct run {
    int64_t start, preempted_ns;
    uint32_t preemptions;
    int ntakers;
    struct taker takers[RUN_TAKERS];
};
struct kept_run { int64_t start, end, preempted_ns; uint32_t preemptions; struct taker top; }; /* top: the longest holder */

struct thread {
    int32_t tid;
    uint8_t seen, running, exited;
    uint8_t switched;         /* a switch of it was traced: whether it runs is known */
    int32_t cpu;              /* the CPU it runs on, while running */
    int32_t last_cpu;         /* the CPU it was last switched in on, -1 before */
    uint64_t in_ts;           /* its switch-in, while running */
    uint64_t wake_ts;         /* its pending wake-up, 0 when none */
    uint64_t exit_ts;
    char comm[COMM_LEN];
    uint64_t wakeups, preemptions, voluntary, migrations, cpu_changes, other_preemptors;
    uint64_t unseen_ins;      /* switch-outs with no switch-in traced before them */
    int64_t run_ns, lat_min, lat_max, lat_sum;
    uint32_t *hist;           /* HIST_BUCKETS counters, halved together when one is full; allocated at the first wake-up */
    uint64_t cpus[CPU_WORDS];
    int npre, nworst;
    struct preemptor pre[MAX_PREEMPTORS];
    struct late worst[MAX_WORST];  /* a min-heap on latency while running, sorted at the end */
    struct run cur;           /* the run under way; cur.start 0 outside one */
    uint64_t out_ts;          /* preempted at, within the run under way; 0 when on a CPU */
    int32_t out_tid, out_prio;
    char out_comm[COMM_LEN];
    int nruns;
    struct kept_run runs[MAX_RUNS]; /* the most preempted runs: a min-heap on preempted_ns */
};

typedef struct {
    PyObject_HEAD
    pthread_mutex_t lock;
    int lock_ready;
    /* layout */
    size_t page_size;
    int ts_off, commit_off, commit_size, data_off;
    int type_off, type_size;
    struct layout layouts[K_COUNT];
    int64_t state_mask;
    int64_t hold_ns;
    /* threads: open addressing, key 0 = empty */
    uint32_t cap, max_threads, nthreads;
    int32_t *keys;
    struct thread **slots;
    int32_t *over;            /* tids the table had no room for, same capacity */
    uint32_t nover;
    /* held events */
    struct rec *recs;
    size_t nrec, caprec;
    uint64_t seq;
    uint64_t last_ts;
    uint64_t first_ts;        /* of the first event applied, 0 before */
    int64_t window_late_ns;   /* time outside the window whose events were applied before it was set */
    /* window */
    int64_t win_start, win_end;
    /* counters */
    uint64_t events, unknown, malformed, untracked, out_of_order, forced, missed_pages, lost_stored, nomem;
    int64_t cpu_ns;
    /* the reading thread */
    int nfiles;
    int *fds, *fd_cpus;
    unsigned char *page;
    pthread_t thread;
    pthread_cond_t wake;
    int started, stopping, joined;
    int64_t interval_ns;
    int read_errno;
} Reader;

/* ---- small helpers ---- */

static int64_t now_ns(clockid_t clock) {
    struct timespec t;
    clock_gettime(clock, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static uint64_t rd_u(const unsigned char *p, int size) {
    switch (size) {
    case 1: return p[0];
    case 2: { uint16_t v; memcpy(&v, p, 2); return v; }
    case 4: { uint32_t v; memcpy(&v, p, 4); return v; }
    case 8: { uint64_t v; memcpy(&v, p, 8); return v; }
    default: return 0;
    }
}

static int64_t rd_s(const unsigned char *p, int size) {
    switch (size) {
    case 1: return (int8_t)p[0];
    case 2: { int16_t v; memcpy(&v, p, 2); return v; }
    case 4: { int32_t v; memcpy(&v, p, 4); return v; }
    case 8: { int64_t v; memcpy(&v, p, 8); return v; }
    default: return 0;
    }
}

static void copy_comm(char *dst, const char *src) {
    memcpy(dst, src, COMM_LEN);
    dst[COMM_LEN - 1] = 0;
}

/* ---- the thread table ---- */

static inline uint32_t hash_tid(int32_t tid, uint32_t cap) { return ((uint32_t)tid * 2654435761u) & (cap - 1); }

static struct thread *find(Reader *r, int32_t tid) {
    if (tid <= 0) return NULL;
    for (uint32_t i = hash_tid(tid, r->cap), n = 0; n < r->cap; i = (i + 1) & (r->cap - 1), n++) {
        if (r->keys[i] == tid) return r->slots[i];
        if (r->keys[i] == 0) return NULL;
    }
    return NULL;
}

static int in_overflow(Reader *r, int32_t tid) {
    if (tid <= 0 || r->nover == 0) return 0;
    for (uint32_t i = hash_tid(tid, r->cap), n = 0; n < r->cap; i = (i + 1) & (r->cap - 1), n++) {
        if (r->over[i] == tid) return 1;
        if (r->over[i] == 0) return 0;
    }
    return 0;
}

/* Add `tid` (a no-op when known); beyond max_threads it goes to the overflow set, counted. */
static struct thread *track(Reader *r, int32_t tid, const char *comm) {
    if (tid <= 0) return NULL;
    struct thread *t = find(r, tid);
    if (t) return t;
    if (r->nthreads >= r->max_threads || !(t = calloc(1, sizeof *t))) {
        if (in_overflow(r, tid) || r->nover >= r->max_threads) return NULL;
        uint32_t i = hash_tid(tid, r->cap);
        while (r->over[i]) i = (i + 1) & (r->cap - 1);
        r->over[i] = tid;
        r->nover++;
        return NULL;
    }
    t->tid = tid;
    t->cpu = t->last_cpu = -1;
    t->lat_min = INT64_MAX;
    t->lat_max = -1;
    if (comm) copy_comm(t->comm, comm);
    uint32_t i = hash_tid(tid, r->cap);
    while (r->keys[i]) i = (i + 1) & (r->cap - 1);
    r->keys[i] = tid;
    r->slots[i] = t;
    r->nthreads++;
    return t;
}

/* The tracked thread `tid` names, or NULL (counting it when it is one the table had no room for). */
static struct thread *subject(Reader *r, int32_t tid) {
    struct thread *t = find(r, tid);
    if (!t && in_overflow(r, tid)) r->untracked++;
    return t;
}

/* ---- aggregates ---- */

static inline int inside(Reader *r, uint64_t ts) { return (int64_t)ts >= r->win_start && (int64_t)ts <= r->win_end; }

static void add_run(Reader *r, struct thread *t, uint64_t from, uint64_t to) {
    int64_t a = (int64_t)from > r->win_start ? (int64_t)from : r->win_start;
    int64_t b = (int64_t)to < r->win_end ? (int64_t)to : r->win_end;
    if (b > a) t->run_ns += b - a;
}

static void add_preemptor(struct thread *t, int32_t tid, int32_t prio, const char *comm) {
    for (int i = 0; i < t->npre; i++) {
        if (t->pre[i].tid == tid) {
            t->pre[i].count++;
            t->pre[i].prio = prio;
            copy_comm(t->pre[i].comm, comm);
            return;
        }
    }
    if (t->npre == MAX_PREEMPTORS) {
        t->other_preemptors++;
        return;
    }
    struct preemptor *p = &t->pre[t->npre++];
    p->tid = tid;
    p->prio = prio;
    p->count = 1;
    copy_comm(p->comm, comm);
}

static void heap_down(struct late *h, int n, int i) {
    for (;;) {
        int l = 2 * i + 1, m = i;
        if (l < n && h[l].latency < h[m].latency) m = l;
        if (l + 1 < n && h[l + 1].latency < h[m].latency) m = l + 1;
        if (m == i) return;
        struct late tmp = h[i];
        h[i] = h[m];
        h[m] = tmp;
        i = m;
    }
}

/* Count a wake-up in bucket `i` of a thread's HIST_BUCKETS counters.  A full bucket (a thread woken every 10 us
 * fills one in half a day) halves them all first, rounding up so that no bucket empties: the percentiles come from
 * the counts' proportions, which this keeps (the wake-ups themselves are counted apart), where a saturated bucket
 * would have skewed them unsaid. */
static void hist_add(uint32_t *hist, int i) {
    if (hist[i] == UINT32_MAX)
        for (int k = 0; k < HIST_BUCKETS; k++) hist[k] = hist[k] / 2 + (hist[k] & 1);
    hist[i]++;
}

static void add_wakeup(Reader *r, struct thread *t, int64_t lat, const struct rec *e) {
    t->wakeups++;
    t->lat_sum += lat;
    if (lat < t->lat_min) t->lat_min = lat;
    if (lat > t->lat_max) t->lat_max = lat;
    if (!t->hist && !(t->hist = calloc(HIST_BUCKETS, sizeof *t->hist))) r->nomem++;
    if (t->hist) hist_add(t->hist, hist_index(lat));
    struct late w = {.latency = lat, .at = (int64_t)e->ts, .cpu = e->cpu, .tid = e->pid_a, .prio = e->prio_a};
    copy_comm(w.comm, e->comm_a);
    if (t->nworst < MAX_WORST) {
        int i = t->nworst++;
        t->worst[i] = w;
        while (i > 0 && t->worst[(i - 1) / 2].latency > t->worst[i].latency) {
            struct late tmp = t->worst[i];
            t->worst[i] = t->worst[(i - 1) / 2];
            t->worst[(i - 1) / 2] = tmp;
            i = (i - 1) / 2;
        }
    } else if (lat > t->worst[0].latency) {
        t->worst[0] = w;
        heap_down(t->worst, t->nworst, 0);
    }
}

static void run_heap_down(struct kept_run *h, int n, int i) {
    for (;;) {
        int l = 2 * i + 1, m = i;
        if (l < n && h[l].preempted_ns < h[m].preempted_ns) m = l;
        if (l + 1 < n && h[l + 1].preempted_ns < h[m].preempted_ns) m = l + 1;
        if (m == i) return;
        struct kept_run tmp = h[i];
        h[i] = h[m];
        h[m] = tmp;
        i = m;
    }
}

/* A run ended at `ts`: kept among the thread's most preempted when it was preempted at all and
 * ended inside the window (one that ends after it also holds what the thread did once its
 * measured work was over, which is not the run's to carry). */
static void run_close(Reader *r, struct thread *t, uint64_t ts) {
    struct run *c = &t->cur;
    if (c->start && c->preemptions && c->preempted_ns > 0 && (int64_t)ts <= r->win_end) {
        int top = 0;
        for (int k = 1; k < c->ntakers; k++)
            if (c->takers[k].ns > c->takers[top].ns) top = k;
        struct kept_run kept = {.start = c->start, .end = (int64_t)ts, .preempted_ns = c->preempted_ns, .preemptions = c->preemptions};
        kept.top = c->takers[top];
        if (t->nruns < MAX_RUNS) {
            int i = t->nruns++;
            t->runs[i] = kept;
            while (i > 0 && t->runs[(i - 1) / 2].preempted_ns > t->runs[i].preempted_ns) {
                struct kept_run tmp = t->runs[i];
                t->runs[i] = t->runs[(i - 1) / 2];
                t->runs[(i - 1) / 2] = tmp;
                i = (i - 1) / 2;
            }
        } else if (c->preempted_ns > t->runs[0].preempted_ns) {
            t->runs[0] = kept;
            run_heap_down(t->runs, t->nruns, 0);
        }
    }
    memset(c, 0, sizeof *c);
    t->out_ts = 0;
}

/* Back on a CPU after a preemption within a run: the time off it goes to the task that took it. */
static void run_resume(struct thread *t, uint64_t ts) {
    struct run *c = &t->cur;
    int64_t off = (int64_t)(ts - t->out_ts);
    t->out_ts = 0;
    if (!c->start || off <= 0) return;
    c->preempted_ns += off;
    int k = 0;
    while (k < c->ntakers && c->takers[k].tid != t->out_tid) k++;
    if (k == c->ntakers) {
        if (c->ntakers == RUN_TAKERS) return; /* a fifth distinct preemptor in one run: its time is in preempted_ns only */
        c->ntakers++;
        c->takers[k].tid = t->out_tid;
        c->takers[k].count = 0;
        c->takers[k].ns = 0;
    }
    c->takers[k].prio = t->out_prio;
    copy_comm(c->takers[k].comm, t->out_comm);
    c->takers[k].count++;
    c->takers[k].ns += off;
}

static void apply_switch(Reader *r, const struct rec *e) {
    struct thread *p = subject(r, e->pid_a), *n = subject(r, e->pid_b);
    int in = inside(r, e->ts);
    if (p) {
        p->seen = 1;
        copy_comm(p->comm, e->comm_a);
        if (p->running) {
            add_run(r, p, p->in_ts, e->ts);
        } else if (p->switched) {
            /* it ran, but its switch-in was not traced (some kernels drop switches out of
             * idle): that switch-in ended any wake-up pending, whose latency is unknown */
            p->wake_ts = 0;
            if (in) p->unseen_ins++;
        }
        p->switched = 1;
        p->running = 0;
        if ((e->state & r->state_mask) == 0) {
            /* switched out runnable: preempted (R+), or it yielded (R); a wake-up traced while
             * it still ran found it running, so no wake-up is pending */
            p->wake_ts = 0;
            if (in) {
                p->preemptions++;
                add_preemptor(p, e->pid_b, e->prio_b, e->comm_b);
            }
            if (p->cur.start) {
                p->cur.preemptions++;
                p->out_ts = e->ts;
                p->out_tid = e->pid_b;
                p->out_prio = e->prio_b;
                copy_comm(p->out_comm, e->comm_b);
            }
        } else {
            if (in) p->voluntary++;
            run_close(r, p, e->ts);
        }
    }
    if (n) {
        n->seen = 1;
        copy_comm(n->comm, e->comm_b);
        if (n->wake_ts) {
            if (in) add_wakeup(r, n, (int64_t)(e->ts - n->wake_ts), e);
            n->wake_ts = 0;
            memset(&n->cur, 0, sizeof n->cur); /* a run whose end went unseen: not one to keep */
            n->out_ts = 0;
            if (in) n->cur.start = (int64_t)e->ts;
        } else if (n->out_ts) {
            run_resume(n, e->ts);
        }
        if (in) {
            if (e->cpu >= 0 && e->cpu < CPU_WORDS * 64) n->cpus[e->cpu / 64] |= 1ULL << (e->cpu % 64);
            if (n->last_cpu >= 0 && n->last_cpu != e->cpu) n->cpu_changes++;
        }
        n->running = n->switched = 1;
        n->cpu = n->last_cpu = e->cpu;
        n->in_ts = e->ts;
    }
}

/* Events were lost on a CPU: what was pending may have ended unseen there, so nothing
 * pending is trusted (a wake-up measured across the gap could be any length). */
static void apply_gap(Reader *r, const struct rec *e) {
    for (uint32_t i = 0; i < r->cap; i++) {
        struct thread *t = r->keys[i] ? r->slots[i] : NULL;
        if (!t) continue;
        t->wake_ts = 0;
        if (t->running && t->cpu == e->cpu) t->running = 0;
        memset(&t->cur, 0, sizeof t->cur); /* a run across the gap would be any length */
        t->out_ts = 0;
    }
}

static void apply(Reader *r, const struct rec *e) {
    struct thread *t;
    if (e->ts < r->last_ts) r->out_of_order++;
    else r->last_ts = e->ts;
    if (!r->first_ts) r->first_ts = e->ts;
    switch (e->kind) {
    case K_SWITCH:
        apply_switch(r, e);
        break;
    case K_WAKING:
    case K_WAKEUP_NEW:
        /* the latest wins: an earlier one found it running (the kernel then traces no switch) */
        if ((t = subject(r, e->pid_a))) {
            t->seen = 1;
            copy_comm(t->comm, e->comm_a);
            t->wake_ts = e->ts;
        }
        break;
    case K_MIGRATE:
        if ((t = subject(r, e->pid_a))) {
            t->seen = 1;
            if (inside(r, e->ts)) t->migrations++;
        }
        break;
    case K_FORK:
        /* the kernel adds a child to the pid filter when its parent is in it (event-fork) */
        if (find(r, e->pid_a)) track(r, e->pid_b, e->comm_b);
        else if (in_overflow(r, e->pid_a)) {
            r->untracked++;
            track(r, e->pid_b, e->comm_b);
        }
        break;
    case K_EXIT:
        if ((t = subject(r, e->pid_a))) {
            t->seen = 1;
            t->exited = 1;
            t->exit_ts = e->ts;
        }
        break;
    case K_GAP:
        apply_gap(r, e);
        break;
    }
}

static int rec_order(const void *a, const void *b) {
    const struct rec *x = a, *y = b;
    if (x->ts != y->ts) return x->ts < y->ts ? -1 : 1;
    return x->seq < y->seq ? -1 : x->seq > y->seq;
}

/* Apply the held events up to `limit` (all of them with UINT64_MAX), in time order. */
static void apply_until(Reader *r, uint64_t limit) {
    if (!r->nrec) return;
    qsort(r->recs, r->nrec, sizeof *r->recs, rec_order);
    size_t i = 0;
    while (i < r->nrec && r->recs[i].ts <= limit) apply(r, &r->recs[i++]);
    memmove(r->recs, r->recs + i, (r->nrec - i) * sizeof *r->recs);
    r->nrec -= i;
}

static struct rec *new_rec(Reader *r) {
    if (r->nrec == r->caprec) {
        if (r->caprec >= MAX_RECS) {
            /* more held than allowed: apply the older half now, whatever the margin says */
            qsort(r->recs, r->nrec, sizeof *r->recs, rec_order);
            size_t half = r->nrec / 2;
            for (size_t i = 0; i < half; i++) apply(r, &r->recs[i]);
            memmove(r->recs, r->recs + half, (r->nrec - half) * sizeof *r->recs);
            r->nrec -= half;
            r->forced += half;
        } else {
            size_t cap = r->caprec ? r->caprec * 2 : 4096;
            struct rec *grown = realloc(r->recs, cap * sizeof *grown);
            if (!grown) {
                r->nomem++;
                apply_until(r, UINT64_MAX);
                if (!r->caprec) return NULL;
            } else {
                r->recs = grown;
                r->caprec = cap;
            }
        }
    }
    struct rec *e = &r->recs[r->nrec++];
    memset(e, 0, sizeof *e);
    e->seq = r->seq++;
    return e;
}

/* ---- decoding ---- */

static int read_string(const unsigned char *data, size_t len, const struct field *f, char *out) {
    memset(out, 0, COMM_LEN);
    if (f->kind == FK_CHARS) {
        memcpy(out, data + f->off, f->size < COMM_LEN ? (size_t)f->size : COMM_LEN - 1);
        out[COMM_LEN - 1] = 0;
        return 0;
    }
    uint32_t loc = (uint32_t)rd_u(data + f->off, 4);
    size_t off = loc & 0xffff, n = loc >> 16;
    if (off + n > len) return -1;
    memcpy(out, data + off, n < COMM_LEN ? n : COMM_LEN - 1);
    out[COMM_LEN - 1] = 0;
    return 0;
}

static void decode_event(Reader *r, int cpu, uint64_t ts, const unsigned char *data, size_t len) {
    r->events++;
    if ((size_t)(r->type_off + r->type_size) > len) {
        r->malformed++;
        return;
    }
    int id = (int)rd_u(data + r->type_off, r->type_size);
    int kind = -1;
    for (int k = 0; k < K_COUNT; k++)
        if (r->layouts[k].id == id) kind = k;
    if (kind < 0) {
        r->unknown++;
        return;
    }
    const struct layout *l = &r->layouts[kind];
    for (int i = 0; i < l->nfields; i++) {
        if ((size_t)(l->f[i].off + l->f[i].size) > len) {
            r->malformed++;
            return;
        }
    }
    struct rec *e = new_rec(r);
    if (!e) return;
    e->ts = ts;
    e->cpu = cpu;
    e->kind = kind;
    for (int i = 0; i < l->nfields; i++) {
        const struct field *f = &l->f[i];
        enum dest d = KIND_FIELDS[kind][i].dest;
        if (d == D_COMM_A || d == D_COMM_B) {
            if (read_string(data, len, f, d == D_COMM_A ? e->comm_a : e->comm_b) < 0) r->malformed++;
            continue;
        }
        int64_t v = f->kind == FK_INT ? rd_s(data + f->off, f->size) : (int64_t)rd_u(data + f->off, f->size);
        switch (d) {
        case D_PID_A: e->pid_a = (int32_t)v; break;
        case D_PID_B: e->pid_b = (int32_t)v; break;
        case D_PRIO_A: e->prio_a = (int32_t)v; break;
        case D_PRIO_B: e->prio_b = (int32_t)v; break;
        case D_STATE: e->state = v; break;
        default: break;
        }
    }
}

/* Decode one page as trace_pipe_raw returns it: events go to the held records. */
static void decode_page(Reader *r, int cpu, const unsigned char *page, size_t n) {
    if (n < (size_t)r->data_off) {
        r->malformed++;
        return;
    }
    uint64_t ts = rd_u(page + r->ts_off, 8);
    uint64_t commit = rd_u(page + r->commit_off, r->commit_size);
    size_t size = (size_t)(commit & COMMIT_MASK);
    size_t end = (size_t)r->data_off + size;
    if (end > n) {
        r->malformed++;
        end = n;
    }
    if (commit & MISSED_EVENTS) {
        r->missed_pages++;
        if ((commit & MISSED_STORED) && end + (size_t)r->commit_size <= n) r->lost_stored += rd_u(page + end, r->commit_size);
        struct rec *g = new_rec(r);
        if (g) {
            g->ts = ts;
            g->cpu = cpu;
            g->kind = K_GAP;
        }
    }
    size_t p = (size_t)r->data_off;
    while (p + 4 <= end) {
        uint32_t hdr = (uint32_t)rd_u(page + p, 4);
        uint32_t type_len = hdr & 31, delta = hdr >> 5;
        if (type_len == TYPE_PADDING) {
            if (delta == 0) break; /* the rest of the page */
            if (p + 8 > end) break;
            p += 4 + (size_t)rd_u(page + p + 4, 4); /* a discarded event; its delta does not count */
        } else if (type_len == TYPE_TIME_EXTEND || type_len == TYPE_TIME_STAMP) {
            if (p + 8 > end) {
                r->malformed++;
                break;
            }
            uint64_t v = (rd_u(page + p + 4, 4) << TS_SHIFT) + delta;
            if (type_len == TYPE_TIME_EXTEND) ts += v;
            else ts = (ts & ~ABS_TS_MASK) | (v & ABS_TS_MASK);
            p += 8;
        } else if (type_len == 0) {
            if (p + 8 > end) {
                r->malformed++;
                break;
            }
            size_t len = (size_t)rd_u(page + p + 4, 4);
            if (len < 4 || p + 4 + len > end) {
                r->malformed++;
                break;
            }
            ts += delta;
            decode_event(r, cpu, ts, page + p + 8, len - 4);
            p += 4 + ((len + 3) & ~(size_t)3);
        } else {
            size_t len = (size_t)type_len * 4;
            if (p + 4 + len > end) {
                r->malformed++;
                break;
            }
            ts += delta;
            decode_event(r, cpu, ts, page + p + 4, len);
            p += 4 + len;
        }
    }
}

/* ---- the reading thread ---- */

static void drain(Reader *r, int final) {
    uint64_t limit = UINT64_MAX;
    for (int i = 0; i < r->nfiles; i++) {
        int64_t began = now_ns(CLOCK_MONOTONIC) - r->hold_ns;
        if (began < 0) began = 0;
        if ((uint64_t)began < limit) limit = (uint64_t)began;
        for (;;) {
            if (!final && __atomic_load_n(&r->stopping, __ATOMIC_RELAXED)) break; /* the final drain reads the rest */
            ssize_t n = read(r->fds[i], r->page, r->page_size);
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) {
                if (n < 0 && errno != EAGAIN) r->read_errno = errno;
                break;
            }
            pthread_mutex_lock(&r->lock);
            decode_page(r, r->fd_cpus[i], r->page, (size_t)n);
            pthread_mutex_unlock(&r->lock);
        }
    }
    pthread_mutex_lock(&r->lock);
    apply_until(r, final ? UINT64_MAX : limit);
    pthread_mutex_unlock(&r->lock);
}

static void *reader_main(void *arg) {
    Reader *r = arg;
    int64_t cpu0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    pthread_mutex_lock(&r->lock);
    while (!r->stopping) {
        pthread_mutex_unlock(&r->lock);
        drain(r, 0);
        pthread_mutex_lock(&r->lock);
        if (r->stopping) break;
        struct timespec until;
        clock_gettime(CLOCK_MONOTONIC, &until);
        int64_t ns = until.tv_nsec + r->interval_ns;
        until.tv_sec += ns / 1000000000LL;
        until.tv_nsec = ns % 1000000000LL;
        while (!r->stopping && pthread_cond_timedwait(&r->wake, &r->lock, &until) == 0) {
        }
    }
    pthread_mutex_unlock(&r->lock);
    drain(r, 1);
    int64_t spent = now_ns(CLOCK_THREAD_CPUTIME_ID) - cpu0;
    pthread_mutex_lock(&r->lock);
    r->cpu_ns += spent;
    pthread_mutex_unlock(&r->lock);
    return NULL;
}

/* ---- Python interface ---- */

static int parse_layout(PyObject *spec, struct layout *l, int kind) {
    int nf = 0;
    while (nf < MAX_FIELDS && KIND_FIELDS[kind][nf].name) nf++;
    l->id = -1;
    l->nfields = nf;
    if (spec == Py_None) return 0;
    PyObject *fields;
    if (!PyArg_ParseTuple(spec, "iO", &l->id, &fields)) return -1;
    PyObject *seq = PySequence_Fast(fields, "fields must be a sequence");
    if (!seq) return -1;
    if (PySequence_Fast_GET_SIZE(seq) != nf) {
        PyErr_Format(PyExc_ValueError, "%s: %d fields expected, got %zd", KIND_NAMES[kind], nf, PySequence_Fast_GET_SIZE(seq));
        Py_DECREF(seq);
        return -1;
    }
    for (int i = 0; i < nf; i++) {
        struct field *f = &l->f[i];
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "iii", &f->off, &f->size, &f->kind)) {
            Py_DECREF(seq);
            return -1;
        }
        int is_string = KIND_FIELDS[kind][i].dest == D_COMM_A || KIND_FIELDS[kind][i].dest == D_COMM_B;
        int ok = f->off >= 0 && (is_string ? (f->kind == FK_CHARS ? f->size > 0 : f->kind == FK_DATA_LOC && f->size == 4)
                                           : (f->kind == FK_INT || f->kind == FK_UINT) &&
                                                 (f->size == 1 || f->size == 2 || f->size == 4 || f->size == 8));
        if (!ok) {
            PyErr_Format(PyExc_ValueError, "%s.%s: unusable layout (offset %d, size %d, kind %d)", KIND_NAMES[kind],
                         KIND_FIELDS[kind][i].name, f->off, f->size, f->kind);
            Py_DECREF(seq);
            return -1;
        }
    }
    Py_DECREF(seq);
    return 0;
}

static void free_state(Reader *r) {
    if (r->slots) {
        for (uint32_t i = 0; i < r->cap; i++) {
            if (r->slots[i]) {
                free(r->slots[i]->hist);
                free(r->slots[i]);
            }
        }
    }
    free(r->slots);
    free(r->keys);
    free(r->over);
    free(r->recs);
    free(r->page);
    free(r->fds);
    free(r->fd_cpus);
    r->slots = NULL;
    r->keys = r->over = NULL;
    r->recs = NULL;
    r->page = NULL;
    r->fds = r->fd_cpus = NULL;
}

static void stop_thread(Reader *r) {
    if (!r->started || r->joined) return;
    pthread_mutex_lock(&r->lock);
    r->stopping = 1;
    pthread_cond_signal(&r->wake);
    pthread_mutex_unlock(&r->lock);
    Py_BEGIN_ALLOW_THREADS
    pthread_join(r->thread, NULL);
    Py_END_ALLOW_THREADS
    r->joined = 1;
    for (int i = 0; i < r->nfiles; i++) close(r->fds[i]);
    r->nfiles = 0;
}

static void Reader_dealloc(Reader *r) {
    if (r->lock_ready) {
        stop_thread(r);
        pthread_mutex_destroy(&r->lock);
        pthread_cond_destroy(&r->wake);
    }
    free_state(r);
    Py_TYPE(r)->tp_free((PyObject *)r);
}

static int Reader_init(Reader *r, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"page_size", "header", "common_type", "layouts", "state_mask", "max_threads", "hold_ns", NULL};
    Py_ssize_t page_size;
    PyObject *layouts;
    unsigned int max_threads = 8192;
    long long state_mask, hold = 10000000;
    if (r->lock_ready) {
        PyErr_SetString(PyExc_RuntimeError, "Reader is initialised once");
        return -1;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "n(iiii)(ii)OL|IL", kwlist, &page_size, &r->ts_off, &r->commit_off, &r->commit_size,
                                     &r->data_off, &r->type_off, &r->type_size, &layouts, &state_mask, &max_threads, &hold))
        return -1;
    if (page_size <= 0 || page_size > (1 << 24) || r->data_off <= 0 || r->data_off >= page_size || r->ts_off < 0 ||
        r->ts_off + 8 > r->data_off || r->commit_off < 0 || (r->commit_size != 4 && r->commit_size != 8) ||
        r->commit_off + r->commit_size > r->data_off || (r->commit_off < r->ts_off + 8 && r->ts_off < r->commit_off + r->commit_size) ||
        r->type_off < 0 || (r->type_size != 1 && r->type_size != 2 && r->type_size != 4)) {
        PyErr_SetString(PyExc_ValueError, "unusable page header or common_type layout");
        return -1;
    }
    if (max_threads < 1 || max_threads > (1u << 22)) {
        PyErr_SetString(PyExc_ValueError, "max_threads must be 1 .. 4194304");
        return -1;
    }
    PyObject *seq = PySequence_Fast(layouts, "layouts must be a sequence");
    if (!seq) return -1;
    if (PySequence_Fast_GET_SIZE(seq) != K_COUNT) {
        PyErr_Format(PyExc_ValueError, "%d layouts expected (FIELDS), got %zd", K_COUNT, PySequence_Fast_GET_SIZE(seq));
        Py_DECREF(seq);
        return -1;
    }
    for (int k = 0; k < K_COUNT; k++) {
        if (parse_layout(PySequence_Fast_GET_ITEM(seq, k), &r->layouts[k], k) < 0) {
            Py_DECREF(seq);
            return -1;
        }
    }
    Py_DECREF(seq);
    if (r->layouts[K_SWITCH].id < 0) {
        PyErr_SetString(PyExc_ValueError, "the switch layout is required");
        return -1;
    }
    r->page_size = (size_t)page_size;
    r->state_mask = state_mask;
    r->hold_ns = hold;
    r->max_threads = max_threads;
    r->cap = 1;
    while (r->cap < 2 * max_threads) r->cap <<= 1;
    r->keys = calloc(r->cap, sizeof *r->keys);
    r->over = calloc(r->cap, sizeof *r->over);
    r->slots = calloc(r->cap, sizeof *r->slots);
    r->page = malloc(r->page_size);
    if (!r->keys || !r->over || !r->slots || !r->page) {
        free_state(r);
        PyErr_NoMemory();
        return -1;
    }
    r->win_start = INT64_MIN;
    r->win_end = INT64_MAX;
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&r->wake, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&r->lock, NULL);
    r->lock_ready = 1;
    return 0;
}

static int ready(Reader *r) {
    if (!r->lock_ready) {
        PyErr_SetString(PyExc_RuntimeError, "Reader is not initialised");
        return 0;
    }
    return 1;
}

static void lock_nogil(Reader *r) {
    if (pthread_mutex_trylock(&r->lock) == 0) return;
    Py_BEGIN_ALLOW_THREADS
    pthread_mutex_lock(&r->lock);
    Py_END_ALLOW_THREADS
}

static PyObject *Reader_track(Reader *r, PyObject *arg) {
    if (!ready(r)) return NULL;
    PyObject *seq = PySequence_Fast(arg, "track() takes a sequence of tids");
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    int32_t *tids = PyMem_Malloc(sizeof *tids * (size_t)(n ? n : 1));
    if (!tids) {
        Py_DECREF(seq);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        long v = PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
        if (v == -1 && PyErr_Occurred()) {
            PyMem_Free(tids);
            Py_DECREF(seq);
            return NULL;
        }
        tids[i] = (int32_t)v;
    }
    Py_DECREF(seq);
    lock_nogil(r);
    for (Py_ssize_t i = 0; i < n; i++) track(r, tids[i], NULL);
    pthread_mutex_unlock(&r->lock);
    PyMem_Free(tids);
    Py_RETURN_NONE;
}

static PyObject *Reader_window(Reader *r, PyObject *args) {
    long long start, end;
    if (!ready(r) || !PyArg_ParseTuple(args, "LL", &start, &end)) return NULL;
    int64_t new_end = end < 0 ? INT64_MAX : end;
    lock_nogil(r);
    if (r->first_ts) {
        /* events already applied are counted as the old window said: what the new one
         * excludes and the old one held is said, not undone */
        int64_t first = (int64_t)r->first_ts, last = (int64_t)r->last_ts;
        int64_t lo = first > r->win_start ? first : r->win_start, hi = last < r->win_end ? last : r->win_end;
        int64_t before = (hi < start ? hi : start) - lo, after = hi - (lo > new_end ? lo : new_end);
        if (before > 0) r->window_late_ns += before;
        if (after > 0) r->window_late_ns += after;
    }
    r->win_start = start;
    r->win_end = new_end;
    pthread_mutex_unlock(&r->lock);
    Py_RETURN_NONE;
}

static PyObject *Reader_feed(Reader *r, PyObject *args) {
    int cpu;
    Py_buffer buf;
    if (!ready(r) || !PyArg_ParseTuple(args, "iy*", &cpu, &buf)) return NULL;
    if (r->started) {
        PyBuffer_Release(&buf);
        PyErr_SetString(PyExc_RuntimeError, "feed() is for a Reader that does not read tracefs itself");
        return NULL;
    }
    int64_t cpu0 = now_ns(CLOCK_THREAD_CPUTIME_ID);
    lock_nogil(r);
    const unsigned char *p = buf.buf;
    for (Py_ssize_t off = 0; off < buf.len; off += (Py_ssize_t)r->page_size) {
        Py_ssize_t n = buf.len - off < (Py_ssize_t)r->page_size ? buf.len - off : (Py_ssize_t)r->page_size;
        decode_page(r, cpu, p + off, (size_t)n);
    }
    r->cpu_ns += now_ns(CLOCK_THREAD_CPUTIME_ID) - cpu0;
    pthread_mutex_unlock(&r->lock);
    PyBuffer_Release(&buf);
    Py_RETURN_NONE;
}

static PyObject *Reader_start(Reader *r, PyObject *args) {
    PyObject *files;
    long long interval;
    if (!ready(r) || !PyArg_ParseTuple(args, "OL", &files, &interval)) return NULL;
    if (r->started) {
        PyErr_SetString(PyExc_RuntimeError, "the reader runs already");
        return NULL;
    }
    PyObject *seq = PySequence_Fast(files, "start() takes a sequence of (cpu, path)");
    if (!seq) return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
    r->fds = calloc((size_t)(n ? n : 1), sizeof *r->fds);
    r->fd_cpus = calloc((size_t)(n ? n : 1), sizeof *r->fd_cpus);
    if (!r->fds || !r->fd_cpus) {
        Py_DECREF(seq);
        return PyErr_NoMemory();
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        int cpu;
        const char *path;
        if (!PyArg_ParseTuple(PySequence_Fast_GET_ITEM(seq, i), "is", &cpu, &path)) goto fail;
        int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
        if (fd < 0) {
            PyErr_SetFromErrnoWithFilename(PyExc_OSError, path);
            goto fail;
        }
        r->fds[r->nfiles] = fd;
        r->fd_cpus[r->nfiles++] = cpu;
    }
    Py_DECREF(seq);
    r->interval_ns = interval > 0 ? interval : 50000000;
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old); /* signals stay with Python's threads */
    int err = pthread_create(&r->thread, NULL, reader_main, r);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (err) {
        errno = err;
        PyErr_SetFromErrno(PyExc_OSError);
        for (int i = 0; i < r->nfiles; i++) close(r->fds[i]);
        r->nfiles = 0;
        return NULL;
    }
    r->started = 1;
    Py_RETURN_NONE;
fail:
    Py_DECREF(seq);
    for (int i = 0; i < r->nfiles; i++) close(r->fds[i]);
    r->nfiles = 0;
    return NULL;
}

static PyObject *Reader_stop(Reader *r, PyObject *unused) {
    if (!ready(r)) return NULL;
    stop_thread(r); /* its last drain reads what is left and applies everything */
    lock_nogil(r);
    apply_until(r, UINT64_MAX);
    pthread_mutex_unlock(&r->lock);
    if (r->read_errno) {
        errno = r->read_errno;
        r->read_errno = 0;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    Py_RETURN_NONE;
}

/* most frequent first; ties by tid, so the order does not depend on the table */
static int preemptor_order(const void *a, const void *b) {
    const struct preemptor *x = a, *y = b;
    if (x->count != y->count) return x->count > y->count ? -1 : 1;
    return (x->tid > y->tid) - (x->tid < y->tid);
}

/* most preempted first; ties: the earlier first */
static int run_order(const void *a, const void *b) {
    const struct kept_run *x = a, *y = b;
    if (x->preempted_ns != y->preempted_ns) return x->preempted_ns > y->preempted_ns ? -1 : 1;
    return (x->start > y->start) - (x->start < y->start);
}

/* largest first; ties: the earlier first */
static int late_order(const void *a, const void *b) {
    const struct late *x = a, *y = b;
    if (x->latency != y->latency) return x->latency > y->latency ? -1 : 1;
    return (x->at > y->at) - (x->at < y->at);
}

/* A task's name as str: the kernel's bytes as UTF-8, a character the 15-byte cut split replaced by U+FFFD. */
static PyObject *comm_text(const char *comm) {
    return PyUnicode_DecodeUTF8(comm, (Py_ssize_t)strnlen(comm, COMM_LEN), "replace");
}

static PyObject *thread_dict(Reader *r, struct thread *t) {
    /* a thread still on a CPU ran until the window's end or the last event, whichever is first */
    int64_t run = t->run_ns;
    if (t->running) {
        uint64_t to = t->exited && t->exit_ts > t->in_ts ? t->exit_ts : r->last_ts;
        int64_t a = (int64_t)t->in_ts > r->win_start ? (int64_t)t->in_ts : r->win_start;
        int64_t b = (int64_t)to < r->win_end ? (int64_t)to : r->win_end;
        if (b > a) run += b - a;
    }
    /* the histogram as (bucket, count) of its buckets that are not empty: 4,352 counters per thread,
     * most of them zero, made a tuple each cost a cell of 1,024 threads 50 ms */
    int nlat = 0;
    for (int i = 0; t->hist && i < HIST_BUCKETS; i++) nlat += t->hist[i] != 0;
    PyObject *lat = PyTuple_New(nlat);
    if (!lat) return NULL;
    for (int i = 0, k = 0; t->hist && i < HIST_BUCKETS; i++) {
        if (!t->hist[i]) continue;
        PyObject *row = Py_BuildValue("(iK)", i, (unsigned long long)t->hist[i]);
        if (!row) {
            Py_DECREF(lat);
            return NULL;
        }
        PyTuple_SET_ITEM(lat, k++, row);
    }
    struct preemptor pre[MAX_PREEMPTORS];
    memcpy(pre, t->pre, sizeof pre);
    qsort(pre, (size_t)t->npre, sizeof *pre, preemptor_order);
    PyObject *pres = PyTuple_New(t->npre);
    if (!pres) goto fail_lat;
    for (int i = 0; i < t->npre; i++) {
        PyObject *p = Py_BuildValue("(iNiK)", pre[i].tid, comm_text(pre[i].comm), pre[i].prio, (unsigned long long)pre[i].count);
        if (!p) goto fail_pres;
        PyTuple_SET_ITEM(pres, i, p);
    }
    struct late worst[MAX_WORST];
    memcpy(worst, t->worst, sizeof worst);
    qsort(worst, (size_t)t->nworst, sizeof *worst, late_order);
    PyObject *worsts = PyTuple_New(t->nworst);
    if (!worsts) goto fail_pres;
    for (int i = 0; i < t->nworst; i++) {
        PyObject *w = Py_BuildValue("(LLiiNi)", (long long)worst[i].latency, (long long)worst[i].at, worst[i].cpu, worst[i].tid,
                                    comm_text(worst[i].comm), worst[i].prio);
        if (!w) goto fail_worst;
        PyTuple_SET_ITEM(worsts, i, w);
    }
    struct kept_run runs[MAX_RUNS];
    memcpy(runs, t->runs, sizeof runs);
    qsort(runs, (size_t)t->nruns, sizeof *runs, run_order);
    PyObject *runt = PyTuple_New(t->nruns);
    if (!runt) goto fail_worst;
    for (int i = 0; i < t->nruns; i++) {
        const struct taker *k = &runs[i].top;
        PyObject *w = Py_BuildValue("(LLLIiNiIL)", (long long)runs[i].start, (long long)runs[i].end, (long long)runs[i].preempted_ns,
                                    runs[i].preemptions, k->tid, comm_text(k->comm), k->prio, k->count, (long long)k->ns);
        if (!w) goto fail_runs;
        PyTuple_SET_ITEM(runt, i, w);
    }
    int ncpu = 0;
    for (int w = 0; w < CPU_WORDS; w++) ncpu += __builtin_popcountll(t->cpus[w]);
    PyObject *cpus = PyTuple_New(ncpu);
    if (!cpus) goto fail_runs;
    for (int c = 0, k = 0; c < CPU_WORDS * 64; c++)
        if (t->cpus[c / 64] & (1ULL << (c % 64))) PyTuple_SET_ITEM(cpus, k++, PyLong_FromLong(c));
    PyObject *d = Py_BuildValue(
        "{s:i,s:N,s:K,s:N,s:L,s:L,s:L,s:K,s:K,s:N,s:K,s:K,s:K,s:K,s:N,s:L,s:N,s:N,s:O}", "tid", t->tid, "comm", comm_text(t->comm), "wakeups",
        (unsigned long long)t->wakeups, "latency", lat, "latency_min", (long long)(t->wakeups ? t->lat_min : 0), "latency_max",
        (long long)(t->wakeups ? t->lat_max : 0), "latency_sum", (long long)t->lat_sum, "preemptions", (unsigned long long)t->preemptions,
        "voluntary", (unsigned long long)t->voluntary, "preemptors", pres, "other_preemptors", (unsigned long long)t->other_preemptors,
        "migrations", (unsigned long long)t->migrations, "cpu_changes", (unsigned long long)t->cpu_changes, "unseen_switch_ins", (unsigned long long)t->unseen_ins, "cpus", cpus, "run_ns",
        (long long)run, "worst", worsts, "runs", runt, "exited", t->exited ? Py_True : Py_False);
    return d; /* N: the tuples' references went to the dict (or were released on failure) */
fail_runs:
    Py_DECREF(runt);
fail_worst:
    Py_DECREF(worsts);
fail_pres:
    Py_DECREF(pres);
fail_lat:
    Py_DECREF(lat);
    return NULL;
}

static PyObject *Reader_result(Reader *r, PyObject *unused) {
    if (!ready(r)) return NULL;
    lock_nogil(r);
    PyObject *threads = PyList_New(0);
    PyObject *out = NULL;
    if (!threads) goto done;
    for (uint32_t i = 0; i < r->cap; i++) {
        struct thread *t = r->keys[i] ? r->slots[i] : NULL;
        if (!t || !t->seen) continue;
        PyObject *d = thread_dict(r, t);
        if (!d || PyList_Append(threads, d) < 0) {
            Py_XDECREF(d);
            goto done;
        }
        Py_DECREF(d);
    }
    out = Py_BuildValue("{s:O,s:K,s:K,s:K,s:K,s:K,s:K,s:K,s:K,s:K,s:L,s:L,s:K,s:I}", "threads", threads, "events",
                        (unsigned long long)r->events, "unknown", (unsigned long long)r->unknown, "malformed",
                        (unsigned long long)r->malformed, "untracked", (unsigned long long)r->untracked, "out_of_order",
                        (unsigned long long)r->out_of_order, "forced", (unsigned long long)r->forced, "missed_pages",
                        (unsigned long long)r->missed_pages, "lost_stored", (unsigned long long)r->lost_stored, "nomem",
                        (unsigned long long)r->nomem, "reader_cpu_ns", (long long)r->cpu_ns, "window_late_ns", (long long)r->window_late_ns, "held", (unsigned long long)r->nrec,
                        "tracked", r->nthreads);
done:
    pthread_mutex_unlock(&r->lock);
    Py_XDECREF(threads);
    return out;
}

static PyMethodDef Reader_methods[] = {
    {"track", (PyCFunction)Reader_track, METH_O, "track(tids): follow these threads (the kernel's pid filter holds them)"},
    {"window", (PyCFunction)Reader_window, METH_VARARGS, "window(start_ns, end_ns): only events inside count; end -1: open"},
    {"feed", (PyCFunction)Reader_feed, METH_VARARGS, "feed(cpu, pages): decode pages as trace_pipe_raw returns them (tests)"},
    {"start", (PyCFunction)Reader_start, METH_VARARGS, "start(files, interval_ns): read [(cpu, path)] in a native thread"},
    {"stop", (PyCFunction)Reader_stop, METH_NOARGS, "stop(): the thread's final drain, joined; every held event applied"},
    {"result", (PyCFunction)Reader_result, METH_NOARGS, "result() -> dict of the aggregates"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject ReaderType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "runner.run._trace.Reader",
    .tp_doc = PyDoc_STR("Reader(page_size, header, common_type, layouts, state_mask[, max_threads, hold_ns])"),
    .tp_basicsize = sizeof(Reader),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Reader_init,
    .tp_dealloc = (destructor)Reader_dealloc,
    .tp_methods = Reader_methods,
};

static PyObject *trace_hist_add(PyObject *mod, PyObject *args) {
    Py_buffer view;
    int i;
    if (!PyArg_ParseTuple(args, "w*i", &view, &i)) return NULL;
    if (view.len != (Py_ssize_t)(HIST_BUCKETS * sizeof(uint32_t)) || i < 0 || i >= HIST_BUCKETS) {
        PyBuffer_Release(&view);
        return PyErr_Format(PyExc_ValueError, "expected %d uint32 counters and a bucket among them", HIST_BUCKETS);
    }
    hist_add((uint32_t *)view.buf, i);
    PyBuffer_Release(&view);
    Py_RETURN_NONE;
}

static PyMethodDef trace_functions[] = {
    {"hist_add", trace_hist_add, METH_VARARGS, "hist_add(counts, i): count one wake-up in bucket i as the reader does (tests)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef trace_module = {
    PyModuleDef_HEAD_INIT, "runner.run._trace", "Native reader of the kernel's scheduler trace (tracefs ring-buffer pages).", -1,
    trace_functions,
};

PyMODINIT_FUNC PyInit__trace(void) {
    if (PyType_Ready(&ReaderType) < 0) return NULL;
    PyObject *m = PyModule_Create(&trace_module);
    if (!m) return NULL;
    Py_INCREF(&ReaderType);
    PyModule_AddObject(m, "Reader", (PyObject *)&ReaderType);
    PyObject *fields = PyTuple_New(K_COUNT);
    if (!fields) return NULL;
    for (int k = 0; k < K_COUNT; k++) {
        int nf = 0;
        while (nf < MAX_FIELDS && KIND_FIELDS[k][nf].name) nf++;
        PyObject *names = PyTuple_New(nf);
        if (!names) return NULL;
        for (int i = 0; i < nf; i++) PyTuple_SET_ITEM(names, i, PyUnicode_FromString(KIND_FIELDS[k][i].name));
        PyTuple_SET_ITEM(fields, k, Py_BuildValue("(sN)", KIND_NAMES[k], names));
    }
    PyModule_AddObject(m, "FIELDS", fields);
    PyModule_AddIntConstant(m, "BUCKETS", HIST_BUCKETS);
    PyModule_AddIntConstant(m, "MAX_PREEMPTORS", MAX_PREEMPTORS);
    PyModule_AddIntConstant(m, "MAX_WORST", MAX_WORST);
    PyModule_AddIntConstant(m, "MAX_HELD", MAX_RECS);
    /* the memory bound: a thread's aggregates, its histogram once it wakes, a held event */
    PyModule_AddIntConstant(m, "THREAD_BYTES", sizeof(struct thread));
    PyModule_AddIntConstant(m, "HIST_BYTES", HIST_BUCKETS * sizeof(uint32_t));
    PyModule_AddIntConstant(m, "HELD_BYTES", sizeof(struct rec));
    PyModule_AddIntConstant(m, "FK_UINT", FK_UINT);
    PyModule_AddIntConstant(m, "FK_INT", FK_INT);
    PyModule_AddIntConstant(m, "FK_CHARS", FK_CHARS);
    PyModule_AddIntConstant(m, "FK_DATA_LOC", FK_DATA_LOC);
    PyModule_AddIntConstant(m, "TYPE_PADDING", TYPE_PADDING);
    PyModule_AddIntConstant(m, "TYPE_TIME_EXTEND", TYPE_TIME_EXTEND);
    PyModule_AddIntConstant(m, "TYPE_TIME_STAMP", TYPE_TIME_STAMP);
    return m;
}
