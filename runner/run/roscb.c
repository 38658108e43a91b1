/*
 * The runner's libtracetools interposer: preloaded (LD_PRELOAD, by path) into a `command:` program, it defines the
 * `ros_trace_*` functions rcl, rclcpp and the rmw libraries call at every instrumented point, records what the runner
 * needs into the file named by RUNNER_ROSCB (layout: roscb.h), and forwards every call to the real function
 * (dlsym(RTLD_NEXT), looked up at a hook's first call and kept), so a `ros2 trace` session still sees its events.
 *
 * - Without RUNNER_ROSCB (or with a file of another layout) it records nothing and only forwards.  A program without
 *   libtracetools never calls a hook; one whose own code defines the functions is found first and never reaches us.
 * - The hot path (callback_start/end, the executor's, rmw_take, rcl_publish, rmw_publish) allocates nothing, takes
 *   no lock and makes no system call but the clocks (vDSO), sched_getcpu (vDSO/rseq) and getrusage(RUSAGE_THREAD):
 *   thread state is initial-exec TLS, records go to the thread's own ring and a full ring overwrites its oldest
 *   (the runner counts what it missed).  The first hook of a process maps the file and claims a process block; the
 *   first of a thread claims a slot (an atomic add, gettid, its name) and backs it with memory (`reserve`: a
 *   full /dev/shm refuses the thread rather than killing the program with a SIGBUS).
 * - fork: the child forgets the parent's block and slots (pthread_atfork) and claims its own at its first hook;
 *   exec loads the library afresh from the inherited environment.
 * - Not defined on purpose: ros_trace_compile_status (`ros2 run tracetools status` must tell the truth), and every
 *   ros_trace_enabled_X but rclcpp_callback_register's (no other argument computation is forced on the program).
 * - rmw_publish has one argument up to Iron and three from Jazzy: it is defined with three, reads the others only
 *   when the real library is Jazzy's or later, and forwards with the real arity (x86-64 SysV and AAPCS64 pass them
 *   in registers, the caller cleans up: the ROS 2 Tier 1 targets).
 */
#define _GNU_SOURCE
#include "roscb.h"

#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#if !defined(__x86_64__) && !defined(__aarch64__)
#error "the interposer forwards rmw_publish by its real arity, which only x86-64 and aarch64 calling conventions allow"
#endif

#define HOOK __attribute__((visibility("default")))
#define TLS __attribute__((tls_model("initial-exec"))) static __thread
#define LIKELY(x) __builtin_expect(!!(x), 1)
#define UNLIKELY(x) __builtin_expect(!!(x), 0)

/* ---- the real functions, each looked up at its hook's first call ---- */

static char unresolved_mark;
#define UNRESOLVED ((void *)&unresolved_mark)

static void *real_of(void *_Atomic *cache, const char *name) {
    void *fn = atomic_load_explicit(cache, memory_order_acquire);
    if (UNLIKELY(fn == UNRESOLVED)) {
        fn = dlsym(RTLD_NEXT, name); /* NULL: no such function after us (no libtracetools, or an older one) */
        atomic_store_explicit(cache, fn, memory_order_release);
    }
    return fn;
}

#define REAL(name) real_of(&real_##name, "ros_trace_" #name)
#define DECLARE_REAL(name) static void *_Atomic real_##name = UNRESOLVED;
#define FORWARD(name, proto, ...)                                                                                         \
    do {                                                                                                                  \
        void *fn_ = REAL(name);                                                                                           \
        if (fn_) ((void(*) proto)fn_)(__VA_ARGS__);                                                                       \
    } while (0)

DECLARE_REAL(rcl_init)
DECLARE_REAL(rcl_node_init)
DECLARE_REAL(rcl_publisher_init)
DECLARE_REAL(rcl_subscription_init)
DECLARE_REAL(rclcpp_subscription_init)
DECLARE_REAL(rclcpp_subscription_callback_added)
DECLARE_REAL(rcl_service_init)
DECLARE_REAL(rclcpp_service_callback_added)
DECLARE_REAL(rcl_timer_init)
DECLARE_REAL(rclcpp_timer_callback_added)
DECLARE_REAL(rclcpp_timer_link_node)
DECLARE_REAL(rclcpp_callback_register)
DECLARE_REAL(enabled_rclcpp_callback_register)
DECLARE_REAL(do_rclcpp_callback_register)
DECLARE_REAL(rclcpp_executor_wait_for_work)
DECLARE_REAL(rclcpp_executor_get_next_ready)
DECLARE_REAL(rclcpp_executor_execute)
DECLARE_REAL(rmw_take)
DECLARE_REAL(rcl_publish)
DECLARE_REAL(rmw_publish)
DECLARE_REAL(callback_start)
DECLARE_REAL(callback_end)

/* ---- the process: its file and block ---- */

enum { P_UNKNOWN = 0, P_BUSY = 1, P_ON = 2, P_OFF = 3 };

static _Atomic int g_state = P_UNKNOWN;
static _Atomic unsigned g_generation = 1; /* bumped by fork: a thread's slot of another generation is not its process's */
static struct roscb_file *g_file;
static struct roscb_proc *g_proc;
static char *g_arena;
static unsigned g_proc_index;
static _Atomic int g_arity; /* rmw_publish's arguments in the real library: 1 or 3; 0 until asked */
static bool g_forked; /* the next block claimed is a forked child's */
static pthread_key_t g_key;
static bool g_key_made;
static char g_path[4096]; /* RUNNER_ROSCB as the file was mapped, and which file it was */
static dev_t g_dev;
static ino_t g_ino;
static _Atomic(uint64_t) g_rosout[32]; /* /rosout publishers (rcl and rmw handles): their publishes are not recorded */

static int64_t now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

/* rmw_publish's arity: 3 where the real library is Iron's successor (it has the enabled_ API and is not Iron), else 1.
 * Unknown (no real library) counts as 1: the two arguments more are then never read. */
static int publish_arity(void) {
    int arity = atomic_load_explicit(&g_arity, memory_order_relaxed);
    if (UNLIKELY(!arity)) {
        const char *distro = getenv("ROS_DISTRO");
        bool iron = distro && strcmp(distro, "iron") == 0;
        arity = dlsym(RTLD_NEXT, "ros_trace_enabled_callback_start") && !iron ? 3 : 1;
        atomic_store_explicit(&g_arity, arity, memory_order_relaxed);
    }
    return arity;
}

/* ---- a thread: its slot and callback stack, in TLS ---- */

struct frame {
    uint64_t cb;
    int64_t start_ns, wake_ns, src_ts, age_ns;
    uint64_t take;
    long ru[4]; /* nivcsw, nvcsw, minflt, majflt */
    int64_t cpu_us;
    uint32_t seq;
    int16_t cpu;
    uint8_t flags;
};

struct tstate {
    unsigned generation; /* g_generation when the slot was claimed (0: not yet) */
    bool refused;        /* every slot was taken: this thread records nothing */
    struct roscb_slot *slot;
    char *ring;
    uint64_t count;
    uint32_t capacity;
    uint32_t seq;
    int depth;
    unsigned too_deep; /* callbacks started beyond ROSCB_STACK and not ended yet */
    struct frame frames[ROSCB_STACK];
    bool waiting;
    int64_t wake_ns;
    uint64_t take, take_src;
    bool take_valid;
    uint64_t last_rcl_pub;
};

TLS struct tstate t_state;

static void process_init(void);

/* The process's state, settled at its first hook (another thread's first hook at the same moment is not recorded). */
static inline bool process_on(void) {
    int s = atomic_load_explicit(&g_state, memory_order_acquire);
    if (LIKELY(s == P_ON)) return true;
    if (s == P_UNKNOWN) {
        int expected = P_UNKNOWN;
        if (atomic_compare_exchange_strong(&g_state, &expected, P_BUSY)) process_init();
        return atomic_load_explicit(&g_state, memory_order_acquire) == P_ON;
    }
    return false;
}

static void thread_claim(struct tstate *t);

/* The calling thread's state with a slot of this process, or NULL (off, refused). */
static inline struct tstate *thread_on(void) {
    if (!process_on()) return NULL;
    struct tstate *t = &t_state;
    if (UNLIKELY(t->generation != atomic_load_explicit(&g_generation, memory_order_relaxed))) thread_claim(t);
    return t->slot ? t : NULL;
}

/* A record into the ring, then its count (release: a reader that sees the count sees the record).  The fence first
 * orders the previous count before this record's bytes, which overwrite the oldest record: a reader that copied the
 * ring and then read count c knows that no record past c had begun to overwrite its copy (roscb.py `_take`). */
static inline void put(struct tstate *t, const void *record) {
    atomic_thread_fence(memory_order_release);
    memcpy(t->ring + (t->count % t->capacity) * ROSCB_RECORD, record, ROSCB_RECORD);
    t->count++;
    atomic_store_explicit((_Atomic uint64_t *)&t->slot->count, t->count, memory_order_release);
}

static void set_open(struct tstate *t) {
    struct roscb_slot *s = t->slot;
    const struct frame *top = t->depth > 0 ? &t->frames[t->depth - 1] : NULL;
    s->open_cb = top ? top->cb : 0;
    s->open_since_ns = top ? top->start_ns : 0;
    atomic_store_explicit((_Atomic uint32_t *)&s->open_depth, (uint32_t)t->depth, memory_order_release);
}

static void usage(long ru[4], int64_t *cpu_us) {
    struct rusage r;
    if (getrusage(RUSAGE_THREAD, &r) != 0) memset(&r, 0, sizeof r);
    ru[0] = r.ru_nivcsw;
    ru[1] = r.ru_nvcsw;
    ru[2] = r.ru_minflt;
    ru[3] = r.ru_majflt;
    *cpu_us = (int64_t)(r.ru_utime.tv_sec + r.ru_stime.tv_sec) * 1000000 + r.ru_utime.tv_usec + r.ru_stime.tv_usec;
}

/* Close the frame at `index` (and write its record) with the end readings given. */
static void close_frame(struct tstate *t, int index, int64_t end_ns, int cpu, const long ru[4], int64_t cpu_us, uint8_t extra) {
    const struct frame *f = &t->frames[index];
    struct roscb_callback r = {0};
    r.type = ROSCB_CALLBACK;
    r.flags = f->flags | extra;
    r.depth = (uint8_t)index;
    r.cpu_start = f->cpu;
    r.cpu_end = (int16_t)cpu;
    r.cb = f->cb;
    r.start_ns = f->start_ns;
    r.end_ns = end_ns;
    r.wake_ns = f->wake_ns;
    r.src_ts = f->src_ts;
    r.age_ns = f->age_ns;
    r.take_handle = f->take;
    r.nivcsw = (uint32_t)(ru[0] - f->ru[0]);
    r.nvcsw = (uint32_t)(ru[1] - f->ru[1]);
    r.minflt = (uint32_t)(ru[2] - f->ru[2]);
    r.majflt = (uint32_t)(ru[3] - f->ru[3]);
    r.seq = f->seq;
    r.cpu_us = (uint32_t)(cpu_us - f->cpu_us);
    put(t, &r);
}

/* A thread that exits inside callbacks: they are closed as unterminated, the slot marked exited. */
static void thread_gone(void *arg) {
    struct tstate *t = arg;
    if (!t || !t->slot || t->generation != atomic_load(&g_generation)) return;
    if (t->depth) {
        long ru[4];
        int64_t cpu_us, end = now_ns(CLOCK_MONOTONIC);
        usage(ru, &cpu_us);
        while (t->depth > 0) {
            t->depth--;
            close_frame(t, t->depth, end, sched_getcpu(), ru, cpu_us, ROSCB_CB_UNTERMINATED);
        }
        set_open(t);
    }
    atomic_store_explicit((_Atomic uint32_t *)&t->slot->state, 2, memory_order_release);
}

/* Back [at, at + size) of the file's mapping with memory now, or say it cannot be: a page of the sparse file that tmpfs
 * has no room for (a full /dev/shm; a container's is 64 MiB) is a SIGBUS at the write that first touches it, which
 * would kill the program because of the runner.  MADV_POPULATE_WRITE (Linux 5.14) faults the pages in or fails; an
 * older kernel allocates them with fallocate through the file's name, reopened (the descriptor the mapping was made
 * with is closed: a program may close every descriptor) and checked to be the same file. */
static bool reserve(void *at, size_t size) {
#ifndef MADV_POPULATE_WRITE
#define MADV_POPULATE_WRITE 23
#endif
    if (madvise(at, size, MADV_POPULATE_WRITE) == 0) return true;
    if (errno != EINVAL) return false;
    int fd = open(g_path, O_RDWR | O_CLOEXEC | O_NOFOLLOW);
    if (fd < 0) return false;
    struct stat st;
    bool ok = fstat(fd, &st) == 0 && st.st_dev == g_dev && st.st_ino == g_ino &&
              fallocate(fd, 0, (off_t)((char *)at - (char *)g_file), (off_t)size) == 0;
    close(fd);
    return ok;
}

static void thread_claim(struct tstate *t) {
    unsigned generation = atomic_load(&g_generation);
    t->generation = generation;
    t->slot = NULL;
    t->depth = 0; /* a forked child's frames are its parent's callbacks; the take and wake-up before this hook are its own */
    t->too_deep = 0;
    if (t->refused) return;
    uint32_t index = atomic_fetch_add((_Atomic uint32_t *)&g_file->next_thread, 1);
    if (index >= g_file->max_threads) {
        atomic_fetch_add((_Atomic uint64_t *)&g_file->threads_refused, 1);
        t->refused = true;
        return;
    }
    char *base = (char *)g_file + g_file->header_size + (size_t)g_file->max_procs * g_file->proc_size;
    struct roscb_slot *s = (struct roscb_slot *)(base + (size_t)index * g_file->slot_size);
    if (!reserve(s, g_file->slot_size)) { /* no room for its ring: refused, as when every slot is taken */
        atomic_fetch_add((_Atomic uint64_t *)&g_file->threads_refused, 1);
        t->refused = true;
        return;
    }
    s->tid = (int32_t)syscall(SYS_gettid);
    s->pid = (int32_t)getpid();
    s->proc = g_proc_index;
    prctl(PR_GET_NAME, (unsigned long)s->comm, 0, 0, 0);
    t->slot = s;
    t->ring = (char *)s + ROSCB_SLOT_HEADER;
    t->capacity = g_file->capacity;
    t->count = 0;
    t->seq = 0;
    atomic_store_explicit((_Atomic uint32_t *)&s->state, 1, memory_order_release);
    if (g_key_made) pthread_setspecific(g_key, t);
}

static void after_fork(void) {
    /* The child is one thread, a copy of the forking one: nothing of the parent's block or slots is its own. */
    if (atomic_load(&g_state) == P_ON) {
        g_forked = true;
        atomic_store(&g_state, P_UNKNOWN);
    }
    atomic_fetch_add(&g_generation, 1);
    t_state.refused = false;
}

static void copy_tail(uint8_t *out, size_t size, const char *text) {
    size_t n = strlen(text);
    const char *from = n >= size ? text + n - (size - 1) : text;
    memcpy(out, from, strlen(from) + 1);
}

static void process_init(void) {
    static bool fork_handler;
    struct roscb_file *f = g_file; /* a forked child's: the parent's mapping, checked already */
    if (!f) {
        const char *path = getenv("RUNNER_ROSCB");
        int fd = path && *path ? open(path, O_RDWR | O_CLOEXEC | O_NOFOLLOW) : -1;
        struct stat st;
        void *map = MAP_FAILED;
        if (fd >= 0 && fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && (size_t)st.st_size >= ROSCB_FILE_HEADER)
            map = mmap(NULL, (size_t)st.st_size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
        if (fd >= 0) close(fd);
        if (map == MAP_FAILED) {
            atomic_store(&g_state, P_OFF);
            return;
        }
        f = map;
        if (f->magic != ROSCB_MAGIC || f->version != ROSCB_VERSION || f->header_size != ROSCB_FILE_HEADER ||
            f->record_size != ROSCB_RECORD || f->proc_size != ROSCB_PROC_BYTES || f->capacity == 0 ||
            f->slot_size != ROSCB_SLOT_HEADER + (uint64_t)f->capacity * ROSCB_RECORD ||
            (uint64_t)f->header_size + (uint64_t)f->max_procs * f->proc_size + (uint64_t)f->max_threads * f->slot_size >
                (uint64_t)st.st_size) {
            munmap(map, (size_t)st.st_size); /* another layout: the runner says so, finding no process in it */
            atomic_store(&g_state, P_OFF);
            return;
        }
        g_file = f;
        g_dev = st.st_dev;
        g_ino = st.st_ino;
        if (strlen(path) < sizeof g_path) strcpy(g_path, path);
    }
    uint32_t index = atomic_fetch_add((_Atomic uint32_t *)&f->next_proc, 1);
    if (index >= f->max_procs) {
        atomic_fetch_add((_Atomic uint64_t *)&f->procs_refused, 1);
        atomic_store(&g_state, P_OFF);
        return;
    }
    struct roscb_proc *p = (struct roscb_proc *)((char *)f + f->header_size + (size_t)index * f->proc_size);
    if (!reserve(p, f->proc_size)) {
        atomic_fetch_add((_Atomic uint64_t *)&f->procs_refused, 1);
        atomic_store(&g_state, P_OFF);
        return;
    }
    p->pid = (int32_t)getpid();
    p->ppid = (int32_t)getppid();
    p->first_hook_ns = now_ns(CLOCK_MONOTONIC);
    char exe[4096];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    exe[n > 0 ? n : 0] = 0;
    copy_tail(p->exe, sizeof p->exe, exe);
    uint32_t flags = g_forked ? ROSCB_P_FORKED : 0;
    if (dlsym(RTLD_NEXT, "ros_trace_callback_start")) flags |= ROSCB_P_TRACETOOLS;
    bool enabled_api = dlsym(RTLD_NEXT, "ros_trace_enabled_callback_start") != NULL;
    if (enabled_api) flags |= ROSCB_P_ENABLED;
    if (publish_arity() == 3) flags |= ROSCB_P_PUBLISH3;
    void *first = dlsym(RTLD_DEFAULT, "ros_trace_callback_start");
    Dl_info info, self;
    bool ours = dladdr((void *)process_init, &self) && dladdr(first, &info) && info.dli_fbase == self.dli_fbase;
    if (first && !ours) {
        flags |= ROSCB_P_SHADOWED;
        copy_tail(p->shadowed_by, sizeof p->shadowed_by, dladdr(first, &info) && info.dli_fname ? info.dli_fname : "?");
    }
    p->flags = flags;
    g_proc = p;
    g_arena = (char *)p + ROSCB_PROC_HEADER;
    g_proc_index = index;
    atomic_store_explicit((_Atomic uint32_t *)&p->state, 1, memory_order_release);
    if (!g_key_made) g_key_made = pthread_key_create(&g_key, thread_gone) == 0;
    if (!fork_handler) fork_handler = pthread_atfork(NULL, NULL, after_fork) == 0;
    atomic_store_explicit(&g_state, P_ON, memory_order_release);
}

/* ---- meta records (init time: strings copied into the process's arena) ---- */

static uint32_t keep(const char *text, uint32_t *len, uint8_t *flags) {
    *len = 0;
    if (!text || !*text) return 0;
    size_t n = strnlen(text, ROSCB_STRING_MAX);
    if (n == ROSCB_STRING_MAX) *flags |= ROSCB_META_TRUNCATED;
    uint64_t at = atomic_fetch_add((_Atomic uint64_t *)&g_proc->arena_used, n + 1);
    if (at + n + 1 > ROSCB_ARENA) {
        atomic_fetch_add((_Atomic uint64_t *)&g_proc->strings_dropped, 1);
        *flags |= ROSCB_META_TRUNCATED;
        return 0;
    }
    memcpy(g_arena + at, text, n);
    g_arena[at + n] = 0;
    *len = (uint32_t)n;
    return (uint32_t)at;
}

static void meta(int kind, const void *a, const void *b, const void *c, int64_t d, int64_t e, uint32_t clock, const char *s1,
                 const char *s2) {
    struct tstate *t = thread_on();
    if (!t) return;
    struct roscb_meta r = {0};
    r.type = (uint16_t)kind;
    r.a = (uint64_t)(uintptr_t)a;
    r.b = (uint64_t)(uintptr_t)b;
    r.c = (uint64_t)(uintptr_t)c;
    r.d = d;
    r.e = e;
    r.clock = clock;
    r.t_ns = now_ns(CLOCK_MONOTONIC);
    r.s1_off = keep(s1, &r.s1_len, &r.flags);
    r.s2_off = keep(s2, &r.s2_len, &r.flags);
    put(t, &r);
}

static void rosout_add(const void *handle) {
    uint64_t h = (uint64_t)(uintptr_t)handle;
    for (size_t i = 0; h && i < sizeof g_rosout / sizeof g_rosout[0]; i++) {
        uint64_t expected = 0;
        if (atomic_compare_exchange_strong(&g_rosout[i], &expected, h) || expected == h) return;
    }
}

static bool rosout_has(uint64_t h) {
    for (size_t i = 0; i < sizeof g_rosout / sizeof g_rosout[0]; i++) {
        uint64_t v = atomic_load_explicit(&g_rosout[i], memory_order_relaxed);
        if (v == h) return true;
        if (!v) return false;
    }
    return false;
}

HOOK void ros_trace_rcl_init(const void *context) {
    process_on();
    FORWARD(rcl_init, (const void *), context);
}

HOOK void ros_trace_rcl_node_init(const void *node, const void *rmw, const char *name, const char *ns) {
    meta(ROSCB_META_NODE, node, rmw, NULL, 0, 0, 0, name, ns);
    FORWARD(rcl_node_init, (const void *, const void *, const char *, const char *), node, rmw, name, ns);
}

HOOK void ros_trace_rcl_publisher_init(const void *pub, const void *node, const void *rmw, const char *topic, const size_t depth) {
    meta(ROSCB_META_PUB, pub, node, rmw, (int64_t)depth, 0, 0, topic, NULL);
    if (topic && strcmp(topic, "/rosout") == 0) {
        rosout_add(pub);
        rosout_add(rmw);
    }
    FORWARD(rcl_publisher_init, (const void *, const void *, const void *, const char *, const size_t), pub, node, rmw, topic, depth);
}

HOOK void ros_trace_rcl_subscription_init(const void *sub, const void *node, const void *rmw, const char *topic, const size_t depth) {
    meta(ROSCB_META_SUB, sub, node, rmw, (int64_t)depth, 0, 0, topic, NULL);
    FORWARD(rcl_subscription_init, (const void *, const void *, const void *, const char *, const size_t), sub, node, rmw, topic,
            depth);
}

HOOK void ros_trace_rclcpp_subscription_init(const void *sub, const void *obj) {
    meta(ROSCB_META_SUBOBJ, sub, obj, NULL, 0, 0, 0, NULL, NULL);
    FORWARD(rclcpp_subscription_init, (const void *, const void *), sub, obj);
}

HOOK void ros_trace_rclcpp_subscription_callback_added(const void *obj, const void *cb) {
    meta(ROSCB_META_SUBCB, obj, cb, NULL, 0, 0, 0, NULL, NULL);
    FORWARD(rclcpp_subscription_callback_added, (const void *, const void *), obj, cb);
}

HOOK void ros_trace_rcl_service_init(const void *srv, const void *node, const void *rmw, const char *name) {
    meta(ROSCB_META_SRV, srv, node, rmw, 0, 0, 0, name, NULL);
    FORWARD(rcl_service_init, (const void *, const void *, const void *, const char *), srv, node, rmw, name);
}

HOOK void ros_trace_rclcpp_service_callback_added(const void *srv, const void *cb) {
    meta(ROSCB_META_SRVCB, srv, cb, NULL, 0, 0, 0, NULL, NULL);
    FORWARD(rclcpp_service_callback_added, (const void *, const void *), srv, cb);
}

/* rcl's public API as rcl/timer.h and rcl/time.h declare it (the same in Humble and Jazzy), looked up, never linked. */
typedef int (*until_next_fn)(const void *timer, int64_t *until);
typedef int (*timer_clock_fn)(const void *timer, void **clock);
typedef int (*override_fn)(const void *clock, bool *enabled);

/* The timer's first release on CLOCK_MONOTONIC and its clock's type, from rcl when the program has it. */
static void first_release(const void *timer, int64_t period, int64_t *first, uint32_t *clock) {
    int64_t now = now_ns(CLOCK_MONOTONIC);
    *first = now + period; /* no rcl (a stand-in): rcl's own rule, next = now + period, read a few µs later */
    *clock = 0;
    until_next_fn until_next = (until_next_fn)dlsym(RTLD_DEFAULT, "rcl_timer_get_time_until_next_call");
    timer_clock_fn timer_clock = (timer_clock_fn)dlsym(RTLD_DEFAULT, "rcl_timer_clock");
    if (!until_next || !timer_clock) return;
    void *clk = NULL;
    if (timer_clock(timer, &clk) == 0 && clk) *clock = (uint32_t) * (const int *)clk; /* rcl_clock_t's first member: its type */
    int64_t until = 0;
    if (until_next(timer, &until) != 0) {
        *first = 0; /* cancelled (autostart off): no grid yet */
        return;
    }
    *first = now + until;
    override_fn ros_time = (override_fn)dlsym(RTLD_DEFAULT, "rcl_is_enabled_ros_time_override");
    bool sim = false;
    if (*clock == 1 && ros_time && ros_time(clk, &sim) == 0 && sim) *first = 0; /* simulated time: no grid on this clock */
}

HOOK void ros_trace_rcl_timer_init(const void *timer, int64_t period) {
    if (process_on()) {
        int64_t first;
        uint32_t clock;
        first_release(timer, period, &first, &clock);
        meta(ROSCB_META_TIMER, timer, NULL, NULL, period, first, clock, NULL, NULL);
    }
    FORWARD(rcl_timer_init, (const void *, int64_t), timer, period);
}

HOOK void ros_trace_rclcpp_timer_callback_added(const void *timer, const void *cb) {
    meta(ROSCB_META_TIMERCB, timer, cb, NULL, 0, 0, 0, NULL, NULL);
    FORWARD(rclcpp_timer_callback_added, (const void *, const void *), timer, cb);
}

HOOK void ros_trace_rclcpp_timer_link_node(const void *timer, const void *node) {
    meta(ROSCB_META_TIMERNODE, timer, node, NULL, 0, 0, 0, NULL, NULL);
    FORWARD(rclcpp_timer_link_node, (const void *, const void *), timer, node);
}

HOOK void ros_trace_rclcpp_callback_register(const void *cb, const char *symbol) {
    meta(ROSCB_META_SYM, cb, NULL, NULL, 0, 0, 0, symbol, NULL);
    FORWARD(rclcpp_callback_register, (const void *, const char *), cb, symbol);
}

/* Iron and later ask first: yes while the runner listens (the symbol is needed), else what the real library says. */
HOOK bool ros_trace_enabled_rclcpp_callback_register(void) {
    if (process_on()) return true;
    void *fn = REAL(enabled_rclcpp_callback_register);
    return fn ? ((bool (*)(void))fn)() : false;
}

HOOK void ros_trace_do_rclcpp_callback_register(const void *cb, const char *symbol) {
    meta(ROSCB_META_SYM, cb, NULL, NULL, 0, 0, 0, symbol, NULL);
    void *enabled = REAL(enabled_rclcpp_callback_register);
    if (enabled && ((bool (*)(void))enabled)()) /* LTTng's semantics: the real event only when its session enabled it */
        FORWARD(do_rclcpp_callback_register, (const void *, const char *), cb, symbol);
}

/* ---- the hot path ---- */

HOOK void ros_trace_rclcpp_executor_wait_for_work(const int64_t timeout) {
    t_state.waiting = true;
    FORWARD(rclcpp_executor_wait_for_work, (const int64_t), timeout);
}

HOOK void ros_trace_rclcpp_executor_get_next_ready(void) {
    FORWARD(rclcpp_executor_get_next_ready, (void));
    struct tstate *t = &t_state;
    if (t->waiting) {
        t->wake_ns = now_ns(CLOCK_MONOTONIC);
        t->waiting = false;
    }
}

HOOK void ros_trace_rclcpp_executor_execute(const void *handle) {
    t_state.take_valid = false;
    FORWARD(rclcpp_executor_execute, (const void *), handle);
}

HOOK void ros_trace_rmw_take(const void *rmw_sub, const void *message, int64_t source_timestamp, const bool taken) {
    if (taken) {
        struct tstate *t = &t_state;
        t->take = (uint64_t)(uintptr_t)rmw_sub;
        t->take_src = (uint64_t)source_timestamp;
        t->take_valid = true;
    }
    FORWARD(rmw_take, (const void *, const void *, int64_t, const bool), rmw_sub, message, source_timestamp, taken);
}

HOOK void ros_trace_rcl_publish(const void *pub, const void *message) {
    t_state.last_rcl_pub = (uint64_t)(uintptr_t)pub;
    FORWARD(rcl_publish, (const void *, const void *), pub, message);
}

HOOK void ros_trace_rmw_publish(const void *first, const void *message, int64_t timestamp) {
    struct tstate *t = thread_on();
    bool three = publish_arity() == 3;
    if (t) {
        struct roscb_publish r = {0};
        r.type = ROSCB_PUBLISH;
        r.t_ns = now_ns(CLOCK_MONOTONIC);
        if (three) {
            r.flags = ROSCB_PUB_EXACT;
            r.handle = (uint64_t)(uintptr_t)first;
            r.src_ts = timestamp;
        } else {
            r.flags = ROSCB_PUB_RCL;
            r.handle = t->last_rcl_pub;
            r.src_ts = now_ns(CLOCK_REALTIME);
        }
        r.enclosing_seq = -1;
        if (t->depth) {
            r.enclosing_cb = t->frames[t->depth - 1].cb;
            r.enclosing_seq = (int32_t)t->frames[t->depth - 1].seq;
        }
        if (!rosout_has(r.handle)) put(t, &r);
    }
    void *fn = REAL(rmw_publish);
    if (!fn) return;
    if (three) ((void (*)(const void *, const void *, int64_t))fn)(first, message, timestamp);
    else ((void (*)(const void *))fn)(first);
}

HOOK void ros_trace_callback_start(const void *callback, const bool is_intra_process) {
    FORWARD(callback_start, (const void *, const bool), callback, is_intra_process); /* LTTng's cost outside the callback */
    struct tstate *t = thread_on();
    if (!t) return;
    if (UNLIKELY(t->depth >= ROSCB_STACK)) {
        t->too_deep++;
        t->slot->lost_other++;
        return;
    }
    struct frame *f = &t->frames[t->depth];
    f->cb = (uint64_t)(uintptr_t)callback;
    f->flags = is_intra_process ? ROSCB_CB_INTRA : 0;
    f->wake_ns = t->wake_ns;
    t->wake_ns = 0;
    f->src_ts = f->age_ns = 0;
    f->take = 0;
    if (t->take_valid && !is_intra_process) {
        f->flags |= ROSCB_CB_TAKE;
        f->take = t->take;
        f->src_ts = (int64_t)t->take_src;
        if (f->src_ts) f->age_ns = now_ns(CLOCK_REALTIME) - f->src_ts;
    }
    t->take_valid = false;
    f->seq = t->seq++;
    f->cpu = (int16_t)sched_getcpu();
    usage(f->ru, &f->cpu_us);
    f->start_ns = now_ns(CLOCK_MONOTONIC);
    t->depth++;
    set_open(t);
}

HOOK void ros_trace_callback_end(const void *callback) {
    int64_t end = now_ns(CLOCK_MONOTONIC);
    struct tstate *t = thread_on();
    if (t) {
        uint64_t cb = (uint64_t)(uintptr_t)callback;
        if (t->too_deep && (!t->depth || t->frames[t->depth - 1].cb != cb)) {
            t->too_deep--; /* the end of one that was never kept */
        } else {
            int found = t->depth - 1;
            while (found >= 0 && t->frames[found].cb != cb) found--;
            if (found < 0) {
                t->slot->lost_other++; /* an end with no start on this thread */
            } else {
                long ru[4];
                int64_t cpu_us;
                usage(ru, &cpu_us);
                int cpu = sched_getcpu();
                while (t->depth - 1 > found) { /* those started inside it and never ended */
                    t->depth--;
                    close_frame(t, t->depth, end, cpu, ru, cpu_us, ROSCB_CB_UNTERMINATED);
                }
                t->depth = found;
                close_frame(t, found, end, cpu, ru, cpu_us, 0);
                set_open(t);
            }
        }
    }
    FORWARD(callback_end, (const void *), callback);
}
