/* A stand-in for a ROS 2 node, as rclcpp and rcl would drive libtracetools: the runner's tests' unmodified ROS 2 node.
 *
 * Built once per distro's vendored header (tests/programs/tracetools/<distro>, see its README) and linked with that
 * distro's fake libtracetools.so (tests/rosfake.py generates and builds both).  It calls every tracepoint through the
 * header's own macros (TRACEPOINT on Humble, TRACETOOLS_TRACEPOINT / _ENABLED / TRACETOOLS_DO_TRACEPOINT on Jazzy and
 * later), in the order rcl and rclcpp do (notes §4.5): rcl_init, the nodes, /rosout and parameter services, a
 * publisher, timers (rcl_timer_init with the period, callback_added, register, link_node), a subscription on its own
 * node, then named executor threads that wait on their timer's grid with rcl's skip rule and run the callbacks, a
 * subscriber executor that takes each message (rmw_take with the publisher's CLOCK_REALTIME stamp) and runs its
 * callback, and "middleware" threads that call no tracepoint.
 *
 * At exit it prints one JSON line (a forked child prints its own): per callback its count, missed releases, first
 * release (CLOCK_MONOTONIC ns) and period; `calls`, its own tally of every tracepoint function it called; `fake`, the
 * fake library's count of each (absent when no fake is linked).  Options (durations: 10ms, 500us, 2s, 250ns or bare ns):
 *   --period D     the timers' period (default 10ms)        --burn D     CPU time each timer callback burns (default 100us)
 *   --count N      timer callbacks per timer (default 10)    --duration D run the timers for D instead of --count
 *   --threads N    N timers, each on its own executor thread exec0..exec<N-1> (default 1)
 *   --fork         fork after the set-up; the child runs timer 0's callbacks on its main thread and prints its own line
 *   --exec PROG    at the end, fork and exec PROG (as system() would); its exit status is in the JSON line
 *   --never-end    a further timer callback on thread exec_stuck that starts and never ends
 *   --many N       N more timer callback objects, each registered and run once, on thread exec_many
 *   --nested       timer 0's callback runs a nested callback inside itself (spin_some in a callback)
 *   --bench N      time N empty callback_start/callback_end pairs and print ns per pair (nothing else runs)
 *   --intra        the subscription is intra-process (SubscriptionIntraProcess first, callback_start(..., true))
 *   --no-sub       no subscription, no subscriber executor
 * SIGINT or SIGTERM stops the executors at their next release; the line is printed as at a normal end.
 * Built with -DEXISTING_DEFINER it also defines ros_trace_callback_start itself (not forwarding: an "existing
 * definer"); built against the `disabled` config (TRACETOOLS_DISABLED) every tracepoint is compiled out.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "tracetools/tracetools.h"

/* The header's macros, per distro: Humble has TRACEPOINT only; Iron and later the prefixed names and ENABLED/DO. */
#ifdef TRACETOOLS_TRACEPOINT
#define RT_TP TRACETOOLS_TRACEPOINT
#define RT_ENABLED_DO 1
#else
#define RT_TP TRACEPOINT
#define RT_ENABLED_DO 0
#endif

/* The stand-in's own tally of what it called, by the name of the function the macro reaches without its
 * ros_trace_ prefix (the fake counts under the same names). */
#define TALLIES(X)                                                                                                     \
    X(rcl_init) X(rcl_node_init) X(rmw_publisher_init) X(rcl_publisher_init) X(rcl_service_init)                        \
    X(rclcpp_service_callback_added) X(rcl_timer_init) X(rclcpp_timer_callback_added) X(rclcpp_callback_register)       \
    X(enabled_rclcpp_callback_register) X(do_rclcpp_callback_register) X(rclcpp_timer_link_node)                        \
    X(rmw_subscription_init) X(rcl_subscription_init) X(rclcpp_subscription_init) X(rclcpp_subscription_callback_added) \
    X(rclcpp_executor_get_next_ready) X(rclcpp_executor_wait_for_work) X(rclcpp_executor_execute) X(callback_start)     \
    X(callback_end) X(rclcpp_publish) X(rclcpp_intra_publish) X(rcl_publish) X(rmw_publish) X(rmw_take) X(rcl_take)      \
    X(rclcpp_take)
#define ENUM(name) T_##name,
enum { TALLIES(ENUM) T_COUNT };
#define NAME(name) #name,
static const char *tally_names[] = {TALLIES(NAME)};
static atomic_ullong tallies[T_COUNT];

#ifdef TRACETOOLS_DISABLED
#define TALLY(name) ((void)0)
#else
#define TALLY(name) atomic_fetch_add_explicit(&tallies[T_##name], 1, memory_order_relaxed)
#endif
#define TP(name, ...) (TALLY(name), RT_TP(name, __VA_ARGS__))
#define TP0(name) (TALLY(name), RT_TP(name))

/* The fake's counters, looked up weakly: a DISABLED build links no fake. */
extern size_t fake_tracetools_size(void) __attribute__((weak));
extern const char *fake_tracetools_name(size_t i) __attribute__((weak));
extern unsigned long long fake_tracetools_count(const char *name) __attribute__((weak));

#ifdef EXISTING_DEFINER
/* The program defines a tracepoint function itself and does not forward it (-rdynamic exports it). */
static atomic_ullong definer_calls;
void ros_trace_callback_start(const void *callback, const bool is_intra_process) {
    (void)callback;
    (void)is_intra_process;
    atomic_fetch_add_explicit(&definer_calls, 1, memory_order_relaxed);
}
#endif

/* Opaque handles: only their addresses matter, as for the real rcl and rmw structures. */
typedef struct {
    char opaque[64];
} handle_t;

typedef struct {
    int64_t seq, stamp_rt;
} msg_t;

typedef struct {
    const char *label, *symbol, *thread;
    handle_t rcl_timer;
    handle_t callback; /* &GenericTimer::callback_ */
    int64_t period, first_release;
    long long count, missed;
    int started, ended;
} timer_cb;

static int64_t period_ns = 10000000, burn_ns = 100000, duration_ns = -1, count = 10;
static int n_threads = 1, do_fork, never_end, nested, intra, no_sub;
static long many, bench;
static const char *exec_prog;
static volatile sig_atomic_t stopping;
static int is_child;

static handle_t context, node, rmw_node, node_b, rmw_node_b, rosout, rmw_rosout, param_srv[2], rmw_param_srv[2];
static handle_t publisher, rmw_publisher, subscription, rmw_subscription, sub_object, sub_callback, ipc_object,
    ipc_callback;
static uint8_t gid[24];
static timer_cb *timers, stuck, inner, bench_cb;
static long long sub_count, sub_empty_takes, many_count;
static int pipe_fds[2] = {-1, -1};
static atomic_int publishers_left;

static int64_t now_ns(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void sleep_until(int64_t when) {
    struct timespec ts = {(time_t)(when / 1000000000LL), (long)(when % 1000000000LL)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !stopping) {
    }
}

static void burn(int64_t ns) {
    int64_t until = now_ns(CLOCK_THREAD_CPUTIME_ID) + ns;
    while (now_ns(CLOCK_THREAD_CPUTIME_ID) < until) {
    }
}

static int64_t parse_duration(const char *text) {
    char *end;
    double value = strtod(text, &end);
    double scale = !strcmp(end, "s")    ? 1e9
                   : !strcmp(end, "ms") ? 1e6
                   : !strcmp(end, "us") ? 1e3
                   : (!strcmp(end, "ns") || !*end) ? 1.0
                                                     : -1.0;
    if (end == text || scale < 0 || value < 0) {
        fprintf(stderr, "rosnode: not a duration: %s (10ms, 500us, 2s, 250ns)\n", text);
        exit(2);
    }
    return (int64_t)(value * scale);
}

/* rclcpp's register: unconditional on Humble; on Iron and later only when a session enables it (ENABLED/DO). */
static void register_callback(const void *callback, const char *symbol) {
#if RT_ENABLED_DO
    TALLY(enabled_rclcpp_callback_register);
    if (TRACETOOLS_TRACEPOINT_ENABLED(rclcpp_callback_register)) {
        TALLY(do_rclcpp_callback_register);
        TRACETOOLS_DO_TRACEPOINT(rclcpp_callback_register, callback, symbol);
    }
#else
    TP(rclcpp_callback_register, callback, symbol);
#endif
}

/* rclcpp::create_wall_timer: rcl_timer_init (rcl's `now + period` is the first release), then GenericTimer's
 * constructor (callback_added, register), then NodeTimers::add_timer (link_node). */
static void create_timer(timer_cb *t, const char *label, const char *symbol, const char *thread) {
    t->label = label;
    t->symbol = symbol;
    t->thread = thread;
    t->period = period_ns;
    t->first_release = now_ns(CLOCK_MONOTONIC) + period_ns;
    TP(rcl_timer_init, &t->rcl_timer, period_ns);
    TP(rclcpp_timer_callback_added, &t->rcl_timer, &t->callback);
    register_callback(&t->callback, symbol);
    TP(rclcpp_timer_link_node, &t->rcl_timer, &node);
}

static void publish(int64_t seq) {
    msg_t msg = {seq, now_ns(CLOCK_REALTIME)};
    if (intra) {
#if RT_ENABLED_DO
        TP(rclcpp_intra_publish, &publisher, &msg);
#endif
    } else {
        TP(rclcpp_publish, NULL, &msg);
        TP(rcl_publish, &publisher, &msg);
#if RT_ENABLED_DO
        TP(rmw_publish, &rmw_publisher, &msg, msg.stamp_rt); /* the stamp the subscriber's source_timestamp carries */
#else
        TP(rmw_publish, &msg);
#endif
    }
    if (pipe_fds[1] >= 0 && write(pipe_fds[1], &msg, sizeof msg) != (ssize_t)sizeof msg) perror("rosnode: write");
}

/* One executable's run, as Executor::execute_any_executable does for a timer: execute, then the callback. */
static void run_timer_callback(timer_cb *t, int64_t seq) {
    TP(rclcpp_executor_execute, &t->rcl_timer);
    TP(callback_start, &t->callback, false);
    t->started++;
    if (t == &stuck) {
        for (;;) pause();
    }
    burn(burn_ns);
    if (nested && t == &timers[0]) {
        run_timer_callback(&inner, seq); /* spin_some inside a callback */
    }
    if (t != &inner) publish(seq);
    TP(callback_end, &t->callback);
    t->ended++;
    t->count++;
}

/* An executor spinning on one timer: get_next_ready (nothing), wait_for_work until the release, get_next_ready, then
 * rcl_timer_call's rule (next += period; when that is already past, skip ahead by whole periods: missed releases). */
static void spin_timer(timer_cb *t) {
    int64_t next = t->first_release, end = duration_ns >= 0 ? now_ns(CLOCK_MONOTONIC) + duration_ns : -1;
    while (!stopping && (duration_ns >= 0 ? next <= end : t->count < count)) {
        TP0(rclcpp_executor_get_next_ready);
        TP(rclcpp_executor_wait_for_work, next - now_ns(CLOCK_MONOTONIC));
        sleep_until(next);
        if (stopping) break;
        TP0(rclcpp_executor_get_next_ready);
        int64_t now = now_ns(CLOCK_MONOTONIC);
        next += t->period;
        if (next < now) {
            int64_t ahead = 1 + (now - next) / t->period;
            t->missed += ahead;
            next += ahead * t->period;
        }
        run_timer_callback(t, t->count);
    }
}

static void *timer_thread(void *arg) {
    spin_timer(arg);
    if (atomic_fetch_sub(&publishers_left, 1) == 1 && pipe_fds[1] >= 0) close(pipe_fds[1]); /* the subscriber ends */
    return NULL;
}

static void *stuck_thread(void *arg) {
    (void)arg;
    TP0(rclcpp_executor_get_next_ready);
    TP(rclcpp_executor_wait_for_work, period_ns);
    sleep_until(stuck.first_release);
    TP0(rclcpp_executor_get_next_ready);
    run_timer_callback(&stuck, 0); /* never returns */
    return NULL;
}

static void *many_thread(void *arg) {
    timer_cb *objects = arg;
    for (long i = 0; i < many; i++) {
        TP0(rclcpp_executor_get_next_ready);
        TP(rclcpp_executor_execute, &objects[i].rcl_timer);
        TP(callback_start, &objects[i].callback, false);
        TP(callback_end, &objects[i].callback);
        objects[i].count++;
        many_count++;
    }
    return NULL;
}

/* The subscriber's executor: wait_for_work blocks on the "middleware" (a pipe), then rmw_take with the publisher's
 * stamp, rcl_take, rclcpp_take and the callback; every fifth message a further poll that takes nothing. */
static void *subscriber_thread(void *arg) {
    (void)arg;
    msg_t msg;
    for (;;) {
        TP0(rclcpp_executor_get_next_ready);
        TP(rclcpp_executor_wait_for_work, (int64_t)-1);
        ssize_t got = read(pipe_fds[0], &msg, sizeof msg);
        if (got != (ssize_t)sizeof msg) break;
        TP0(rclcpp_executor_get_next_ready);
        TP(rclcpp_executor_execute, &subscription);
        if (intra) {
            TP(callback_start, &ipc_callback, true);
            TP(callback_end, &ipc_callback);
        } else {
            TP(rmw_take, &rmw_subscription, &msg, msg.stamp_rt, true);
            TP(rcl_take, &msg);
            TP(rclcpp_take, &msg);
            TP(callback_start, &sub_callback, false);
            TP(callback_end, &sub_callback);
        }
        sub_count++;
        if (!intra && sub_count % 5 == 0) {
            msg_t none = {0, 0};
            TP(rmw_take, &rmw_subscription, &none, (int64_t)0, false);
            sub_empty_takes++;
        }
    }
    return NULL;
}

static void *middleware_thread(void *arg) {
    (void)arg;
    for (;;) {
        struct timespec ts = {0, 5000000};
        nanosleep(&ts, NULL); /* a DDS thread's own wake-ups; no tracepoint */
    }
    return NULL;
}

static pthread_t start(const char *name, void *(*fn)(void *), void *arg) {
    pthread_t thread;
    if (pthread_create(&thread, NULL, fn, arg) != 0) {
        perror("rosnode: pthread_create");
        exit(2);
    }
    pthread_setname_np(thread, name);
    return thread;
}

static void on_signal(int sig) {
    (void)sig;
    stopping = 1;
}

static void print_timer(FILE *out, const timer_cb *t, int *first) {
    fprintf(out,
            "%s{\"name\":\"%s\",\"kind\":\"timer\",\"node\":\"minimal_publisher\",\"symbol\":\"%s\",\"thread\":\"%s\","
            "\"count\":%lld,\"missed\":%lld,\"first_release\":%lld,\"period\":%lld,\"started\":%d,\"ended\":%d}",
            *first ? "" : ",", t->label, t->symbol, t->thread, t->count, t->missed, (long long)t->first_release,
            (long long)t->period, t->started, t->ended);
    *first = 0;
}

static void print_json(int exec_status, double bench_ns) {
    FILE *out = stdout;
    int first = 1;
    fprintf(out, "{\"pid\":%d,\"role\":\"%s\",\"callbacks\":[", (int)getpid(), is_child ? "child" : "main");
    for (int i = 0; i < (is_child ? 1 : n_threads) && !bench; i++) print_timer(out, &timers[i], &first);
    if (nested && !bench) print_timer(out, &inner, &first);
    if (never_end && !is_child) print_timer(out, &stuck, &first);
    if (!no_sub && !is_child && !bench) {
        fprintf(out,
                "%s{\"name\":\"subscription\",\"kind\":\"subscription\",\"node\":\"minimal_subscriber\",\"topic\":\"/topic\","
                "\"intra\":%s,\"thread\":\"exec_sub\",\"count\":%lld,\"empty_takes\":%lld}",
                first ? "" : ",", intra ? "true" : "false", sub_count, sub_empty_takes);
        first = 0;
    }
    if (many && !is_child) {
        fprintf(out, "%s{\"name\":\"many\",\"kind\":\"many\",\"thread\":\"exec_many\",\"objects\":%ld,\"count\":%lld}",
                first ? "" : ",", many, many_count);
    }
    fprintf(out, "],\"calls\":{");
    first = 1;
    for (int i = 0; i < T_COUNT; i++) {
        unsigned long long n = atomic_load(&tallies[i]);
        if (n) fprintf(out, "%s\"%s\":%llu", first ? "" : ",", tally_names[i], n), first = 0;
    }
    fprintf(out, "}");
    if (fake_tracetools_size) {
        fprintf(out, ",\"fake\":{");
        first = 1;
        for (size_t i = 0; i < fake_tracetools_size(); i++) {
            unsigned long long n = fake_tracetools_count(fake_tracetools_name(i));
            if (n) fprintf(out, "%s\"%s\":%llu", first ? "" : ",", fake_tracetools_name(i), n), first = 0;
        }
        fprintf(out, "}");
    }
#ifdef EXISTING_DEFINER
    fprintf(out, ",\"definer_calls\":%llu", atomic_load(&definer_calls));
#endif
    if (exec_prog) fprintf(out, ",\"exec\":{\"prog\":\"%s\",\"status\":%d}", exec_prog, exec_status);
    if (bench) fprintf(out, ",\"bench\":{\"pairs\":%ld,\"ns_per_pair\":%.1f}", bench, bench_ns);
    fprintf(out, "}\n");
    fflush(out);
}

/* N empty callbacks timed as rclcpp's dispatch would run them; the tally is added after, outside the timing. */
static double run_bench(void) {
    int64_t t0 = now_ns(CLOCK_MONOTONIC);
    for (long i = 0; i < bench; i++) {
        RT_TP(callback_start, &bench_cb.callback, false);
        RT_TP(callback_end, &bench_cb.callback);
    }
    int64_t spent = now_ns(CLOCK_MONOTONIC) - t0;
#ifndef TRACETOOLS_DISABLED
    atomic_fetch_add(&tallies[T_callback_start], (unsigned long long)bench);
    atomic_fetch_add(&tallies[T_callback_end], (unsigned long long)bench);
#endif
    bench_cb.count = bench;
    return (double)spent / (double)bench;
}

static int run_exec(void) {
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        execlp(exec_prog, exec_prog, (char *)NULL);
        _exit(127);
    }
    int status = 0;
    if (pid < 0 || waitpid(pid, &status, 0) < 0) return -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

int main(int argc, char **argv) {
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--period") && v) period_ns = parse_duration(argv[++i]);
        else if (!strcmp(a, "--burn") && v) burn_ns = parse_duration(argv[++i]);
        else if (!strcmp(a, "--count") && v) count = atoll(argv[++i]);
        else if (!strcmp(a, "--duration") && v) duration_ns = parse_duration(argv[++i]);
        else if (!strcmp(a, "--threads") && v) n_threads = atoi(argv[++i]);
        else if (!strcmp(a, "--many") && v) many = atol(argv[++i]);
        else if (!strcmp(a, "--bench") && v) bench = atol(argv[++i]);
        else if (!strcmp(a, "--exec") && v) exec_prog = argv[++i];
        else if (!strcmp(a, "--fork")) do_fork = 1;
        else if (!strcmp(a, "--never-end")) never_end = 1;
        else if (!strcmp(a, "--nested")) nested = 1;
        else if (!strcmp(a, "--intra")) intra = 1;
        else if (!strcmp(a, "--no-sub")) no_sub = 1;
        else {
            fprintf(stderr, "rosnode: unknown option or missing value: %s\n", a);
            return 2;
        }
    }
    if (period_ns <= 0 || n_threads < 1 || n_threads > 64 || many < 0 || bench < 0) {
        fprintf(stderr, "rosnode: --period > 0, 1 <= --threads <= 64, --many and --bench >= 0\n");
        return 2;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    /* rclcpp::init, then the publisher's node with its /rosout publisher and parameter services. */
    TP(rcl_init, &context);
    TP(rcl_node_init, &node, &rmw_node, "minimal_publisher", "/");
    TP(rmw_publisher_init, &rmw_rosout, gid);
    TP(rcl_publisher_init, &rosout, &node, &rmw_rosout, "/rosout", (size_t)1000);
    static const char *services[] = {"/minimal_publisher/get_parameters", "/minimal_publisher/set_parameters"};
    for (int i = 0; i < 2; i++) {
        TP(rcl_service_init, &param_srv[i], &node, &rmw_param_srv[i], services[i]);
        TP(rclcpp_service_callback_added, &param_srv[i], &rmw_param_srv[i]);
        register_callback(&rmw_param_srv[i], "rclcpp::ParameterService::ParameterService(...)::{lambda(...)#1}");
    }

    if (bench) {
        create_timer(&bench_cb, "bench", "bench_callback()", "main");
        double ns = run_bench();
        print_json(0, ns);
        return 0;
    }

    TP(rmw_publisher_init, &rmw_publisher, gid);
    TP(rcl_publisher_init, &publisher, &node, &rmw_publisher, "/topic", (size_t)10);
    static const char *labels[] = {"timer0", "timer1", "timer2", "timer3"};
    static char names[64][16], symbols[64][64];
    timers = calloc((size_t)n_threads, sizeof *timers);
    for (int i = 0; i < n_threads; i++) {
        snprintf(names[i], sizeof names[i], "exec%d", i);
        snprintf(symbols[i], sizeof symbols[i], "MinimalPublisher::MinimalPublisher()::{lambda()#%d}", i + 1);
        create_timer(&timers[i], i < 4 ? labels[i] : names[i], symbols[i], names[i]);
    }
    if (nested) create_timer(&inner, "nested", "MinimalPublisher::nested_callback()", "exec0");
    if (never_end) create_timer(&stuck, "stuck", "MinimalPublisher::stuck_callback()", "exec_stuck");
    timer_cb *objects = NULL;
    if (many) {
        objects = calloc((size_t)many, sizeof *objects);
        char *syms = calloc((size_t)many, 40);
        for (long i = 0; i < many; i++) {
            snprintf(syms + i * 40, 40, "Many::callback_%ld()", i);
            create_timer(&objects[i], "many", syms + i * 40, "exec_many");
        }
    }

    /* The subscriber's node, its subscription (rcl, then rclcpp), as rclcpp::Node::create_subscription does. */
    if (!no_sub) {
        TP(rcl_node_init, &node_b, &rmw_node_b, "minimal_subscriber", "/");
        TP(rmw_subscription_init, &rmw_subscription, gid);
        TP(rcl_subscription_init, &subscription, &node_b, &rmw_subscription, "/topic", (size_t)10);
        if (intra) { /* SubscriptionIntraProcess is built first, and named before the rcl subscription is linked to it */
            TP(rclcpp_subscription_callback_added, &ipc_object, &ipc_callback);
            register_callback(&ipc_callback, "MinimalSubscriber::topic_callback(std_msgs::msg::String const&) const");
            TP(rclcpp_subscription_init, &subscription, &ipc_object);
        }
        TP(rclcpp_subscription_init, &subscription, &sub_object);
        TP(rclcpp_subscription_callback_added, &sub_object, &sub_callback);
        register_callback(&sub_callback, "MinimalSubscriber::topic_callback(std_msgs::msg::String const&) const");
        if (pipe(pipe_fds) != 0) {
            perror("rosnode: pipe");
            return 2;
        }
    }

    if (do_fork) {
        fflush(stdout);
        pid_t pid = fork();
        if (pid == 0) {
            is_child = 1;
            if (pipe_fds[1] >= 0) close(pipe_fds[1]), close(pipe_fds[0]), pipe_fds[0] = pipe_fds[1] = -1;
            pthread_setname_np(pthread_self(), "exec_child");
            timers[0].thread = "exec_child";
            spin_timer(&timers[0]);
            print_json(0, 0);
            return 0;
        }
        if (pid < 0) perror("rosnode: fork");
    }

    start("recvUC", middleware_thread, NULL);
    start("dq.builtins", middleware_thread, NULL);
    start("tev", middleware_thread, NULL);
    atomic_store(&publishers_left, n_threads);
    pthread_t subscriber = 0, many_runner = 0, *executors = calloc((size_t)n_threads, sizeof *executors);
    if (!no_sub) subscriber = start("exec_sub", subscriber_thread, NULL);
    if (many) many_runner = start("exec_many", many_thread, objects);
    if (never_end) start("exec_stuck", stuck_thread, NULL);
    for (int i = 0; i < n_threads; i++) executors[i] = start(names[i], timer_thread, &timers[i]);
    for (int i = 0; i < n_threads; i++) pthread_join(executors[i], NULL);
    if (many) pthread_join(many_runner, NULL);
    if (!no_sub) pthread_join(subscriber, NULL);
    int exec_status = exec_prog ? run_exec() : 0;
    if (do_fork) while (wait(NULL) > 0) {
        }
    print_json(exec_status, 0);
    return 0; /* exit() ends the stuck and middleware threads */
}
