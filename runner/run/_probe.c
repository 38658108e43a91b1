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
 * Buffer layout (little endian, all offsets in bytes), version 2:
 *   file header, 64 bytes:  magic "RSMP0002", u32 version, u32 nthreads,
 *                           u32 capacity, u32 slot_header_size, u32 sample_size,
 *                           u32 hist_buckets (0 when the group keeps none),
 *                           u64 slot_stride
 *   per thread, at 64 + i * slot_stride:
 *     slot header, 512 bytes (struct slot_header): totals and running figures
 *     histograms, 3 * hist_buckets u64 (latency, slack >= 0, -slack for slack < 0)
 *     then a second block of hist_buckets u64: callback wall time
 *     ring of capacity samples of 64 bytes (struct sample): sample n at n % capacity
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
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#define FILE_HEADER 64
#define SLOT_HEADER 512
#define SAMPLE_BYTES 64
#define MAX_CPU_WORDS 16

/* Log-linear histogram: values below 2 * HIST_SUB are their own bucket; above, each
 * power of two is split into HIST_SUB buckets.  Values from 2^HIST_TOP_BITS ns (about
 * 18 minutes) up share the last bucket; the exact maximum is kept beside it. */
#define HIST_SUB_BITS 7
#define HIST_SUB (1 << HIST_SUB_BITS)
#define HIST_TOP_BITS 40
#define HIST_BUCKETS ((HIST_TOP_BITS - HIST_SUB_BITS + 1) * HIST_SUB)
#define HIST_SETS 4 /* latency, slack >= 0, -slack, callback wall time */

enum work_kind { WORK_SLEEP = 0, WORK_PERIODIC = 1, WORK_SPIN = 2 };
enum slot_state { ST_CREATED = 0, ST_READY = 1, ST_RUNNING = 2, ST_DONE = 3, ST_FAILED = 4 };
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
    uint8_t reserved[SLOT_HEADER - 440];
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
};

_Static_assert(sizeof(struct slot_header) == SLOT_HEADER, "slot header size");
_Static_assert(sizeof(struct sample) == SAMPLE_BYTES, "sample size");

static inline int hist_index(int64_t v) {
    if (v < 0) v = 0;
    if (v < 2 * HIST_SUB) return (int)v;
    if (v >= (int64_t)1 << HIST_TOP_BITS) return HIST_BUCKETS - 1;
    int shift = 63 - __builtin_clzll((unsigned long long)v) - HIST_SUB_BITS;
    return (shift + 1) * HIST_SUB + (int)(v >> shift) - HIST_SUB;
}

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
    int ncpus;           /* 0: leave as is */
    int cpus[1024];
};

static void apply_settings(const struct settings *s, int32_t errs[3]) {
    errs[0] = errs[1] = errs[2] = 0;
    if (s->policy >= 0) {
        struct sched_param p = {.sched_priority = s->priority};
        if (sched_setscheduler(0, s->policy, &p) != 0) errs[0] = errno;
    }
    if (s->has_nice) {
        if (setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), s->nice) != 0) errs[1] = errno;
    }
    if (s->ncpus > 0) {
        cpu_set_t set;
        CPU_ZERO(&set);
        for (int i = 0; i < s->ncpus; i++) CPU_SET(s->cpus[i], &set);
        if (sched_setaffinity(0, sizeof(set), &set) != 0) errs[2] = errno;
    }
}

/* Fill a settings struct from Python values; returns -1 with an exception set. */
static int parse_settings(PyObject *policy, PyObject *priority, PyObject *nice, PyObject *cpus, struct settings *out) {
    memset(out, 0, sizeof(*out));
    out->policy = -1;
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
    struct sample *samples;
    uint64_t capacity;
    size_t stride;
    pthread_t thread;
    int started;
};

struct group {
    char *base;
    Py_ssize_t size;
    uint32_t nslots;
    uint32_t capacity;
    int with_hist;
    size_t stride;
    struct slot *slots;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int released;
    int64_t start_ns;
    int64_t end_ns;
    cpu_set_t all_cpus;
    long page_size;
};

static void burn(const struct work *w) {
    clockid_t clock = w->burn_wall ? CLOCK_MONOTONIC : CLOCK_THREAD_CPUTIME_ID;
    int64_t until = now_ns(clock) + w->burn_ns;
    while (now_ns(clock) < until) {
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
static void record_callback(struct slot *s, const struct sample *c) {
    struct slot_header *h = s->hdr;
    const struct work *w = &s->work;
    /* Skipped releases were answered by this wake-up too: each is as late as the wait for it. */
    for (int32_t k = c->missed; k >= 1; k--) record_latency(s, c->wake_ns - (c->scheduled_ns - k * w->period_ns));
    record_latency(s, c->wake_ns - c->scheduled_ns);
    uint64_t n = h->loops; /* this callback's number, from 1 */
    int64_t slack = c->scheduled_ns + w->period_ns - c->end_ns;
    int64_t wall = c->end_ns - c->wake_ns;
    if (slack < 0) h->overruns++;
    if (n == 1 || slack < h->slack_min) h->slack_min = slack;
    if (n == 1 || slack > h->slack_max) h->slack_max = slack;
    welford(n, &h->slack_mean, &h->slack_m2, slack);
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
        if (slack >= 0)
            s->hist[HIST_BUCKETS + hist_index(slack)]++;
        else
            s->hist[2 * HIST_BUCKETS + hist_index(-slack)]++;
        s->hist[3 * HIST_BUCKETS + hist_index(wall)]++;
    }
    if (s->capacity == 0 || w->ring_mode == RING_NONE) return;
    if (w->ring_mode == RING_OUTLIERS && !(c->missed || slack < 0 || (w->bound_ns > 0 && c->wake_ns - c->scheduled_ns + c->missed * w->period_ns > w->bound_ns)))
        return;
    uint64_t at = h->count;
    s->samples[at % s->capacity] = *c;
    atomic_store_explicit((_Atomic uint64_t *)&h->count, at + 1, memory_order_release);
}

static void run_periodic(struct slot *s) {
    struct group *g = s->group;
    struct slot_header *h = s->hdr;
    const struct work *w = &s->work;
    int64_t next = g->start_ns + w->offset_ns;
    int64_t ru0[4], ru1[4];
    int32_t missed = 0;
    struct sample c;
    memset(&c, 0, sizeof(c));
    while (!g_stop && next < g->end_ns) {
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
        note_cpu(h, cpu0);
        note_cpu(h, cpu1);
        h->loops++;
        record_callback(s, &c);
        missed = 0;
        next += w->period_ns;
        int64_t now = now_ns(CLOCK_MONOTONIC);
        while (next < now) { /* overran or woke late: skip the releases already past, as ROS 2 timers do */
            if (next < g->end_ns) missed++;
            next += w->period_ns;
        }
        h->missed += (uint64_t)missed;
    }
}

static void run_spin(struct slot *s) {
    struct group *g = s->group;
    uint64_t loops = 0;
    while (!g_stop) {
        int64_t t = now_ns(CLOCK_MONOTONIC);
        if (t >= g->end_ns) break;
        if ((loops & 1023) == 0) note_cpu(s->hdr, sched_getcpu());
        loops++;
    }
    s->hdr->loops = loops;
}

static void run_sleep(struct slot *s) {
    struct group *g = s->group;
    while (!g_stop) {
        int64_t left = g->end_ns - now_ns(CLOCK_MONOTONIC);
        if (left <= 0) break;
        struct timespec ts = to_ts(left);
        struct pollfd pfd = {.fd = g_stop_pipe[0], .events = POLLIN};
        ppoll(g_stop_pipe[0] >= 0 ? &pfd : NULL, g_stop_pipe[0] >= 0 ? 1 : 0, &ts, NULL);
        note_cpu(s->hdr, sched_getcpu());
    }
}

/* Wait for the gate, run the work, record totals.  Called with the GIL released. */
static void run_slot(struct slot *s) {
    struct group *g = s->group;
    pthread_mutex_lock(&g->lock);
    while (!g->released) pthread_cond_wait(&g->cond, &g->lock);
    pthread_mutex_unlock(&g->lock);
    if (s->work.kind != WORK_PERIODIC) sleep_until(g->start_ns);
    struct slot_header *h = s->hdr;
    h->work_start_ns = now_ns(CLOCK_MONOTONIC);
    read_ru(h->start_ru);
    atomic_store((_Atomic int32_t *)&h->state, ST_RUNNING);
    switch (s->work.kind) {
        case WORK_PERIODIC: run_periodic(s); break;
        case WORK_SPIN: run_spin(s); break;
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
    atomic_store((_Atomic int32_t *)&s->hdr->state, ST_READY);
    run_slot(s);
    return NULL;
}

/* ------------------------------------------------------------ Group object */

typedef struct {
    PyObject_HEAD
    struct group g;
    Py_buffer view;
    int has_view;
} GroupObject;

static void Group_dealloc(GroupObject *self) {
    if (self->g.slots) {
        pthread_mutex_lock(&self->g.lock);
        if (!self->g.released) { /* never started: let parked threads run an empty work and exit */
            self->g.start_ns = self->g.end_ns = 0;
            self->g.released = 1;
            pthread_cond_broadcast(&self->g.cond);
        }
        pthread_mutex_unlock(&self->g.lock);
        for (uint32_t i = 0; i < self->g.nslots; i++) {
            if (self->g.slots[i].started) {
                Py_BEGIN_ALLOW_THREADS
                pthread_join(self->g.slots[i].thread, NULL);
                Py_END_ALLOW_THREADS
            }
        }
        PyMem_Free(self->g.slots);
    }
    if (self->has_view) PyBuffer_Release(&self->view);
    pthread_mutex_destroy(&self->g.lock);
    pthread_cond_destroy(&self->g.cond);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Group_init(GroupObject *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"buffer", "nthreads", "capacity", "all_cpus", "histograms", NULL};
    PyObject *buffer, *all_cpus;
    unsigned int nthreads, capacity;
    int with_hist = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OIIO|p", kwlist, &buffer, &nthreads, &capacity, &all_cpus, &with_hist))
        return -1;
    if (PyObject_GetBuffer(buffer, &self->view, PyBUF_WRITABLE) != 0) return -1;
    self->has_view = 1;
    size_t stride = SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0) + (size_t)capacity * sizeof(struct sample);
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
    g->page_size = sysconf(_SC_PAGESIZE);
    pthread_mutex_init(&g->lock, NULL);
    pthread_cond_init(&g->cond, NULL);
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
    memcpy(g->base, "RSMP0002", 8);
    uint32_t meta[6] = {2, nthreads, capacity, SLOT_HEADER, SAMPLE_BYTES, with_hist ? HIST_BUCKETS : 0};
    memcpy(g->base + 8, meta, sizeof(meta));
    uint64_t stride64 = g->stride;
    memcpy(g->base + 32, &stride64, sizeof(stride64));
    for (uint32_t i = 0; i < nthreads; i++) {
        struct slot *s = &g->slots[i];
        char *at = g->base + FILE_HEADER + (size_t)i * g->stride;
        s->group = g;
        s->index = (int)i;
        s->hdr = (struct slot_header *)at;
        s->hist = with_hist ? (uint64_t *)(at + SLOT_HEADER) : NULL;
        s->samples = (struct sample *)(at + SLOT_HEADER + (with_hist ? HIST_SETS * HIST_BUCKETS * sizeof(uint64_t) : 0));
        s->capacity = capacity;
        s->stride = g->stride;
        memset(s->hdr, 0, SLOT_HEADER);
        s->hdr->minflt_first = -1;
    }
    return 0;
}

static int parse_work(PyObject *work, struct work *out) {
    memset(out, 0, sizeof(*out));
    long long kind, period, burn_ns, alloc, offset, bound = 0;
    int wall, spin = 0, ring = RING_ALL;
    if (!PyArg_ParseTuple(work, "LLLpLL|pLi", &kind, &period, &burn_ns, &wall, &alloc, &offset, &spin, &bound, &ring)) return -1;
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
"spawn(index, name, work, policy, priority, nice, cpus, explicit)\n\n"
"Create a thread from the calling thread (so it inherits the caller's settings\n"
"unless explicit is true), name it, let it apply its own settings, and park it\n"
"at the start gate.  work is (kind, period_ns, burn_ns, burn_wall, alloc_bytes,\n"
"offset_ns[, wait_spin, bound_ns, ring_mode]).  Returns when the thread is created;\n"
"see wait_ready().");

static PyObject *Group_spawn(GroupObject *self, PyObject *args) {
    unsigned int index;
    const char *name;
    PyObject *work, *policy, *priority, *nice, *cpus;
    int explicit_defaults;
    if (!PyArg_ParseTuple(args, "IsOOOOOp", &index, &name, &work, &policy, &priority, &nice, &cpus, &explicit_defaults))
        return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    if (s->started) {
        PyErr_Format(PyExc_ValueError, "slot %u already has a thread", index);
        return NULL;
    }
    if (parse_work(work, &s->work) || parse_settings(policy, priority, nice, cpus, &s->own)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->explicit_defaults = explicit_defaults;
    pthread_attr_t attr;
    int rc = pthread_getattr_default_np(&attr);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    if (explicit_defaults) {
        struct sched_param p = {.sched_priority = 0};
        pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
        pthread_attr_setschedpolicy(&attr, SCHED_OTHER);
        pthread_attr_setschedparam(&attr, &p);
        pthread_attr_setaffinity_np(&attr, sizeof(cpu_set_t), &self->g.all_cpus);
    }
    Py_BEGIN_ALLOW_THREADS
    rc = pthread_create(&s->thread, &attr, thread_main, s);
    Py_END_ALLOW_THREADS
    pthread_attr_destroy(&attr);
    if (rc) {
        errno = rc;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    s->started = 1;
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
    if (!s || parse_work(work, &s->work)) return NULL;
    snprintf(s->name, sizeof(s->name), "%s", name);
    s->hdr->tid = (int32_t)syscall(SYS_gettid);
    s->own.policy = -1;
    prefault_slot(s);
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

PyDoc_STRVAR(release_doc, "release(start_ns, end_ns)\n\nOpen the gate: every thread starts its work at start_ns (CLOCK_MONOTONIC) and stops at end_ns.");

static PyObject *Group_release(GroupObject *self, PyObject *args) {
    long long start, end;
    if (!PyArg_ParseTuple(args, "LL", &start, &end)) return NULL;
    pthread_mutex_lock(&self->g.lock);
    self->g.start_ns = start;
    self->g.end_ns = end;
    self->g.released = 1;
    pthread_cond_broadcast(&self->g.cond);
    pthread_mutex_unlock(&self->g.lock);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(run_main_doc, "run_main(index)\n\nRun the adopted main thread's work in the calling thread, GIL released, after the gate opens.");

static PyObject *Group_run_main(GroupObject *self, PyObject *args) {
    unsigned int index;
    if (!PyArg_ParseTuple(args, "I", &index)) return NULL;
    struct slot *s = get_slot(self, index);
    if (!s) return NULL;
    Py_BEGIN_ALLOW_THREADS
    run_slot(s);
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyDoc_STRVAR(join_doc, "join()\n\nJoin every spawned thread, GIL released.");

static PyObject *Group_join(GroupObject *self, PyObject *Py_UNUSED(ignored)) {
    for (uint32_t i = 0; i < self->g.nslots; i++) {
        struct slot *s = &self->g.slots[i];
        if (!s->started) continue;
        Py_BEGIN_ALLOW_THREADS
        pthread_join(s->thread, NULL);
        Py_END_ALLOW_THREADS
        s->started = 0;
    }
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
    PyObject *policy, *priority, *nice, *cpus;
    if (!PyArg_ParseTuple(args, "OOOO", &policy, &priority, &nice, &cpus)) return NULL;
    struct settings s;
    if (parse_settings(policy, priority, nice, cpus, &s)) return NULL;
    int32_t errs[3];
    apply_settings(&s, errs);
    return Py_BuildValue("(iii)", errs[0], errs[1], errs[2]);
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

static PyObject *probe_stopped(PyObject *mod, PyObject *Py_UNUSED(ignored)) {
    return PyBool_FromLong(g_stop);
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
    int npids;
    pid_t pids[4096];
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
            for (int i = 0; i < w->npids; i++) kill(-w->pids[i], SIGKILL);
            for (int i = 0; i < w->npids; i++) kill(w->pids[i], SIGKILL);
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
    pthread_mutex_lock(&self->lock);
    self->npids = 0;
    for (Py_ssize_t i = 0; i < PySequence_Fast_GET_SIZE(seq) && self->npids < 4096; i++)
        self->pids[self->npids++] = (pid_t)PyLong_AsLong(PySequence_Fast_GET_ITEM(seq, i));
    self->deadline_ns = deadline;
    self->fired = 0;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
    Py_DECREF(seq);
    if (PyErr_Occurred()) return NULL;
    Py_RETURN_NONE;
}

static PyObject *Watchdog_disarm(WatchdogObject *self, PyObject *Py_UNUSED(ignored)) {
    pthread_mutex_lock(&self->lock);
    self->deadline_ns = 0;
    self->npids = 0;
    pthread_cond_broadcast(&self->cond);
    pthread_mutex_unlock(&self->lock);
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
    {"apply", probe_apply, METH_VARARGS, "apply(policy, priority, nice, cpus) -> (err_sched, err_nice, err_cpus) for the calling thread"},
    {"set_name", probe_set_name, METH_VARARGS, "set_name(name): prctl(PR_SET_NAME) on the calling thread"},
    {"lock_memory", probe_lock_memory, METH_NOARGS, "mlockall(MCL_CURRENT|MCL_FUTURE), no heap trimming, no mmap'd blocks"},
    {"preallocate", probe_preallocate, METH_VARARGS, "preallocate(bytes): grow the heap by bytes, fault it in, keep it"},
    {"set_default_stacksize", probe_set_default_stacksize, METH_VARARGS, "default stack size of threads created later"},
    {"install_stop_handler", probe_install_stop_handler, METH_NOARGS, "SIGTERM/SIGINT/SIGUSR1 stop every loop of this process"},
    {"set_pdeathsig", probe_set_pdeathsig, METH_VARARGS, "set_pdeathsig(sig): receive sig when the parent dies"},
    {"stopped", probe_stopped, METH_NOARGS, "True once a stop signal arrived"},
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
    PyModule_AddIntConstant(m, "SLOT_HEADER", SLOT_HEADER);
    PyModule_AddIntConstant(m, "SAMPLE_SIZE", sizeof(struct sample));
    PyModule_AddIntConstant(m, "HIST_BUCKETS", HIST_BUCKETS);
    PyModule_AddIntConstant(m, "HIST_SUB_BITS", HIST_SUB_BITS);
    PyModule_AddIntConstant(m, "HIST_SETS", HIST_SETS);
    PyModule_AddIntConstant(m, "RING_NONE", RING_NONE);
    PyModule_AddIntConstant(m, "RING_ALL", RING_ALL);
    PyModule_AddIntConstant(m, "RING_OUTLIERS", RING_OUTLIERS);
    PyModule_AddIntConstant(m, "WORK_SLEEP", WORK_SLEEP);
    PyModule_AddIntConstant(m, "WORK_PERIODIC", WORK_PERIODIC);
    PyModule_AddIntConstant(m, "WORK_SPIN", WORK_SPIN);
    return m;
}
